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

`--inverse-grid` audits instead the grid the inverse layer traces through: the wave tables of the shipped
emulator's tracer (`WIDE_TRACER_SETTINGS`: 8 × 7 nodes over σ 0.015–0.15 µm × τ 0.25–2.0 µm, the tables
the tracer reads), at the centre of each of its 42 cells against a wave table built there with the same
options: the L1 above for `at` (what the tracer uses) and `build_at` at 0°, 20°, 40°, 60°, 70° and 80°;
the directional albedo of `at` (hemisphere quadrature of the diffuse part + the coherent part) against the
flat surface's reflectance (impedance boundary) + 3 SE of the direct table + 2·10⁻³ at 0–85°, and against
the direct table's albedo, and the same for `build_at`; and reciprocity of both. A second direct table from
other profiles (seed 1) measures the references' own statistical spread (their L1 against each other): a cell
is over the goal beyond that spread when it is over 3 % against both direct tables and further from each than
they are from each other. Each cell also records where the q_z continuation starts in the direct table and in
`build_at`'s (`BRDFTableGrid.build_arrays_at`): the construction switches at a coverage threshold, so the two
can continue from different nodes. What the L1 does to L*: the tracer forward map (common
random numbers, the main job's 65 536 rays × `--rays-factor`) at the cells where `at` is worst, with `at` and
with `build_at` under the same seed, at Silver #1's published tilt law and a wide one.

Writes experiments/output/grid_interpolation/summary.json and grid_interpolation.png (atomic), or with
`--inverse-grid` experiments/output/grid_interpolation/inverse_grid.json and inverse_grid.png.

Run: python experiments/grid_interpolation.py [--quick | --inverse-grid]   (≈ 6 min on 2 CPU cores with a cold
cache; the inverse grid ≈ 17 min with its 49 node tables cached, 72 tables built)
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

from paintjax import (  # noqa: E402
    TracerLStar,
    aluminium_index,
    atomic_savefig,
    atomic_write_json,
    enable_compilation_cache,
    platelet_brdf_grid,
    platelet_brdf_table,
    platelet_table_arrays,
)
from paintjax.brdf import TabulatedBRDF, hemisphere_directions, leontovich_reflectance  # noqa: E402
from paintjax.inverse import WIDE_TRACER_SETTINGS  # noqa: E402

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


@eqx.filter_jit
def _evaluate(brdf, wi, wo):
    return brdf.evaluate(wi, wo)


def _direction(theta_deg, phi_deg=0.0):
    t, p = np.deg2rad(theta_deg), np.deg2rad(phi_deg)
    return np.stack(np.broadcast_arrays(np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)), -1)


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


INVERSE_INCIDENCES = (0.0, 20.0, 40.0, 60.0, 70.0, 80.0)
ENERGY_INCIDENCES = (0.0, 20.0, 40.0, 60.0, 70.0, 80.0, 85.0)


def _first_continued(arrays: dict) -> dict:
    """Where the q_z continuation starts: the first continued incidence [deg] (None: none) and the in-plane coverage
    of the incidences before and at it (the reference's coverage is ≥ `MIN_COVERAGE`, the next one's below)."""
    continued = np.asarray(arrays["continued"], bool)
    if not continued.any():
        return {"from_deg": None}
    j = int(np.argmax(continued))
    cover = np.asarray(arrays["lobe_coverage"], float)
    return {"from_deg": float(np.asarray(arrays["incidence_deg"])[j]), "coverage_reference": float(cover[j - 1]), "coverage_first": float(cover[j])}


def audit_cell(grid, q, options: dict, wo, wt, rng) -> dict:
    """One cell centre q = (σ, τ) of the inverse layer's grid: `at` and `build_at` against a direct table, their energy and reciprocity."""
    def table(a):  # a table read as the grid's own tables are
        return TabulatedBRDF.from_arrays(a, coherent=grid.coherent, coherent_width=grid.coherent_width, n_medium=grid.n_medium)

    arrays, _ = platelet_table_arrays(*q, **options)
    built_arrays = grid.build_arrays_at(*q)
    direct, second, built = table(arrays), table(platelet_table_arrays(*q, seed=1, **options)[0]), table(built_arrays)
    at = grid.at(*q)
    mu_nodes = np.cos(np.deg2rad(np.asarray(arrays["incidence_deg"], float)))
    metal = complex(np.asarray(aluminium_index(grid.wavelength_um)))

    def albedo(brdf, wi, mu):  # hemisphere quadrature of the diffuse part + the coherent part
        return float(np.sum(np.asarray(_incoherent(brdf, wi, wo)) * wt)) + float(brdf.coherent_reflectance(jnp.asarray(mu)))

    energy = []
    for ti in ENERGY_INCIDENCES:
        mu = float(np.cos(np.deg2rad(ti)))
        wi = jnp.asarray(_direction(ti))
        se = float(np.interp(mu, mu_nodes[::-1], np.asarray(arrays["reflectance_se"], float)[::-1]))
        flat = float(leontovich_reflectance(mu, grid.n_medium, metal))
        e = {"incidence_deg": ti, "albedo_at": albedo(at, wi, mu), "albedo_build_at": albedo(built, wi, mu), "albedo_direct": albedo(direct, wi, mu),
             "flat": flat, "se": se, "allowed_excess": 3 * se + 2e-3}
        energy.append(e | {"excess_over_flat": max(e["albedo_at"], e["albedo_build_at"]) - flat})
    a = _direction(rng.uniform(0, 85, 200), rng.uniform(0, 360, 200))
    b = _direction(rng.uniform(0, 85, 200), rng.uniform(0, 360, 200))

    def reciprocity(brdf):  # largest relative |f(a→b) − f(b→a)| over 200 random direction pairs
        fab, fba = np.asarray(_evaluate(brdf, jnp.asarray(a), jnp.asarray(b))), np.asarray(_evaluate(brdf, jnp.asarray(b), jnp.asarray(a)))
        return float(np.max(np.abs(fab - fba) / np.maximum(np.abs(fab), 1e-300)))
    return {"sigma_um": q[0], "tau_um": q[1], "at": {str(ti): l1(at, direct, ti, wo, wt) for ti in INVERSE_INCIDENCES},
            "build_at": {str(ti): l1(built, direct, ti, wo, wt) for ti in INVERSE_INCIDENCES}, "energy": energy,
            "direct_vs_direct": {str(ti): l1(second, direct, ti, wo, wt) for ti in INVERSE_INCIDENCES},
            # where the q_z continuation starts (None: not continued) and the in-plane coverage there, direct and build_at
            "continuation": {"direct": _first_continued(arrays), "build_at": _first_continued(built_arrays)},
            "at_vs_second": {str(ti): l1(at, second, ti, wo, wt) for ti in INVERSE_INCIDENCES},
            "build_at_vs_second": {str(ti): l1(built, second, ti, wo, wt) for ti in INVERSE_INCIDENCES},
            "energy_ok": all(e["excess_over_flat"] <= e["allowed_excess"] for e in energy),
            "albedo_at_vs_direct_max": max(abs(e["albedo_at"] / e["albedo_direct"] - 1.0) for e in energy),
            "albedo_build_at_vs_direct_max": max(abs(e["albedo_build_at"] / e["albedo_direct"] - 1.0) for e in energy),
            "reciprocity_max_relative": max(reciprocity(at), reciprocity(built))}


def audit_inverse_grid(wo, wt, quick: bool = False) -> dict:
    """Every cell centre of the shipped emulator's tracer grid (`WIDE_TRACER_SETTINGS`), see the module docstring."""
    settings = WIDE_TRACER_SETTINGS
    fn = TracerLStar(settings)
    grid = fn.brdf_grid()
    options = dict(source=settings.table_source, n_medium=grid.n_medium)
    s_nodes, t_nodes = settings.nodes("sigma"), settings.nodes("tau")
    centres = [(float(np.sqrt(s_nodes[i] * s_nodes[i + 1])), float(np.sqrt(t_nodes[j] * t_nodes[j + 1])))
               for i in range(len(s_nodes) - 1) for j in range(len(t_nodes) - 1)]
    if quick:
        centres = centres[:2]
    rng = np.random.default_rng(0)
    cells = []
    for k, q in enumerate(centres):
        t0 = time.perf_counter()
        c = audit_cell(grid, q, options, wo, wt, rng)
        cells.append(c)
        print(f"cell {k + 1}/{len(centres)} σ {q[0]:.4f} τ {q[1]:.3f}: at {100 * max(c['at'].values()):.2f} %, build_at "
              f"{100 * max(c['build_at'].values()):.2f} %, two direct tables {100 * max(c['direct_vs_direct'].values()):.2f} %, energy {'ok' if c['energy_ok'] else 'EXCEEDS'}, reciprocity "
              f"{c['reciprocity_max_relative']:.1e} ({time.perf_counter() - t0:.0f} s)", flush=True)
    worst = {m: max(max(c[m].values()) for c in cells) for m in ("at", "build_at")}
    # Beyond the references' own spread: over the goal against both direct tables (profile seeds 0 and 1) and
    # further from each than the two are from each other.
    over = {m: [{"sigma_um": c["sigma_um"], "tau_um": c["tau_um"], "incidence_deg": float(ti), "l1": v, "l1_vs_second": c[f"{m}_vs_second"][ti],
                 "direct_vs_direct": c["direct_vs_direct"][ti], "continuation": c["continuation"],
                 "beyond_reference_spread": min(v, c[f"{m}_vs_second"][ti]) > max(GOAL, c["direct_vs_direct"][ti])}
                for c in cells for ti, v in c[m].items() if v > GOAL] for m in ("at", "build_at")}
    switched = [c for c in cells if c["continuation"]["direct"]["from_deg"] != c["continuation"]["build_at"]["from_deg"]]
    return {"goal": GOAL, "sigma_nodes_um": s_nodes.tolist(), "tau_nodes_um": t_nodes.tolist(), "table_options": options,
            "incidences_deg": INVERSE_INCIDENCES, "energy_incidences_deg": ENERGY_INCIDENCES, "cells": cells, "worst": worst,
            "cells_over_goal": {m: len({(o["sigma_um"], o["tau_um"]) for o in over[m]}) for m in over}, "over_goal": over,
            "cells_over_goal_beyond_reference_spread": {m: len({(o["sigma_um"], o["tau_um"]) for o in over[m] if o["beyond_reference_spread"]})
                                                        for m in over},
            "direct_vs_direct_worst": max(max(c["direct_vs_direct"].values()) for c in cells),
            "continuation_switched": [{"sigma_um": c["sigma_um"], "tau_um": c["tau_um"], **c["continuation"]} for c in switched],
            "energy_ok": all(c["energy_ok"] for c in cells), "reciprocity_max_relative": max(c["reciprocity_max_relative"] for c in cells)}


#: Tilt laws (gamma shape, scale [deg]) of the L* comparison: Silver #1's published law and a wide one.
CONSEQUENCE_TILTS = ((2.29, 2.18), (2.0, 4.5))


def l_star_consequence(cells: list[dict], worst: int, seeds=(0, 1), rays_factor: int = 4) -> list[dict]:
    """The tracer forward map's L* with `at` and with `build_at` at the `worst` cells (largest `at` L1), same seeds."""
    fn = TracerLStar(WIDE_TRACER_SETTINGS)
    grid = fn.brdf_grid()
    rays = int(fn.settings.rays) * rays_factor
    out = []
    for c in sorted(cells, key=lambda c: -max(c["at"].values()))[:worst]:
        tables = {"at": grid.at(c["sigma_um"], c["tau_um"]), "build_at": grid.build_at(c["sigma_um"], c["tau_um"])}
        for shape, scale in CONSEQUENCE_TILTS:
            for seed in seeds:
                runs = {m: fn.trace_one(shape, scale, c["sigma_um"], c["tau_um"], seed=seed, rays=rays, brdf=b) for m, b in tables.items()}
                d = np.asarray(runs["at"].L_star) - np.asarray(runs["build_at"].L_star)
                se = np.hypot(np.asarray(runs["at"].L_star_se), np.asarray(runs["build_at"].L_star_se))
                out.append({"sigma_um": c["sigma_um"], "tau_um": c["tau_um"], "shape": shape, "scale": scale, "seed": seed, "rays": rays,
                            "L_at": np.asarray(runs["at"].L_star).tolist(), "L_build_at": np.asarray(runs["build_at"].L_star).tolist(),
                            "difference": d.tolist(), "combined_se": se.tolist()})
                print(f"σ {c['sigma_um']:.4f} τ {c['tau_um']:.3f}, tilt ({shape:g}, {scale:g}°), seed {seed}: L*(at) − L*(build_at) = "
                      f"{np.array2string(d, precision=2)} (SE {np.array2string(se, precision=2)})", flush=True)
    return out


def plot_inverse_grid(summary: dict, path: Path) -> None:
    s_nodes, t_nodes = np.asarray(summary["sigma_nodes_um"]), np.asarray(summary["tau_nodes_um"])
    ns, nt = len(s_nodes) - 1, len(t_nodes) - 1
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2))
    for ax, method in zip(axes[:2], ("at", "build_at")):
        m = np.full((nt, ns), np.nan)
        for k, c in enumerate(summary["cells"]):
            m[k % nt, k // nt] = 100 * max(c[method].values())
        im = ax.pcolormesh(s_nodes, t_nodes, m, cmap="viridis", vmin=0, vmax=max(6.0, np.nanmax(m)), shading="flat")
        for k, c in enumerate(summary["cells"]):
            ti = max(c[method], key=c[method].get)
            v, ref = 100 * c[method][ti], 100 * c["direct_vs_direct"][ti]
            ax.text(c["sigma_um"], c["tau_um"], f"{v:.1f}\n({ref:.1f})", ha="center", va="center", fontsize=5.5, color="w" if v < 3 else "r")
        ax.set_xscale("log"), ax.set_yscale("log")
        ax.set_xticks(s_nodes, [f"{1000 * v:.0f}" for v in s_nodes]), ax.set_yticks(t_nodes, [f"{v:.2f}" for v in t_nodes])
        ax.set_xticks([], minor=True), ax.set_yticks([], minor=True)
        ax.set_xlabel("σ [nm] (grid nodes)"), ax.set_ylabel("τ [µm] (grid nodes)")
        ax.set_title(f"`{method}` vs direct table: worst L1 over 0–80° [%] (goal 3);\n"
                     "in brackets two direct tables (other profiles) at that incidence", fontsize=8)
        fig.colorbar(im, ax=ax)
    ax = axes[2]
    for c in summary["cells"]:
        e = c["energy"]
        ax.plot([x["incidence_deg"] for x in e], [(x["albedo_at"] - x["flat"]) / x["flat"] * 100 for x in e], color="C0", lw=0.6, alpha=0.6)
        ax.plot([x["incidence_deg"] for x in e], [(x["albedo_at"] / x["albedo_direct"] - 1) * 100 for x in e], color="C1", lw=0.6, alpha=0.6)
        ax.plot([x["incidence_deg"] for x in e], [(x["albedo_build_at"] / x["albedo_direct"] - 1) * 100 for x in e], color="C2", lw=0.6, alpha=0.6)
    ax.plot([], [], color="C0", label="`at` albedo vs flat surface")
    ax.plot([], [], color="C1", label="`at` albedo vs direct table")
    ax.plot([], [], color="C2", label="`build_at` albedo vs direct table")
    ax.axhline(0, color="k", lw=0.8)
    ax.set_xlabel("incidence [deg]"), ax.set_ylabel("relative difference [%]")
    ax.set_title("energy at the 36 cell centres", fontsize=9)
    ax.legend(fontsize=7)
    fig.suptitle("The inverse layer's platelet BRDF grid (python experiments/grid_interpolation.py --inverse-grid)", fontsize=10)
    fig.tight_layout()
    atomic_savefig(fig, path, dpi=130)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="two points, two ratios (a smoke run)")
    ap.add_argument("--inverse-grid", action="store_true", help="audit the shipped emulator's tracer grid, cell by cell")
    ap.add_argument("--worst", type=int, default=3, help="with --inverse-grid: cells traced with `at` and `build_at` (default 3)")
    args = ap.parse_args(argv)
    enable_compilation_cache()
    if args.inverse_grid:
        wo, wt = hemisphere_directions()
        t0 = time.perf_counter()
        summary = audit_inverse_grid(wo, wt, quick=args.quick) | {"n_medium": 1.5}
        summary["l_star_consequence"] = l_star_consequence(summary["cells"], 1 if args.quick else args.worst, seeds=(0,) if args.quick else (0, 1))
        summary["seconds"] = time.perf_counter() - t0
        OUT.mkdir(parents=True, exist_ok=True)
        if not args.quick:
            atomic_write_json(OUT / "inverse_grid.json", summary)
            plot_inverse_grid(summary, OUT / "inverse_grid.png")
        print(f"worst: at {100 * summary['worst']['at']:.2f} %, build_at {100 * summary['worst']['build_at']:.2f} %; cells over "
              f"{100 * GOAL:g} %: {summary['cells_over_goal']}, of them beyond the two direct tables' spread "
              f"{summary['cells_over_goal_beyond_reference_spread']}; energy {'ok' if summary['energy_ok'] else 'EXCEEDED'}; reciprocity "
              f"{summary['reciprocity_max_relative']:.1e}; the q_z continuation starts elsewhere than in the direct table in "
              f"{len(summary['continuation_switched'])} cells: {summary['continuation_switched']}")
        return 0
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
