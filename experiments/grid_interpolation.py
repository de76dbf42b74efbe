"""Experiment: the (σ, τ) grid's interpolated platelet tables against tables built directly, by node ratio.

The inverse layer's tracer reads the platelet BRDF between the nodes of a grid of tables
(`BRDFTableGrid.at`: differentiable; `build_at`: host-side, not smooth in (σ, τ)). Here, for grids
of node ratio 1.41 (the tracer's grids: 1.35–1.41), 1.2 and 1.1 about points that cover the box
σ 0.01–0.30 µm × τ 0.2–2.0 µm (binder n = 1.5, λ0 = 0.5 µm, aluminium, coherent part as a delta),
each cell's centre is compared with a table built there: the scattered-power weighted L1 of the
diffuse BRDF over the hemisphere at 0°, 40°, 70° and 80° incidence (the test's measure,
`tests/test_platelet_brdf_truth.py`). Tables from the closed-form 1-D Kirchhoff lobes (fast; the
same table machinery as the wave tables), and the measured roughness (σ 0.051, τ 0.64 µm) with wave
tables of 8 profiles too. Goal: within 3 %.

Writes experiments/output/grid_interpolation/summary.json and grid_interpolation.png (atomic).

Run: python experiments/grid_interpolation.py [--quick]   (≈ 6 min on 2 CPU cores with a cold cache)
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import matplotlib  # noqa: E402
import numpy as np  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from paintjax import atomic_savefig, atomic_write_json, enable_compilation_cache, platelet_brdf_grid, platelet_brdf_table  # noqa: E402
from paintjax.brdf import hemisphere_directions  # noqa: E402

OUT = Path(__file__).parent / "output" / "grid_interpolation"
RATIOS = (1.41, 1.2, 1.1)
INCIDENCES = (0.0, 40.0, 70.0, 80.0)
#: (σ, τ) [µm] at the centre of each grid: a 3 × 3 cover of the box, the steep surface of the tests, and
#: the measured roughness (Kirchhoff and wave tables)
POINTS = [(s, t, "kirchhoff") for s in (0.012, 0.05, 0.25) for t in (0.22, 0.64, 1.8)] + [(0.14, 0.39, "kirchhoff"), (0.051, 0.64, "kirchhoff"),
                                                                                        (0.051, 0.64, "wave")]
GOAL = 0.03


@eqx.filter_jit
def _incoherent(brdf, wi, wo):
    return brdf.incoherent(wi, wo)


def l1(a, b, theta_i: float, wo, wt) -> float:
    """Scattered-power weighted L1 of a against b's diffuse BRDF at incidence θ_i [deg]."""
    t = np.deg2rad(theta_i)
    wi = jnp.asarray([np.sin(t), 0.0, np.cos(t)])
    fa, fb = np.asarray(_incoherent(a, wi, wo)), np.asarray(_incoherent(b, wi, wo))
    return float(np.sum(np.abs(fa - fb) * wt) / np.sum(fb * wt))


def study(sigma: float, tau: float, source: str, ratio: float, wo, wt) -> dict:
    kw = dict(source=source) if source == "kirchhoff" else dict(num_profiles=8)
    grid = platelet_brdf_grid([sigma / ratio, sigma, sigma * ratio], [tau / ratio, tau, tau * ratio], coherent="delta", **kw)
    r = np.sqrt(ratio)
    cells = []
    for q in [(sigma * a, tau * b) for b in (1 / r, r) for a in (1 / r, r)]:
        direct = platelet_brdf_table(*q, coherent="delta", **kw)
        at, built = grid.at(*q), grid.build_at(*q)
        cells.append({"sigma_um": q[0], "tau_um": q[1], "at": {str(ti): l1(at, direct, ti, wo, wt) for ti in INCIDENCES},
                      "build_at": {str(ti): l1(built, direct, ti, wo, wt) for ti in INCIDENCES}})
    worst = {m: max(max(c[m].values()) for c in cells) for m in ("at", "build_at")}
    return {"sigma_um": sigma, "tau_um": tau, "source": source, "ratio": ratio, "cells": cells, "worst": worst}


def plot(summary: dict, path: Path) -> None:
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    for ax, method in zip(axes, ("at", "build_at")):
        for k, (s, t, src) in enumerate(POINTS):
            rows = [r for r in summary["runs"] if (r["sigma_um"], r["tau_um"], r["source"]) == (s, t, src)]
            ax.plot([r["ratio"] for r in rows], [100 * r["worst"][method] for r in rows], marker="o", color=f"C{k % 10}",
                    ls="-" if src == "kirchhoff" else "--", label=f"σ {s:g}, τ {t:g} µm ({src})")
        ax.axhline(100 * GOAL, color="k", lw=0.8, ls=":")
        ax.set_xscale("log"), ax.set_yscale("log")
        ax.set_xticks(RATIOS, [f"{x:g}" for x in RATIOS])
        ax.set_xticks([], minor=True)
        ax.set_xlabel("node ratio of the grid")
        ax.set_title(f"`{method}`: worst L1 over the 4 cells and 0–80° incidence", fontsize=9)
    axes[0].set_ylabel("L1 against a direct table [%]")
    axes[1].legend(fontsize=6, ncol=2)
    fig.suptitle("Interpolated platelet tables against direct ones (python experiments/grid_interpolation.py)", fontsize=10)
    fig.tight_layout()
    atomic_savefig(fig, path, dpi=130)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="two points, two ratios (a smoke run)")
    args = ap.parse_args(argv)
    enable_compilation_cache()
    points, ratios = (POINTS[:2], RATIOS[:2]) if args.quick else (POINTS, RATIOS)
    wo, wt = hemisphere_directions()  # the tests' quadrature (tests/test_platelet_brdf_truth.py)
    t0 = time.perf_counter()
    runs = []
    for s, t, src in points:
        for ratio in ratios:
            r = study(s, t, src, ratio, wo, wt)
            runs.append(r)
            print(f"σ {s:g} τ {t:g} ({src}), ratio {ratio:g}: worst at {100 * r['worst']['at']:.2f} %, "
                  f"build_at {100 * r['worst']['build_at']:.2f} %", flush=True)
    summary = {"goal": GOAL, "incidences_deg": INCIDENCES, "ratios": ratios, "n_medium": 1.5, "wavelength_um": 0.5,
               "measure": "∫|f_interp − f_direct| cos dω / ∫ f_direct cos dω over the hemisphere (diffuse part), at each cell's centre",
               "runs": runs, "seconds": time.perf_counter() - t0}
    OUT.mkdir(parents=True, exist_ok=True)
    atomic_write_json(OUT / "summary.json", summary)
    if not args.quick:
        plot(summary, OUT / "grid_interpolation.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
