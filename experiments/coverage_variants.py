"""Which part of the likelihood leans the calibration study? Posteriors of a finished study's panels again,
under variants of the emulator's likelihood, and the shift of each parameter's rank (PIT) against the study.

The converged calibration study (`experiments/coverage.py --converge`) found the scale's posterior below
the truth more often than chance (mean PIT 0.63). Two candidate causes, each a variant here:

* ``fixed-width``: the residual law's width (Student-t scale and run-to-run spread) varies over the box, so
  −Σ log width(θ) in the log-likelihood pulls the posterior toward where the emulator claims to be accurate.
  The variant holds the width at its value at the panel's least-squares point.
* ``bias-corrected``: the emulator is brighter than direct tracer runs at 45–110° (a mean miss the zero-mean
  law does not hold). The variant subtracts the mean miss (emulator − tracer at the truths) measured on the
  *other* half of the study's panels (cross-fitted: no panel's own miss enters its posterior).

Each posterior is sampled as in the study (16 walkers, the stopping rule, at most 60 000 steps, started from
a 4-start least-squares fit; the seed is the study's seed + the panel's row index, so the Monte Carlo noise
differs from the study's). Writes `<out>/<variant>.json` (per panel: PIT and 68/95 % coverage under the variant
and in the study) with the mean PIT shift and its standard error per parameter.

    python experiments/coverage_variants.py --variant fixed-width --rows 0-8,25-30
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from paintjax import atomic_write_json
from paintjax.inverse import ForwardModel, fit_least_squares, make_forward, sample_posterior

ALL = ("shape", "scale", "sigma", "tau")
VARIANTS = ("fixed-width", "bias-corrected")


class _Variant(ForwardModel):
    """The emulator with its likelihood changed: its L* shifted by `offset`, or its residual law's width taken at `theta0`."""

    emulator: ForwardModel
    offset: jax.Array
    theta0: jax.Array | None = None

    @property
    def parameter_names(self):
        return self.emulator.parameter_names

    @property
    def aspecular_deg(self):
        return self.emulator.aspecular_deg

    @property
    def spec(self):  # the emulator's box bounds the fit and the posterior
        return self.emulator.spec

    @property
    def error_df(self):
        return self.emulator.error_df

    @property
    def error_sd(self):
        return self.emulator.error_sd

    def evaluate(self, theta):
        return self.emulator.evaluate(theta) - self.offset

    def fingerprint(self):
        return f"variant of {self.emulator.fingerprint()}: offset {np.round(np.asarray(self.offset), 4).tolist()}, width at {self.theta0}"

    def _at(self, theta):
        return theta if self.theta0 is None else jnp.broadcast_to(self.theta0, jnp.shape(theta))

    def residual_log_density(self, r, var, theta, have=None):
        return self.emulator.residual_log_density(r, var, self._at(theta), have)

    def sample_residual(self, rng, var, theta):
        return self.emulator.sample_residual(rng, var, np.asarray(self._at(jnp.asarray(theta))))


def parse_rows(text: str, n: int) -> list[int]:
    rows = []
    for part in text.split(","):
        a, _, b = part.partition("-")
        rows += list(range(int(a), int(b or a) + 1))
    if not rows or min(rows) < 0 or max(rows) >= n:
        raise SystemExit(f"--rows must name rows in 0–{n - 1}, got {text!r}")
    return rows


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--variant", choices=VARIANTS, required=True)
    ap.add_argument("--study", type=Path, default=Path("experiments/output/coverage_tracer_wide_converged"))
    ap.add_argument("--rows", default="0-8,25-30", help="rows of the study's summary, e.g. 0-8,25-30")
    ap.add_argument("--out", type=Path, default=Path("experiments/output/coverage_variants"))
    args = ap.parse_args(argv)
    jax.config.update("jax_enable_x64", True)
    study = json.loads((args.study / "summary.json").read_text())
    if study.get("forward") != "tracer-emulator-wide" or not study.get("converge"):
        raise SystemExit(f"{args.study} is not a converged study of the wide tracer emulator")
    rows = study["rows"]
    picked = parse_rows(args.rows, len(rows))
    emulator = make_forward("tracer-emulator-wide", ALL)
    miss = np.asarray(emulator(np.array([[r["truth"][n] for n in ALL] for r in rows]))) - np.array([r["L_star_clean"] for r in rows])
    half = len(rows) // 2
    out_rows, t0 = [], time.perf_counter()
    for k, i in enumerate(picked):
        r = rows[i]
        y, truth = np.asarray(r["L_star"]), r["truth"]
        fr = fit_least_squares(emulator, y, free=ALL, fixed={"discrepancy": 0.0}, n_starts=4, seed=study["seed"] + i)
        if args.variant == "bias-corrected":
            other = slice(half, None) if i < half else slice(0, half)
            forward = _Variant(emulator, jnp.asarray(miss[other].mean(0)))
        else:
            forward = _Variant(emulator, jnp.zeros(len(emulator.aspecular_deg)), jnp.asarray([[fr.values[n] for n in ALL]]))
        post = sample_posterior(forward, y, free=ALL, fixed={"discrepancy": 0.0}, walkers=study["walkers"], max_steps=study["steps"],
                                min_steps=500, check_every=250, init=fr, seed=study["seed"] + i, progress=False, inference_data=False)
        row = {"row": i, "truth": truth, "steps": post.steps, "converged": bool(post.converged),
               "pit": {n: float(np.mean(post.draws(n) < truth[n])) for n in ALL}, "pit_study": r["pit"], "inside": {}, "inside_study": {}}
        for lv in (0.68, 0.95):
            for n in ALL:
                lo, hi = post.interval(n, lv)
                row["inside"][f"{n}@{lv}"] = bool(lo <= truth[n] <= hi)
                row["inside_study"][f"{n}@{lv}"] = r["inside"][f"{n}@{lv}"]
        out_rows.append(row)
        spent = time.perf_counter() - t0
        print(f"row {i} ({k + 1}/{len(picked)}, {spent:.0f} s, about {spent / (k + 1) * (len(picked) - k - 1):.0f} s left): PIT "
              + ", ".join(f"{n} {row['pit'][n]:.2f} (study {r['pit'][n]:.2f})" for n in ALL), flush=True)
    shift = {n: np.array([row["pit"][n] - row["pit_study"][n] for row in out_rows]) for n in ALL}
    summary = {"variant": args.variant, "study": str(args.study), "rows": out_rows, "seconds": time.perf_counter() - t0,
               "mean_pit": {n: float(np.mean([row["pit"][n] for row in out_rows])) for n in ALL},
               "mean_pit_study": {n: float(np.mean([row["pit_study"][n] for row in out_rows])) for n in ALL},
               "pit_shift_mean": {n: float(v.mean()) for n, v in shift.items()},
               "pit_shift_se": {n: float(v.std(ddof=1) / np.sqrt(len(v))) if len(v) > 1 else None for n, v in shift.items()}}
    args.out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(args.out / f"{args.variant}.json", summary)
    se = {n: "n/a (one row)" if v is None else f"{v:.3f}" for n, v in summary["pit_shift_se"].items()}
    print("mean PIT shift (variant − study): " + ", ".join(f"{n} {summary['pit_shift_mean'][n]:+.3f} ± {se[n]}" for n in ALL))
    return summary


if __name__ == "__main__":
    main()
