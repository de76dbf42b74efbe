"""Shared pieces of the sub-commands: JSON output, sample overrides, output folders."""

from __future__ import annotations

import json
import sys

from .._io import to_jsonable


def print_json(obj) -> None:
    json.dump(to_jsonable(obj), sys.stdout, indent=None)
    sys.stdout.write("\n")


def add_output_argument(parser, default: str) -> None:
    parser.add_argument("--out", default=default, help=f"folder for data and plots (default: {default})")


def add_json_argument(parser) -> None:
    parser.add_argument("--json", action="store_true", help="print machine-readable JSON to stdout instead of a table")
