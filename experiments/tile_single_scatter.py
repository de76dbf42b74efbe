"""Experiment: mirror single scattering tile by tile: tracer, the tile's own model, and the ensemble model.

The scene of the tracer's thin-mirror tests (`tests/test_tracer_single_scatter.py`, `thin_mirror_scene`): a Boolean
layer of 7360 thin mirror platelets (w = 1 µm, t = 0.02 µm, mean free depth 50 µm, Silver #1 tilt
law) in a 40 × 40 × 230 µm tile under a flat coat of n = 1.5, 45° illumination, detectors at
15°, 25°, 45° with 8° apertures, black side walls (`edges="absorb"`). For each of `--tiles`
independent tiles (seeds seed, seed + 1, …):

* the tile's own single-scatter model (`_tile_single_scatter`: its tilts, widths and boxes, the
  visibility of the faces walked through its grid), and its deviation from the ensemble model
  (`microfacet_reflectance_factor` with the hot spot and the side walls). The mean over tiles
  tests the ensemble model itself (standard error from the tile-to-tile spread);
* on the first `--tracer-tiles` tiles, the tracer (flat coat; `--rays` rays, ray seed 7 as in the
  test) against the tile model, in units of the combined standard error;
* on the same tiles, the tracer under a wavy coat (RMS slope 12°) against the wavy ensemble model:
  the tile-to-tile spread that the wavy test cannot see.

`--tile` widens the tile (same platelet density): the tile-to-tile spread falls with the tile's
area, so the mean over tiles checks the ensemble model more finely (and shows any effect of the
periodic images on the 40 µm tile).

Writes {--out}/{summary.json, tile_single_scatter.png} (atomic; default
experiments/output/tile_single_scatter).

Run: python experiments/tile_single_scatter.py [--tiles 16] [--tracer-tiles 6] [--seed 2] [--rays 200000] [--samples 100000]
     [--tile 40] [--out DIR]
e.g. python experiments/tile_single_scatter.py --tile 80 --tiles 8 --tracer-tiles 0 --seed 100 --out experiments/output/tile_single_scatter_80um
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from paintjax import (  # noqa: E402
    GammaTilt,
    HotSpot,
    MirrorBRDF,
    atomic_savefig,
    atomic_write_json,
    boolean_platelet_array,
    build_grid,
    enable_compilation_cache,  # noqa: E402
    ma98_geometry,
    trace,
)
from paintjax.instrument import microfacet_reflectance_factor  # noqa: E402
from paintjax.tracer import (
    TracerOptions,  # noqa: E402
    tile_mirror_single_scatter,  # noqa: E402
)

OUT = Path(__file__).parent / "output" / "tile_single_scatter"
N, WIDTH, THICKNESS, MEAN_FREE_DEPTH, FILM, TILE = 1.5, 1.0, 0.02, 50.0, 230.0, 40.0  # the tracer tests' thin-mirror scene (TILE: default)
TILT = (2.29, 2.18)
ASPECULAR = (15.0, 25.0, 45.0)
WAVINESS = 12.0


def thin_mirror_tile(seed: int, tile: float = TILE):
    count = int(round(tile * tile * FILM / (MEAN_FREE_DEPTH * WIDTH**2)))
    array = boolean_platelet_array(seed, count, tile=(tile, tile), basecoat_thickness=FILM, width=WIDTH, thickness=THICKNESS,
                                   tilt=TILT, margin=0.6)
    return array, build_grid(array, 4.0)


def ensemble(geometry, mirror, waviness_deg: float) -> np.ndarray:
    hot_spot = HotSpot.for_layer((WIDTH * 0.99999, WIDTH, WIDTH * 1.00001), thickness=THICKNESS, pvc=THICKNESS / MEAN_FREE_DEPTH)
    return np.asarray(microfacet_reflectance_factor(geometry, GammaTilt(*TILT), n=N, platelet=mirror, exit_occlusion=True, hot_spot=hot_spot,
                                                    side_walls=THICKNESS / WIDTH, aperture_nodes=12, waviness_deg=waviness_deg))


def run(tiles: int, tracer_tiles: int, seed: int, rays: int, samples: int, tile: float = TILE) -> dict:
    geometry = ma98_geometry(45.0, ASPECULAR, detector_aperture_deg=8.0)
    mirror = MirrorBRDF(n_binder=N)
    flat, wavy = ensemble(geometry, mirror, 0.0), ensemble(geometry, mirror, WAVINESS)
    rows = []
    for k in range(tiles):
        t0 = time.perf_counter()
        array, grid = thin_mirror_tile(seed + k, tile)
        model = tile_mirror_single_scatter(array, geometry, mirror, grid, n=N, samples=samples, seed=0)
        row = {"seed": seed + k, "tile_model": model["reflectance_factor"].tolist(), "tile_model_se": model["se"].tolist(),
               "visibility": model["visibility"].tolist(), "tile_over_ensemble": (model["reflectance_factor"] / flat - 1.0).tolist()}
        if k < tracer_tiles:
            for name, waviness in (("tracer", 0.0), ("tracer_wavy", WAVINESS)):
                res = trace(array, geometry, mirror, grid=grid, n=N, primer_albedo=0.0, rays=rays, seed=7, single_scatter=True,
                            waviness_deg=waviness, options=TracerOptions(lanes=1024, steps_per_call=16, batches=32, edges="absorb"))
                row[name], row[name + "_se"] = res.reflectance_factor.tolist(), res.reflectance_factor_se.tolist()
            R, se = np.asarray(row["tracer"]), np.asarray(row["tracer_se"])
            row["tracer_minus_tile_z"] = ((R - model["reflectance_factor"]) / np.hypot(se, model["se"])).tolist()
            row["wavy_tracer_over_ensemble"] = (np.asarray(row["tracer_wavy"]) / wavy - 1.0).tolist()
        rows.append(row)
        print(f"tile {k + 1}/{tiles} (seed {seed + k}, {time.perf_counter() - t0:.0f} s): tile model / ensemble − 1 = "
              f"{np.round(row['tile_over_ensemble'], 3)}" + (f", tracer − tile = {np.round(row['tracer_minus_tile_z'], 2)} SE, "
                                                            f"wavy tracer / ensemble − 1 = {np.round(row['wavy_tracer_over_ensemble'], 3)}"
                                                            if "tracer" in row else ""), flush=True)
    dev = np.array([r["tile_over_ensemble"] for r in rows])
    traced = [r for r in rows if "tracer" in r]
    wavy_dev = np.array([r["wavy_tracer_over_ensemble"] for r in traced])
    wavy_se = np.array([np.asarray(r["tracer_wavy_se"]) / np.asarray(r["tracer_wavy"]) for r in traced])
    return {
        "aspecular_deg": list(ASPECULAR), "tile_um": tile, "platelets": int(array.count), "tiles": tiles, "seed": seed, "rays": rays, "samples": samples, "waviness_deg": WAVINESS,
        "ensemble_model": flat.tolist(), "ensemble_model_wavy": wavy.tolist(), "rows": rows,
        "tile_over_ensemble_mean": dev.mean(0).tolist(), "tile_over_ensemble_sem": (dev.std(0, ddof=1) / np.sqrt(tiles)).tolist(),
        "tile_to_tile_sd": dev.std(0, ddof=1).tolist(),
        "tracer_minus_tile_z_max": np.abs([r["tracer_minus_tile_z"] for r in traced]).max(0).tolist() if traced else None,
        "wavy_tile_to_tile_sd": wavy_dev.std(0, ddof=1).tolist() if len(traced) > 1 else None,
        "wavy_ray_se_rms": np.sqrt((wavy_se**2).mean(0)).tolist() if traced else None,
    }


def plot(result: dict, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10.5, 4.2))
    seeds = [r["seed"] for r in result["rows"]]
    for j, g in enumerate(result["aspecular_deg"]):
        dev = 100 * np.array([r["tile_over_ensemble"][j] for r in result["rows"]])
        se = 100 * np.array([r["tile_model_se"][j] / r["tile_model"][j] for r in result["rows"]])
        axes[0].errorbar(np.array(seeds) + 0.2 * (j - 1), dev, yerr=se, fmt="o", ms=3, color=f"C{j}", label=f"{g:g}°: tile model")
        traced = [r for r in result["rows"] if "tracer" in r]
        axes[0].errorbar([r["seed"] + 0.2 * (j - 1) + 0.08 for r in traced],
                         [100 * (r["tracer"][j] / result["ensemble_model"][j] - 1) for r in traced],
                         yerr=[100 * r["tracer_se"][j] / result["ensemble_model"][j] for r in traced], fmt="x", ms=4, color=f"C{j}")
        axes[1].errorbar(np.array([r["seed"] for r in traced]) + 0.2 * (j - 1), [r["tracer_minus_tile_z"][j] for r in traced], fmt="o",
                         ms=3, color=f"C{j}", label=f"{g:g}°")
    axes[0].plot([], [], "kx", label="tracer")
    axes[0].axhline(0.0, color="k", lw=0.8)
    axes[0].set_xlabel("tile seed")
    axes[0].set_ylabel("R / ensemble model − 1 [%]")
    axes[0].set_title("One tile against the ensemble of tiles", fontsize=9)
    axes[0].legend(fontsize=7)
    for y in (-4, 4):
        axes[1].axhline(y, color="0.6", ls=":")
    axes[1].axhline(0.0, color="k", lw=0.8)
    axes[1].set_xlabel("tile seed")
    axes[1].set_ylabel("(tracer − tile model) / combined SE")
    axes[1].set_title("Tracer against the model of the same tile", fontsize=9)
    axes[1].legend(fontsize=7)
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.suptitle(f"Thin mirror platelets, single scattering, 8° apertures, {result['tile_um']:g} µm tiles, {result['rays']} rays per tracer run",
                 fontsize=9)
    path = atomic_savefig(fig, path)
    plt.close(fig)
    return path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tiles", type=int, default=16, help="independent tiles (seeds seed … seed + tiles − 1)")
    ap.add_argument("--tracer-tiles", type=int, default=6, help="of those, how many the tracer also runs on (flat and wavy coat)")
    ap.add_argument("--seed", type=int, default=2)
    ap.add_argument("--rays", type=int, default=200_000, help="tracer rays per run")
    ap.add_argument("--samples", type=int, default=100_000, help="visibility samples per detector of the tile model")
    ap.add_argument("--tile", type=float, default=TILE, help=f"tile side [µm] at the same platelet density (default {TILE:g}, the test's)")
    ap.add_argument("--out", type=Path, default=OUT, help="output folder")
    args = ap.parse_args(argv)
    if args.tiles < 2:
        ap.error(f"--tiles must be an integer ≥ 2 (the ensemble's standard error is the tile-to-tile spread), got {args.tiles}")
    if not 0 <= args.tracer_tiles <= args.tiles:
        ap.error(f"--tracer-tiles must lie in [0, --tiles = {args.tiles}], got {args.tracer_tiles}")
    if args.rays < 1 or args.samples < 2:
        ap.error(f"--rays must be ≥ 1 and --samples ≥ 2, got {args.rays}, {args.samples}")
    if not args.tile >= 2.0:
        ap.error(f"--tile must be ≥ 2 µm (√2 platelet widths and more), got {args.tile}")
    if args.seed < 0:
        ap.error(f"--seed must be a non-negative integer, got {args.seed}")
    enable_compilation_cache()
    result = run(args.tiles, args.tracer_tiles, args.seed, args.rays, args.samples, args.tile)
    args.out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(args.out / "summary.json", result)
    print("tile model / ensemble − 1 over", args.tiles, "tiles:", np.round(result["tile_over_ensemble_mean"], 4), "± (SEM)",
          np.round(result["tile_over_ensemble_sem"], 4), "; tile-to-tile SD", np.round(result["tile_to_tile_sd"], 3))
    print("max |tracer − tile| / SE:", result["tracer_minus_tile_z_max"], "; wavy tile-to-tile SD", result["wavy_tile_to_tile_sd"],
          "against ray SE", result["wavy_ray_se_rms"])
    print(f"plot: {plot(result, args.out / 'tile_single_scatter.png')}; data: {args.out / 'summary.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
