"""Experiment: how much a tracer run's L* depends on its platelet array, and how the tile's size changes that.

An array of a finite tile is one draw of the microstructure: independent arrays at the same θ give different L*,
beyond the rays' own standard error. The inverse layer's tracer (`WIDE_TRACER_SETTINGS`, the forward tracer,
65 536 rays) uses a 400 µm tile; `paintjax simulate` uses the sample's 752 µm. At the θ where the emulator's
check draws found the largest spread (the smooth, wide-tilt corner of the box: Silver #1's and Silver #2's
L*-alone posteriors, `experiments/calibrated_posterior.py`) and at the published Silver #1 inputs, `--arrays`
independent runs per tile (fresh generator arrays and rays, seeds 5000 + i, `TracerLStar.evaluate(mode="rsa")`,
otherwise the inverse layer's settings) give per angle: the SD between arrays, the rays' SE within one array (RMS),
and the array part of the spread, √max(SD² − SE², 0).

Writes experiments/output/array_spread/summary.json and array_spread.png (atomic).
Run from the repository root: python experiments/array_spread.py [--arrays 6]   (≈ 10 min on 2 CPU cores)
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from paintjax import atomic_savefig, atomic_write_json, enable_compilation_cache  # noqa: E402
from paintjax.inverse import WIDE_TRACER_SETTINGS, TracerLStar  # noqa: E402

OUT = Path("experiments/output/array_spread")
#: (label, θ = shape, scale [deg], σ [µm], τ [µm])
POINTS = (("smooth, wide tilt (Silver #1 L*-alone draw)", (1.514, 4.213, 0.02169, 0.3025)),
          ("smooth, wide tilt (Silver #2 L*-alone draw)", (1.703, 4.476, 0.0201, 0.306)),
          ("published Silver #1 inputs", (2.29, 2.18, 0.051, 0.64)))
TILES_UM = (400.0, 752.0)
SEED0 = 5000


def spread(theta, tile_um: float, arrays: int) -> dict:
    fn = TracerLStar(dataclasses.replace(WIDE_TRACER_SETTINGS, tile_um=tile_um))
    rows, ses = [], []
    for i in range(arrays):
        li, si = fn.evaluate(np.asarray(theta, float)[None], seed=SEED0 + i, return_se=True, mode="rsa")
        rows.append(np.asarray(li)[0]), ses.append(np.asarray(si)[0])
    L, se = np.asarray(rows), np.asarray(ses)
    sd = L.std(axis=0, ddof=1)
    rays = np.sqrt(np.mean(se**2, axis=0))
    return {"angles": list(fn.angles), "L": L.tolist(), "se": se.tolist(), "mean": L.mean(0).tolist(), "sd": sd.tolist(),
            "rays_se": rays.tolist(), "array_part": np.sqrt(np.maximum(sd**2 - rays**2, 0.0)).tolist()}


def plot(out: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(out["points"]), figsize=(5 * len(out["points"]), 3.8), squeeze=False)
    for ax, p in zip(axes[0], out["points"]):
        for tile, c in zip(TILES_UM, ("C0", "C1")):
            r = p["tiles"][str(tile)]
            a = np.asarray(r["angles"])
            ax.plot(a, r["sd"], "o-", color=c, label=f"{tile:.0f} µm tile: SD between arrays")
            ax.plot(a, r["rays_se"], "s--", color=c, alpha=0.6, label=f"{tile:.0f} µm tile: rays' SE in one array")
        ax.set_xlabel("aspecular angle [deg]"), ax.set_ylabel("L*")
        ax.set_title(f"{p['label']}\nθ = {tuple(p['theta'])}", fontsize=8)
        ax.legend(fontsize=6)
    fig.suptitle(f"L* from array to array ({out['arrays']} independent arrays per tile; python experiments/array_spread.py)", fontsize=10)
    fig.tight_layout()
    atomic_savefig(fig, path, dpi=120)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--arrays", type=int, default=6, help="independent arrays per θ and tile (≥ 2)")
    args = ap.parse_args(argv)
    if args.arrays < 2:
        raise SystemExit("--arrays must be at least 2")
    enable_compilation_cache()
    t0 = time.perf_counter()
    out = {"arrays": args.arrays, "seeds": [SEED0, SEED0 + args.arrays - 1], "rays": WIDE_TRACER_SETTINGS.rays, "points": []}
    for label, theta in POINTS:
        entry = {"label": label, "theta": list(theta), "tiles": {}}
        for tile in TILES_UM:
            r = spread(theta, tile, args.arrays)
            entry["tiles"][str(tile)] = r
            print(f"{label}, {tile:.0f} µm tile: SD between arrays {np.round(r['sd'], 2).tolist()}, rays' SE {np.round(r['rays_se'], 2).tolist()}, "
                  f"array part {np.round(r['array_part'], 2).tolist()} (angles {r['angles']})", flush=True)
        out["points"].append(entry)
    out["seconds"] = time.perf_counter() - t0
    OUT.mkdir(parents=True, exist_ok=True)
    atomic_write_json(OUT / "summary.json", out)
    plot(out, OUT / "array_spread.png")
    print(f"done in {out['seconds']:.0f} s: {OUT}/summary.json", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
