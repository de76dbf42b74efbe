"""Experiment: is the shipped emulator's bias against fresh arrays linear in σ, as its run-to-run term assumes?

The wide tracer emulator predicts what an independent tracer run (a fresh platelet array and rays) gives: the GP of
the common-random-number (CRN) tracer minus a run-to-run bias b₀ + B·(z − ½), linear over the box's unit coordinates
z (`fit_run_to_run`, fitted to its misses against `independent_check_design`'s independent runs). This takes the
shipped emulator's misses against those same runs (all read from the caches: nothing is traced when they are there),
after that bias, and asks per angle whether they still bend with σ: ordinary least squares on [1, z − ½] against the
same plus (z_σ − ½)², and plus (z_σ − ½)² and (z_σ − ½)³ (F-tests), and the mean miss in each fifth of z_σ with its
standard error.

Writes experiments/output/run_to_run_shape/summary.json and figure.png (atomic).

Run: python experiments/run_to_run_shape.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402
from scipy import stats  # noqa: E402

from paintjax import atomic_savefig, atomic_write_json, enable_compilation_cache  # noqa: E402
from paintjax.inverse import WIDE_TRACER_SETTINGS, TracerLStar, independent_check_design, independent_runs, wide_tracer_emulator  # noqa: E402

OUT = Path(__file__).resolve().parent / "output" / "run_to_run_shape"
FIFTHS = 5


def misses():
    """(z, miss, angles, names): the unit-cube points of the independent runs that have an array, the shipped
    emulator's prediction minus each run at every angle it gives (the run-to-run bias already subtracted), those
    angles, and the box's parameter names (the columns of z)."""
    angles = WIDE_TRACER_SETTINGS.aspecular
    em = wide_tracer_emulator(angles=angles)
    fn = TracerLStar(WIDE_TRACER_SETTINGS)
    z, out = [], []
    for zb, tb, seeds in independent_check_design(em.spec, seed=0):
        L = independent_runs(fn, tb, seeds)["L"]
        made = np.all(np.isfinite(L), axis=1)  # a θ whose platelets cannot fit the film has no array
        z.append(zb[made])
        out.append(np.asarray(em(tb[made])) - L[made])
    return np.concatenate(z), np.concatenate(out), angles, em.spec.names


def f_test(X1, X2, y) -> np.ndarray:
    """p-value per column of y that the columns X2 adds to X1 explain nothing."""
    rss = [np.sum((y - X @ np.linalg.lstsq(X, y, rcond=None)[0]) ** 2, axis=0) for X in (X1, X2)]
    q, dof = X2.shape[1] - X1.shape[1], y.shape[0] - X2.shape[1]
    return stats.f.sf((rss[0] - rss[1]) / q / (rss[1] / dof), q, dof)


def main() -> int:
    enable_compilation_cache()
    z, miss, angles, names = misses()
    s = z[:, names.index("sigma")] - 0.5
    linear = np.c_[np.ones(len(z)), z - 0.5]
    p_square = f_test(linear, np.c_[linear, s**2], miss)
    p_cubic = f_test(linear, np.c_[linear, s**2, s**3], miss)
    left = miss - linear @ np.linalg.lstsq(linear, miss, rcond=None)[0]
    edges = np.quantile(s, np.linspace(0, 1, FIFTHS + 1))
    which = np.clip(np.digitize(s, edges[1:-1]), 0, FIFTHS - 1)
    mean = np.array([left[which == k].mean(axis=0) for k in range(FIFTHS)])
    se = np.array([left[which == k].std(axis=0, ddof=1) / np.sqrt(np.sum(which == k)) for k in range(FIFTHS)])
    out = {"runs": int(len(z)), "angles": list(angles), "p_sigma_squared": p_square.tolist(), "p_sigma_squared_and_cubed": p_cubic.tolist(),
           "fifths_of_log_sigma_unit": edges.tolist(), "fifth_mean_miss": mean.tolist(), "fifth_mean_se": se.tolist()}
    print(f"{len(z)} independent runs; the shipped emulator's misses after its linear run-to-run bias")
    for j, a in enumerate(angles):
        print(f"  {a:+5.0f}°: F-test p, (z_σ−½)² {p_square[j]:.4f}; with (z_σ−½)³ {p_cubic[j]:.4f}; mean miss by fifth of σ "
              + " ".join(f"{m:+.2f}±{e:.2f}" for m, e in zip(mean[:, j], se[:, j])))
    OUT.mkdir(parents=True, exist_ok=True)
    atomic_write_json(OUT / "summary.json", out)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, len(angles), figsize=(2.4 * len(angles), 2.8), sharey=True)
    centres = 0.5 * (edges[1:] + edges[:-1]) + 0.5
    for j, a in enumerate(angles):
        ax[j].scatter(s + 0.5, left[:, j], s=5, color="0.7")
        ax[j].errorbar(centres, mean[:, j], 2 * se[:, j], fmt="o", color="C3", ms=4)
        ax[j].axhline(0, color="k", lw=0.8)
        ax[j].set(title=f"{a:+.0f}° (p {p_cubic[j]:.3f})", xlabel="σ, unit coordinate (log)")
    ax[0].set_ylabel("miss less its linear fit [L*]")
    ax[0].set_ylim(-8, 8)
    fig.tight_layout()
    atomic_savefig(fig, OUT / "figure.png", dpi=110)
    print(f"wrote {OUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
