"""The `paintjax` console script: one sub-command per module in `paintjax.cli`.

Float64 is enabled here (the CLI is a documented place that needs it); errors in user input are
reported as one line naming the parameter, with exit status 2.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

#: Sub-command modules under paintjax.cli, in the order `--help` lists them.
COMMANDS = ("demo", "microfacet", "array", "brdf", "lobe", "fit", "posterior", "design", "simulate", "table1", "gonio", "render")


class _OneLineParser(argparse.ArgumentParser):
    """argparse with its usage errors on one line (`paintjax CMD: error: …`, exit status 2); --help is unchanged."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _OneLineParser(
        prog="paintjax",
        description="Hybrid ray-wave appearance model of metallic paint (lengths in µm, angles in degrees).",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND", parser_class=_OneLineParser)
    for name in COMMANDS:
        importlib.import_module(f"paintjax.cli._{name}").register(sub)
    return parser


def _check_output_folder(out) -> None:
    """Fail at once, before any work, where `--out` could not be created or written (ValueError
    naming --out); nothing is created here."""
    if not out:
        return
    from .._io import nearest_existing

    probe = nearest_existing(out)  # it must be a folder that lets us create the rest
    if not probe.is_dir():
        raise ValueError(f"--out must be a folder, but {str(probe)!r} is a file, got {out!r}")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise ValueError(f"--out must be a folder that can be written, but {str(probe)!r} is not writable, got {out!r}")


def _check_arguments(args) -> None:
    """The validation layer, before any array, table, fit or compilation: every option in the command's
    `RANGES` (flag → `paintjax._validate.Range`; `flag_ranges(args)` where they depend on other options) against its
    range, then `--out`."""
    from ._common import check_flags

    module = importlib.import_module(f"paintjax.cli._{args.command}")
    check_flags(args, module.flag_ranges(args) if hasattr(module, "flag_ranges") else getattr(module, "RANGES", {}))
    _check_output_folder(getattr(args, "out", None))


def _as_flags(message: str, command: str) -> str:
    """The error message with the API argument names of the command's `API_FLAGS` written as its flags."""
    import re

    flags = getattr(importlib.import_module(f"paintjax.cli._{command}"), "API_FLAGS", {})
    for name, flag in flags.items():
        message = re.sub(rf"(?<![\w-]){re.escape(name)}(?![\w])", flag, message)
    return message


def main(argv: list[str] | None = None) -> int:
    import jax

    jax.config.update("jax_enable_x64", True)
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as done:  # --help (0) or a usage error (2, already printed on one line)
        return int(done.code or 0)
    try:
        _check_arguments(args)
        result = args.func(args)
    except ValueError as err:
        print(f"paintjax {args.command}: error: {_as_flags(str(err), args.command)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as err:  # Ctrl-C: one line, no traceback (what was kept, where a command says)
        print(f"paintjax {args.command}: {str(err) or 'interrupted'}", file=sys.stderr)
        return 130
    except OSError as err:  # e.g. a full disk or an unwritable cache folder ($PAINTJAX_CACHE)
        print(f"paintjax {args.command}: error: {err}", file=sys.stderr)
        return 1
    except BrokenPipeError:  # the reader went away (`paintjax … | head`): results on disk are complete
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 1
    return int(result or 0)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
