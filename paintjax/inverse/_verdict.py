"""Posteriors of one panel with and without its published inputs, and the consistency verdict.

Three runs share the forward model and the L* likelihood (instrument repeatability ⊕ emulator error
⊕ a model discrepancy δ): the L* alone; the L* and the published inputs as data (`MeasuredInputs`);
and the same with δ = 0, the hypothesis "the inputs and the L* agree within the stated errors",
judged by the posterior-predictive p-value of the L* deviance (`posterior_predictive_check`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from ._chain import MAX_STEPS
from ._measured_inputs import MeasuredInputs, posterior_predictive_check
from ._posterior import sample_posterior

#: The runs of `panel_posteriors`: label → (published inputs as data, fixed values).
RUNS: dict[str, tuple[bool, dict]] = {
    "L* alone": (False, {}),
    "L* and inputs": (True, {}),
    "L* and inputs, no discrepancy": (True, {"discrepancy": 0.0}),
}

#: A predictive p-value below this says the inputs and the L* disagree.
DISAGREE_P = 0.01


def panel_posteriors(
    forward,
    sample,
    reading,
    *,
    runs: Sequence[str] = tuple(RUNS),
    definition: str = "rq",
    tilt_platelets: int = 200,
    walkers: int = 32,
    max_steps: int = MAX_STEPS,
    min_ess: float = 1000.0,
    seed: int = 0,
    on_run: Callable[[str, dict], None] | None = None,
) -> dict:
    """Posteriors of a reference sample's measured L*, with its published inputs as data or not.

    Arguments:
        forward: forward model (e.g. the shipped tracer emulator, `make_forward("tracer-emulator-wide", …)`).
        sample: a reference sample (`paintjax.load_sample`): measured L* and published inputs.
        reading: the roughness `ReadingModel` (`build_reading_model`), or None where σ, τ are not inputs.
        runs: labels of `RUNS` to sample, in order.
        definition, tilt_platelets: as in `MeasuredInputs.for_sample`.
        walkers, max_steps, min_ess, seed: as in `sample_posterior` (at least min(500, max_steps) steps,
            convergence checked every min(250, max_steps)).
        on_run: called as `on_run(label, entry)` after each run (progress reporting).

    Returns:
        {label: {"posterior": PosteriorResult, "check": posterior-predictive check, "input_shift":
        each input's expected reading against its published value}}, plus "verdict": "disagree" or
        "agree" from the δ = 0 run's p-value (against `DISAGREE_P`), when that run was sampled.
    """
    unknown = [r for r in runs if r not in RUNS]
    if unknown:
        raise ValueError(f"runs must be among {list(RUNS)}, got {unknown}")
    inputs = MeasuredInputs.for_sample(sample, reading, definition=definition, tilt_platelets=tilt_platelets)
    out: dict = {}
    for label in runs:
        with_inputs, fixed = RUNS[label]
        r = sample_posterior(forward, sample.L_star, fixed=dict(fixed) or None, inputs=inputs if with_inputs else None, walkers=walkers,
                             max_steps=max_steps, min_steps=min(500, int(max_steps)), check_every=min(250, int(max_steps)), min_ess=min_ess,
                             seed=seed, progress=False)
        check = posterior_predictive_check(r, forward, sample.L_star, fixed=dict(fixed) or None, seed=seed)
        out[label] = {"posterior": r, "check": check, "input_shift": inputs.shift_table({n: r.draws(n) for n in r.names})}
        if on_run is not None:
            on_run(label, out[label])
    strict = "L* and inputs, no discrepancy"
    if strict in out:
        out["verdict"] = "disagree" if out[strict]["check"]["p_value"] < DISAGREE_P else "agree"
    return out
