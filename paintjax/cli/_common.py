"""Shared pieces of the sub-commands: JSON output, sample overrides, output folders."""

from __future__ import annotations

import json
import math
import sys

from .. import _pipeline as pipeline
from .._io import to_jsonable
from .._pipeline import D50_RANGE_UM
from .._validate import check_args
from ..microstructure._array import MAX_PVC


def as_flags(ranges, renamed=None) -> dict:
    """A library entry point's ranges (argument → `Range`) under the CLI's flags: `platelet_thickness` →
    `--platelet-thickness`, or as `renamed` (argument → flag) says."""
    renamed = renamed or {}
    return {renamed.get(k, "--" + k.replace("_", "-")): r for k, r in ranges.items()}


#: Ranges shared by several sub-commands (each sub-command's `RANGES` maps its flags to `Range`s; --seed's is `paintjax._validate.SEED`):
#: `add_paint_arguments`' flags (σ and τ as the wave tables accept them) and `add_array_arguments`'.
PAINT_RANGES, ARRAY_RANGES = as_flags(pipeline.PAINT_RANGES), as_flags(pipeline.ARRAY_RANGES)


def check_flags(args, ranges) -> None:
    """Every option of `ranges` (flag → `Range`) that was given against its range, before any work: a
    ValueError "--flag must lie in [a, b] unit, got X" (`paintjax._validate.check_args`). A flag the command does not
    have is an AttributeError, not a check silently skipped."""
    check_args({flag: getattr(args, flag[2:].replace("-", "_")) for flag in ranges}, ranges)


def print_json(obj) -> None:
    json.dump(to_jsonable(obj), sys.stdout, indent=None, allow_nan=False)
    sys.stdout.write("\n")


def format_optional(value, spec: str = ".2f") -> str:
    """`value` formatted, or an em dash for None."""
    return "—" if value is None else format(value, spec)


def parse_floats(text: str, name: str, count: int | None = None) -> list[float]:
    """Comma-separated finite numbers of option `name` (exactly `count` of them if given)."""
    try:
        values = [float(v) for v in str(text).replace(" ", "").split(",") if v != ""]
    except ValueError:
        raise ValueError(f"{name} must be comma-separated numbers, got {text!r}") from None
    if not values or not all(math.isfinite(v) for v in values):
        raise ValueError(f"{name} must be comma-separated finite numbers, got {text!r}")
    if count is not None and len(values) != count:
        raise ValueError(f"{name} must have {count} comma-separated values, got {len(values)}")
    return values


def parse_distinct(text: str, name: str) -> list[float]:
    """Comma-separated finite numbers of option `name`, none repeated."""
    values = parse_floats(text, name)
    repeated = sorted({v for v in values if values.count(v) > 1})
    if repeated:
        raise ValueError(f"{name} must list each angle once, got {', '.join(f'{v:g}' for v in repeated)} more than once in {text!r}")
    return values


def add_output_argument(parser, default: str) -> None:
    parser.add_argument("--out", default=default, help=f"folder for data and plots (default: {default})")


def add_json_argument(parser) -> None:
    parser.add_argument("--json", action="store_true", help="print machine-readable JSON to stdout instead of a table")


def parse_color_table(text: str):
    """`--color-table NHxND` as (nh, nd), or None for "none"; a ValueError naming the flag otherwise."""
    from ..appearance._carpaint import MAX_TABLE_NODES

    if str(text).lower() == "none":
        return None
    try:
        nodes = tuple(int(v) for v in str(text).lower().split("x"))
    except ValueError:
        nodes = ()
    if len(nodes) != 2 or not all(2 <= v <= MAX_TABLE_NODES for v in nodes):
        raise ValueError(f"--color-table must be NHxND with 2 to {MAX_TABLE_NODES} nodes each, e.g. 6x6, got {text!r}")
    return nodes


def add_color_table_argument(parser) -> None:
    parser.add_argument("--color-table", default="6x6", help="nodes NHxND of the colour table χ(θh, θd) fitted with the lobes (default "
                        "6x6: ΔL* RMS 0.93 and 0.86 at the MA98 geometries for the two silvers, 1.84 and 1.58 without); none: the "
                        "plain diffuse + lobes form")


def add_paint_arguments(parser) -> None:
    """`--sample` and the tilt-law and roughness overrides (`--shape`, `--scale`, `--sigma`, `--tau`) of a simulated paint."""
    parser.add_argument("--sample", default="silver1", help="reference sample: silver1 or silver2 (default silver1)")
    parser.add_argument("--shape", type=float, help="tilt gamma shape (> 0); default: the sample's")
    parser.add_argument("--scale", type=float, help="tilt gamma scale [deg] (> 0); default: the sample's")
    parser.add_argument("--sigma", type=float, help="platelet rms roughness σ [µm]; default: the sample's (0.051)")
    parser.add_argument("--tau", type=float, help="platelet correlation length τ [µm]; default: the sample's (0.64)")


def add_array_arguments(parser) -> None:
    """`--pvc`, `--d50` and `--platelet-thickness`: the platelet overrides of `array_overrides`."""
    parser.add_argument("--pvc", type=float, help=f"pigment volume concentration in (0, {MAX_PVC}]; default: the sample's (0.20)")
    parser.add_argument("--d50", type=float,
                        help=f"median platelet width [µm] in [{D50_RANGE_UM[0]:g}, {D50_RANGE_UM[1]:g}]: the sample's log-normal width law scaled to this median (D10, D90 and "
                        "the default tile in proportion); default: the sample's (16, D10 ≈ 8, D90 ≈ 30; not measured)")
    parser.add_argument("--platelet-thickness", type=float,
                        help="platelet thickness t [µm] (> 0, below the basecoat's); default: the sample's (1.0, the original study's value)")
