"""`paintjax demo` (the job `make demo` runs): the forward comparison and what the measurements imply.

First `paintjax table1` with its defaults: measured L* next to the hybrid ray-wave model, mirror
platelets through the same tracer and the analytic single-scatter model. Then, for both reference
samples, the inverse: posteriors through the shipped tracer emulator with the published inputs as
data (`paintjax.inverse.panel_posteriors`), estimates with 90 % intervals, and the consistency
verdict (posterior-predictive p-value with no model discrepancy). Written to `<out>/inference.json`.
Each panel's summary is cached by everything it depends on (the forward model's and the reading
model's content, the sample's data, the runs, the seed, the stopping rule, the package version), so
a second `make demo` reads it instead of sampling again: with the same seed the chains, and so the
numbers, would be the same.
"""

from __future__ import annotations

import time

import numpy as np

from . import _table1 as table1
from ._common import print_json

#: The validation layer's ranges: table1's options.
RANGES = table1.RANGES
#: What the demo prints of each posterior: parameter → (label, scale, unit).
_SHOWN = {"shape": ("tilt shape", 1.0, ""), "scale": ("tilt scale", 1.0, "°"), "sigma": ("σ", 1000.0, " nm"),
          "tau": ("τ", 1.0, " µm"), "discrepancy": ("δ", 1.0, " L*")}


def register(sub) -> None:
    p = sub.add_parser("demo", help="the main job: five-angle L* of Silver #1 and #2 vs measurement, then the posteriors and the "
                                    "consistency verdict of the measured inputs and L*")
    table1.add_arguments(p)
    p.add_argument("--no-inference", action="store_true", help="the forward comparison only (table1)")
    p.set_defaults(func=run)


#: Bumped when what a cached panel summary holds or how it is computed changes (part of its cache key).
SUMMARY_VERSION = 1
#: The modules whose source enters the summaries' cache key: the posterior, its likelihoods and sampler, this command.
_POSTERIOR_CODE = ("cli/_demo.py", "inverse/_verdict.py", "inverse/_posterior.py", "inverse/_chain.py", "inverse/_measured_inputs.py",
                   "inverse/_profilometer.py", "inverse/_tilt_measurement.py", "inverse/_error_model.py", "inverse/_observations.py",
                   "inverse/_parameters.py", "inverse/_forward.py", "inverse/_emulator.py")


def _panel_summary(forward, reading, s, runs, seed: int) -> dict:
    """One panel's posteriors (`panel_posteriors`) reduced to what the demo shows (JSON-ready)."""
    from ..inverse._verdict import panel_posteriors

    t0 = time.perf_counter()
    r = panel_posteriors(forward, s, reading, runs=runs, seed=seed)
    post, strict = r["L* and inputs"]["posterior"].to_dict(), r["L* and inputs, no discrepancy"]
    return {
        "measured": list(s.L_star),
        "estimates": {k: {"mean": post["mean"][k], "q05": post["q05"][k], "q95": post["q95"][k]} for k in post["mean"] if k in _SHOWN},
        "L_star_q50": r["L* and inputs"]["check"]["L_star_q50"],
        "predictive_p_value": strict["check"]["p_value"],
        "predictive_p_value_se": strict["check"]["p_value_se"],
        "verdict": r["verdict"],
        "at_edge": post["at_edge"],
        "converged": {label: bool(r[label]["posterior"].converged) for label in runs},
        "seconds": time.perf_counter() - t0,
    }


#: The two runs of each panel: δ free (the estimates), then δ = 0 (the verdict).
RUNS = ("L* and inputs", "L* and inputs, no discrepancy")
PANELS = ("silver1", "silver2")


def _models(progress: bool):
    """The shipped tracer emulator (the four microstructure parameters free) and the roughness reading model."""
    from ..inverse._profilometer import build_reading_model
    from ..inverse._registry import make_forward

    forward = make_forward("tracer-emulator-wide", ("shape", "scale", "sigma", "tau"), {}, progress=progress)
    return forward, build_reading_model(progress=progress)


def _sample_panel(name: str, seed: int) -> dict:
    """One panel's summary in a process of its own (spawned, so float64 and the compilation cache are set as `main` sets them)."""
    import jax

    from .._cache import enable_compilation_cache
    from .._samples import load_sample

    jax.config.update("jax_enable_x64", True)
    enable_compilation_cache()
    forward, reading = _models(progress=False)
    return _panel_summary(forward, reading, load_sample(name), RUNS, seed)


def inference(*, seed: int = 0, progress: bool = True, workers: int = 2) -> dict:
    """Both panels' posteriors with the published inputs as data (δ free, then δ = 0) and verdicts
    (each panel's summary from the cache when one matches; "cached" says which). With `workers` > 1
    the panels missing from the cache are sampled side by side, one process each (the same seed, so the
    same numbers as one after the other)."""
    import hashlib
    from concurrent.futures import ProcessPoolExecutor
    from multiprocessing import get_context

    import jax

    from .. import __version__
    from .._cache import cache_path, cached_json
    from .._pipeline import _source_digest
    from .._samples import load_sample
    from ..inverse._chain import MAX_RHAT, MAX_STEPS
    from ..inverse._verdict import DISAGREE_P

    forward, reading = _models(progress)
    digest = hashlib.sha256()
    for leaf in jax.tree_util.tree_leaves(reading):
        digest.update(np.ascontiguousarray(np.asarray(leaf, float)).tobytes())
    code = _source_digest(*_POSTERIOR_CODE)  # an edit to the posterior's code invalidates the summaries
    out = {"forward": "tracer-emulator-wide", "disagree_below_p": DISAGREE_P, "panels": {}}
    samples = {name: load_sample(name) for name in PANELS}
    keys = {name: {"version": SUMMARY_VERSION, "paintjax": __version__, "code": code, "forward": forward.fingerprint(), "reading": digest.hexdigest(),
                   "sample": repr(s), "runs": list(RUNS), "seed": int(seed), "max_rhat": MAX_RHAT, "max_steps": MAX_STEPS, "disagree_p": DISAGREE_P}
            for name, s in samples.items()}
    todo = [name for name in PANELS if not cache_path("demo-panel", keys[name]).exists()]
    pool = ProcessPoolExecutor(min(workers, len(todo)), mp_context=get_context("spawn")) if workers > 1 and len(todo) > 1 else None
    try:
        futures = {name: pool.submit(_sample_panel, name, seed) for name in todo} if pool else {}
        if futures and progress:
            print(f"[demo] sampling {len(futures)} panels' posteriors side by side, one process each …", flush=True)
        for name, s in samples.items():
            build = (lambda f=futures[name]: f.result()) if name in futures else (lambda s=s: _panel_summary(forward, reading, s, RUNS, seed))
            summary, hit = cached_json("demo-panel", keys[name], build)
            out["panels"][s.name] = summary | {"cached": bool(hit)}
    finally:
        if pool is not None:
            pool.shutdown(cancel_futures=True)
    return out


def run(args) -> int:
    from .._io import atomic_write_json

    status = table1.run(args)
    if args.no_inference:
        return status
    r = inference(seed=args.seed, progress=not args.json)
    atomic_write_json(f"{args.out}/inference.json", r)
    if args.json:
        print_json(r)
        return status
    print("\nWhat the measured L* and the published inputs imply (ray tracer through its shipped emulator; "
          "published roughness and tilt law as data through models of their measurements):")
    for name, p in r["panels"].items():
        est = ", ".join(f"{_SHOWN[k][0]} {v['mean'] * _SHOWN[k][1]:.3g}{_SHOWN[k][2]} [{v['q05'] * _SHOWN[k][1]:.3g}, "
                        f"{v['q95'] * _SHOWN[k][1]:.3g}]" for k, v in p["estimates"].items())
        print(f"  {name}: {est} (posterior mean [90 %])")
        print(f"    L* measured {np.round(p['measured'], 1).tolist()}, posterior median {np.round(p['L_star_q50'], 1).tolist()}")
        for label, done in p["converged"].items():
            if not done:
                print(f"    WARNING: the posterior '{label}' did not meet the stopping rule (R-hat, ESS) within its steps")
        for k, side in p["at_edge"].items():
            print(f"    WARNING: the posterior of {_SHOWN.get(k, (k,))[0]} piles against the {side} edge of the prior box")
        verdict = ("the inputs and the L* DISAGREE within the stated errors" if p["verdict"] == "disagree"
                   else "the inputs and the L* agree within the stated errors")
        took = f"from the cache; sampled in {p['seconds']:.0f} s" if p["cached"] else f"{p['seconds']:.0f} s"
        print(f"    with no model discrepancy: predictive p = {p['predictive_p_value']:.2g} ± {p['predictive_p_value_se']:.1g}: {verdict} ({took})")
    print(f"  data: {args.out}/inference.json; docs/input_measurement.md explains the runs")
    return status
