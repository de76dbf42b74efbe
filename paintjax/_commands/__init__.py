"""Sub-commands of the `paintjax` CLI; each module defines `register(subparsers)`."""
