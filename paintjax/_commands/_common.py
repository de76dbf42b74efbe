"""Shared pieces of the sub-commands: JSON output, sample overrides, output folders."""

from __future__ import annotations

import json
import math
import sys

from .._io import to_jsonable


def print_json(obj) -> None:
    json.dump(to_jsonable(obj), sys.stdout, indent=None, allow_nan=False)
    sys.stdout.write("\n")


def flop_index_or_none(L15, L45, L110) -> float | None:
    """The flop index, or None where the formula is undefined (no light at 45°, L*15 < L*110)."""
    from .._lightness import flop_index

    v = float(flop_index(L15, L45, L110))
    return v if math.isfinite(v) else None


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


def add_output_argument(parser, default: str) -> None:
    parser.add_argument("--out", default=default, help=f"folder for data and plots (default: {default})")


def add_json_argument(parser) -> None:
    parser.add_argument("--json", action="store_true", help="print machine-readable JSON to stdout instead of a table")


def add_array_arguments(parser) -> None:
    """`--pvc`, `--d50` and `--platelet-thickness`: the platelet overrides of `array_overrides`."""
    from .._microstructure import MAX_PVC

    parser.add_argument("--pvc", type=float, help=f"pigment volume concentration in (0, {MAX_PVC}]; default: the sample's (0.20)")
    parser.add_argument("--d50", type=float,
                        help=f"median platelet width [µm] in [{D50_RANGE_UM[0]:g}, {D50_RANGE_UM[1]:g}]: the sample's log-normal width law scaled to this median (D10, D90 and "
                        "the default tile in proportion); default: the sample's (16, D10 ≈ 8, D90 ≈ 30; not measured)")
    parser.add_argument("--platelet-thickness", type=float,
                        help="platelet thickness t [µm] (> 0, below the basecoat's); default: the sample's (1.0, the original study's value)")


#: Allowed median platelet width for `--d50` [µm]: the reference samples' platelets are 10–30 µm
#: across; beyond 50 µm the widest platelets (≈ 4.7 × D50) no longer fit a 20 µm film at their tilts.
D50_RANGE_UM = (1.0, 50.0)


def array_overrides(s, *, pvc=None, thickness=None, d50=None, platelet_thickness=None) -> dict:
    """Validated `generate_platelet_array` keywords for the array overrides of sample `s`.

    `thickness` is the basecoat's; `d50` rescales the sample's log-normal width law to that median
    (same spread in ln w, so D10, D90 and the default tile scale with it; `D50_RANGE_UM`);
    `platelet_thickness` is t, which must stay below the basecoat thickness (given or the sample's).
    """
    from .._microstructure import check_pvc
    from .._sizes import LogNormalSizes, positive_finite

    out = {}
    if pvc is not None:
        out["pvc"] = check_pvc(pvc)
    if thickness is not None:
        out["basecoat_thickness"] = positive_finite("thickness", thickness, "µm")
    if d50 is not None:
        lo, hi = D50_RANGE_UM
        if not lo <= positive_finite("d50", d50, "µm") <= hi:
            raise ValueError(f"d50 (median platelet width) must lie in [{lo:g}, {hi:g}] µm, got {d50!r}")
        k = float(d50) / s.size_d50
        out["sizes"] = LogNormalSizes.from_quantiles(k * s.size_d10, float(d50), k * s.size_d90)
    if platelet_thickness is not None:
        out["thickness"] = positive_finite("platelet_thickness", platelet_thickness, "µm")
    t = out.get("thickness", s.platelet_thickness)
    h_b = out.get("basecoat_thickness", s.basecoat_thickness)
    if t >= h_b:
        name = "platelet_thickness" if platelet_thickness is not None else "thickness"
        raise ValueError(f"{name}: the platelets (t = {t:g} µm) must be thinner than the basecoat (thickness {h_b:g} µm)")
    return out
