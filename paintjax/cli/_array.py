"""`paintjax array`: build a platelet array of a sample, print its statistics, draw it."""

from __future__ import annotations

import warnings
from pathlib import Path

from .._pipeline import array_overrides
from .._progress import print_progress
from .._validate import SEED, Range
from ..microstructure._array import MAX_TILE_UM
from ..microstructure._plots import plot_cross_section, plot_tilt_histogram
from ._common import ARRAY_RANGES, add_array_arguments, add_json_argument, add_output_argument, print_json

#: The validation layer's ranges (flag → `Range`), checked before any work.
RANGES = {"--seed": SEED, "--tile": Range(0.0, MAX_TILE_UM, "µm", lo_open=True), **ARRAY_RANGES,
          "--max-attempts": Range(0, None, integer=True)}
#: The API argument names of the generator's own checks (the tile's lower end depends on the widths) → flags.
API_FLAGS = {"tile (": "--tile (", "tile sides": "--tile sides", "tile must": "--tile must", "platelet_thickness": "--platelet-thickness",
             "lower pvc, a smaller tile, or thicker or wider platelets": "lower --pvc, a smaller --tile, or a larger --platelet-thickness or --d50",
             "raise pvc or tile": "raise --pvc or --tile"}
JSON_KEYS = ("count", "pvc", "overlaps_exact", "overlaps_midplane", "tilt_ks", "seconds")


def register(sub) -> None:
    p = sub.add_parser(
        "array",
        help="generate a platelet array (statistics, overlap removal), print statistics, draw pictures",
        description=(
            "Platelet array of a reference sample: widths, gamma tilts, uniform positions in a periodic "
            "basecoat tile, overlaps removed. Writes a vertical cross-section and the tilt histogram."
        ),
    )
    p.add_argument("--sample", default="silver1", help="reference sample: silver1 or silver2 (default silver1)")
    p.add_argument("--seed", type=int, default=0, help="random seed, integer ≥ 0 (default 0)")
    p.add_argument("--tile", type=float, help="tile side [µm] (default 10 × the largest platelet width)")
    add_array_arguments(p)
    p.add_argument("--overlap-test", default="sat", choices=("sat", "midplane", "none"), help="overlap test used for removal (default sat)")
    p.add_argument("--max-attempts", type=int, default=1000, help="re-placements per platelet (default 1000)")
    p.add_argument("--allow-overlaps", action="store_true", help="keep an array whose overlaps could not all be removed (default: refuse, exit 2)")
    p.add_argument("--no-plots", action="store_true", help="do not write the pictures")
    add_output_argument(p, "results/array")
    add_json_argument(p)
    p.set_defaults(func=run)


def compute(sample="silver1", seed=0, tile=None, pvc=None, overlap_test="sat", max_attempts=1000, d50=None,
            platelet_thickness=None, progress=False) -> tuple:
    """Build the array; returns (array, tilt law, statistics dict incl. the JSON keys, log).

    `pvc`, `d50` and `platelet_thickness` override the sample's (`_common.array_overrides`); `progress` prints
    the share of platelets placed, with the time left, every few seconds to stderr.
    """
    from .. import GammaTilt, load_sample
    from ..microstructure._array import platelet_array_for_sample
    from ..microstructure._statistics import array_statistics

    s = load_sample(sample)
    overrides = dict(overlap_test=overlap_test, max_attempts=max_attempts, heartbeat=print_progress("array", "of the platelets placed") if progress else None,
                     **array_overrides(s, pvc=pvc, d50=d50, platelet_thickness=platelet_thickness))
    if tile is not None:
        overrides["tile"] = tile
    array, log = platelet_array_for_sample(s.name, seed, return_log=True, **overrides)
    tilt = GammaTilt(s.tilt_shape.value, s.tilt_scale.value)
    stats = array_statistics(array, tilt)
    stats.update(sample=s.name, seed=seed, seconds=log.seconds, pvc_target=log.pvc_target, log=log)
    return array, tilt, stats


def run(args) -> int:
    with warnings.catch_warnings():  # leftover overlaps are refused or reported below, not warned about twice
        warnings.filterwarnings("ignore", message=r".*still overlap after", category=RuntimeWarning)
        array, tilt, stats = compute(args.sample, args.seed, args.tile, args.pvc, args.overlap_test, args.max_attempts,
                                     d50=args.d50, platelet_thickness=args.platelet_thickness, progress=True)
    left = stats["overlaps_midplane" if args.overlap_test == "midplane" else "overlaps_exact"]
    if args.overlap_test != "none" and left > 0 and not args.allow_overlaps:
        raise ValueError(f"{left} overlapping platelet pairs remain after --max-attempts {args.max_attempts} re-placements "
                         f"({stats['log'].n_failed} platelets could not be placed); raise --max-attempts, lower --pvc, or pass --allow-overlaps")
    paths = []
    if not args.no_plots:
        out = Path(args.out)
        stem = f"{stats['sample']}_seed{args.seed}"
        paths.append(plot_cross_section(array, out / f"{stem}_cross_section.png"))
        paths.append(plot_tilt_histogram(array, tilt, out / f"{stem}_tilt_histogram.png", (stats["tilt_ks"], stats["tilt_ks_pvalue"])))
    if args.json:
        print_json({k: stats[k] for k in JSON_KEYS})
        return 0
    log = stats["log"]
    print(f"Platelet array of {stats['sample']} (seed {args.seed}), tile {stats['tile'][0]:.0f} × {stats['tile'][1]:.0f} µm, basecoat {stats['basecoat_thickness']:.0f} µm")
    print(f"  platelets              {stats['count']} ({array.thickness:g} µm thick)")
    print(f"  PVC                    {100 * stats['pvc']:.3f} % (target {100 * stats['pvc_target']:.1f} %)")
    print(f"  widths D10/D50/D90     {stats['width_d10']:.1f} / {stats['width_d50']:.1f} / {stats['width_d90']:.1f} µm")
    print(f"  mean tilt              {stats['tilt_mean_deg']:.2f}°  (KS D = {stats['tilt_ks']:.4f}, p = {stats['tilt_ks_pvalue']:.3f})")
    print(f"  residual overlaps      exact (SAT) {stats['overlaps_exact']}, mid-plane (Möller) {stats['overlaps_midplane']}")
    print(f"  re-placed platelets    {log.n_replaced} ({log.total_replacements} re-placements, most {log.max_replacements}; {log.n_failed} failed)")
    print(f"  generation time        {stats['seconds']:.2f} s")
    for p in paths:
        print(f"  wrote {p}")
    return 0
