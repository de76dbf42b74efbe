"""The tracer's registered emulators: "tracer-emulator" (`TRACER_BOX`) and "tracer-emulator-wide" (`WIDE_TRACER_BOX`, shipped).

Registered as ``"tracer-emulator"`` (`paintjax fit --forward tracer-emulator`): a Gaussian-process
emulator (`paintjax.inverse._emulator.build_emulator`) of `TracerLStar` (`paintjax.inverse._tracer_forward`) over the prior box `TRACER_BOX`
(96 training + 24 held-out tracer runs), built once and cached under a content hash, design
evaluations check-pointed. It is physics-informed: per angle the GP models the tracer minus a
linear function of the analytic single-scatter L* (`AnalyticForward`, diffuse 0), and the
analytic L* at every traced angle are extra GP inputs (against the 15°, 25°, 45° features alone this
cuts the wide emulator's cross-validated error at 45°, 75°, 110° from 3.4–3.9 to 2.6–2.9 L*). Its `error_sd` is the emulator's
cross-validated RMS against the same CRN tracer (the 24 held-out errors pooled with the 96
leave-one-out errors; `Emulator.error_sd`) combined in quadrature with the **CRN-vs-independent spread**: the RMS difference between
the CRN evaluation and independent tracer runs (fresh generator arrays and rays, seeds ≠ the CRN
seed) at `SPREAD_THETA` (`seed_spread`) — the error of one finite tile and ray count against
another realisation, including the transport's bias. The likelihood uses the same errors' heavy-tailed,
regional model (`EmulatorError`: multivariate Student-t over the angles, ν ≈ 4 for the shipped wide emulator against its CRN runs, 2.5 against independent runs; scale falling
about eightfold from the smoothest to the roughest platelets, the correlation between the angles that of the misses against
independent runs) plus the **run-to-run terms** (`RunToRun`), fitted to the emulator's misses against
`INDEPENDENT_RUNS` independent tracer runs: the CRN tracer's bias against fresh arrays, linear over the box
(the transported tilts of one reference array are not de-overlapped again, so the CRN tracer is brighter at
45–110° where the tilt law is wide), which the emulator subtracts from its prediction, and a normal spread
whose scale varies over the box, to which the likelihood adds the fitted bias's own variance
(`residual_log_density`). The emulator thus predicts what an independent run, a measured panel, gives.

One GP per output angle. "tracer-emulator-wide" is built over the six MA98 in-plane angles of 45°
illumination (−15° traced in its own pass, `TracerSettings.extra_aspecular`) and gives the standard
five by default (`angles=` selects, e.g. all six for a panel measured at −15°; `Emulator.select`);
"tracer-emulator" gives the standard five.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from ..instrument._geometry import STANDARD_ASPECULAR
from ._tracer_forward import TRACER_BOX, TRACER_PARAMETERS, TracerLStar, TracerSettings, independent_runs, seed_spread

#: θ rows and seeds of the seed-spread measurement of the registered model (inside `TRACER_BOX`:
#: a well-aligned and a poorly aligned paint, moderate roughness); seeds differ from the CRN seed 0.
SPREAD_THETA = ((2.0, 1.5, 0.06, 0.7), (4.0, 2.5, 0.09, 0.5))
SPREAD_SEEDS = (101, 102, 103, 104, 105)
#: Independent tracer runs that judge the emulator as a measured panel would (a Latin hypercube of the box,
#: one fresh array and ray seed each, in Latin hypercubes of `INDEPENDENT_BATCH` runs cached one by one): the
#: CRN tracer's bias and the run-to-run spread are fitted to the emulator's misses there (`fit_run_to_run`). 192 runs:
#: the 54 run-to-run terms fitted to the first 96 alone left the law's far tail too light for runs they had not seen
#: (12 of 95 beyond its 5 % tail in 5-fold cross-validation, binomial range 1–9).
INDEPENDENT_RUNS, INDEPENDENT_SEED0, INDEPENDENT_BATCH = 192, 2000, 24


def tracer_emulator(
    free: Sequence[str] = TRACER_PARAMETERS,
    fixed: Mapping[str, float] | None = None,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    *,
    settings: TracerSettings | None = None,
    cache_dir="default",
    n_train: int = 96,
    n_test: int = 24,
    seed: int = 0,
    batch: int = 4,
    spread_theta=SPREAD_THETA,
    spread_seeds=SPREAD_SEEDS,
    progress: bool = False,
    analytic_mean: bool = True,
    client=None,
    angles=STANDARD_ASPECULAR,
    independent: int = INDEPENDENT_RUNS,
    refine: Mapping[str, tuple[float, float]] | None = None,
    n_refine: int = 0,
    **kw,
):
    """Factory of the registered ``"tracer-emulator"``: a GP emulator of `TracerLStar` (cached).

    Arguments:
        free: free parameters (those of the tracer are kept: shape, scale, sigma, tau; others such
            as "diffuse" or "discrepancy" are not inputs of this model and are ignored).
        fixed: values for tracer parameters that are not free (registered defaults otherwise).
        bounds: box overrides (default `TRACER_BOX`).
        settings: `TracerSettings` of the tracer runs.
        cache_dir: emulator cache folder ("default": `default_cache_dir()/emulators`); the BRDF
            tables and the seed-spread record live in the array cache (`$PAINTJAX_CACHE`).
        n_train, n_test, seed, batch: design of `build_emulator`.
        spread_theta, spread_seeds: where and with which seeds the seed-to-seed spread is measured
            (None: not measured, `error_sd` is the cross-validated RMS alone, and no independent runs).
        independent: independent tracer runs (fresh arrays and rays, seeds 2000 + i) at Latin hypercubes
            of the box; the CRN tracer's bias (subtracted from the prediction) and the run-to-run spread
            (added to the likelihood's error law) are fitted to the emulator's misses against them, over the box
            (`fit_run_to_run`; 0: no bias, the seed spread at `spread_theta`, one number per angle).
        progress: progress bar over the design and one line per tracer run.
        analytic_mean: physics-informed GP (default): the analytic single-scatter model
            (`AnalyticForward`, diffuse 0) is the linear prior mean per angle and its L* at every
            traced angle are extra GP inputs; False: a plain GP over θ.
        client: a Dask `distributed.Client`: the design's tracer runs are tasks on its workers (each
            worker builds its BRDF grid and compiles the tracer once, `shared_tracer`).
        refine, n_refine: `n_refine` more design runs in a sub-box given in unit coordinates (`build_emulator`).
        angles: the output angles, some of `settings.aspecular` (default the standard five, as the
            reference samples give; with ``extra_aspecular=(-15,)`` also −15°). The emulator is built
            over every angle of the settings, one GP each; this selects (`Emulator.select`).

    Returns:
        `TracerEmulator` (an `Emulator` whose `error_sd` includes the seed-to-seed spread).
    """
    from ._emulator import build_emulator
    from ._forward import CallableForward
    from ._parameters import make_spec

    names = tuple(n for n in free if n in TRACER_PARAMETERS)
    if not names:
        raise ValueError(f"the tracer emulator needs at least one of {', '.join(TRACER_PARAMETERS)} free")
    fixed = {k: float(v) for k, v in (fixed or {}).items() if k in TRACER_PARAMETERS}
    box = {n: tuple(TRACER_BOX[n]) for n in names}
    box.update({k: tuple(v) for k, v in (bounds or {}).items() if k in names})
    spec = make_spec(names, box)
    fn = TracerLStar(settings, progress=progress)
    angles = tuple(float(a) for a in angles)
    missing = [a for a in angles if a not in fn.angles]
    if missing:
        raise ValueError(f"this tracer emulator gives L* at {_degrees(fn.angles)}, not at {_degrees(missing)} "
                         f"('tracer-emulator-wide' also gives -15°)")
    # Tracer parameters held fixed default to the box's log-centre, not to the measured values.
    held = {n: fixed.get(n, math.sqrt(TRACER_BOX[n][0] * TRACER_BOX[n][1])) for n in TRACER_PARAMETERS if n not in names}
    model = CallableForward(fn, TRACER_PARAMETERS, fn.settings.identity(), aspecular_deg=fn.angles).restrict(names, held)
    t0 = time.perf_counter()
    mean = _analytic_mean(fn.angles, names, held) if analytic_mean else None
    features = tuple(range(len(fn.angles))) if analytic_mean else ()
    em = build_emulator(model, spec, n_train=n_train, n_test=n_test, seed=seed, cache_dir=cache_dir, batch=batch, progress=progress,
                        mean=mean, mean_features=features, client=client, refine=refine, n_refine=n_refine)
    build_seconds = time.perf_counter() - t0
    spread, checked = None, None
    if spread_theta is not None:
        array_cache = None
        if cache_dir not in ("default", None):
            array_cache = Path(cache_dir)
        spread = seed_spread(fn, spread_theta, spread_seeds, cache_dir=array_cache)
        if independent:
            checked = _independent_check(em, model, fn, spec, int(independent), seed, array_cache)
    out = _wrap(em, spread, build_seconds=build_seconds, evaluations=fn.evaluations, direct=fn, checked=checked)
    if angles != out.angles:
        out = out.select(angles)
    return out


def independent_check_design(spec, n: int = INDEPENDENT_RUNS, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray, list[int]]]:
    """Where a tracer emulator is judged against independent tracer runs: Latin hypercubes of `INDEPENDENT_BATCH`
    points of its box (each batch cached on its own by `independent_runs`).

    Arguments:
        spec: the emulator's `ParameterSpec` (`Emulator.spec`).
        n, seed: the runs and the emulator's design seed (`tracer_emulator`'s `independent` and `seed`).

    Returns:
        One (z, θ, seeds) per batch: unit-cube points (k, p), parameters (k, p) and the runs' seeds
        (`INDEPENDENT_SEED0` + i).
    """
    from ._emulator import _lhs

    out = []
    for b in range(-(-n // INDEPENDENT_BATCH)):
        k = min(INDEPENDENT_BATCH, n - b * INDEPENDENT_BATCH)
        z = _lhs(k, len(spec), seed + 7 + b)
        out.append((z, np.asarray(spec.from_unit(z)), [INDEPENDENT_SEED0 + b * INDEPENDENT_BATCH + i for i in range(k)]))
    return out


def _independent_check(em, model, fn, spec, n: int, seed: int, cache_dir) -> dict:
    """The emulator against `n` independent tracer runs at Latin hypercubes of its box (`independent_check_design`),
    and the run-to-run terms (`fit_run_to_run`: the CRN tracer's bias, the spread, the angles' correlation) that its
    cross-validated error law needs to hold those misses."""
    z, theta, runs = [], [], []
    for zb, tb, seeds in independent_check_design(spec, n, seed):
        z.append(zb)
        theta.append(tb)
        runs.append(independent_runs(fn, np.asarray(model.full(tb)), seeds, cache_dir=cache_dir)["L"])
    z, theta, runs = np.concatenate(z), np.concatenate(theta), np.concatenate(runs)
    made = np.all(np.isfinite(runs), axis=1)  # a θ whose platelets cannot fit the film has no array
    z, theta, runs = z[made], theta[made], runs[made]
    miss = np.asarray(em(theta)) - runs
    term = _cached_run_to_run(em.error, z, miss, cache_dir)
    left = miss - np.asarray(term.mean(z))
    return {"term": term, "rms": np.sqrt(np.mean(miss**2, axis=0)), "max": np.max(np.abs(miss), axis=0),
            "rms_corrected": np.sqrt(np.mean(left**2, axis=0)), "n": int(made.sum()), "no_array": int(n - made.sum())}


def _cached_run_to_run(error, z, miss, cache_dir):
    """`fit_run_to_run`, cached on disk under its inputs (the error law; the points and misses rounded to 10⁻⁶, so
    that a key does not hang on the last bits) and shipped with the wide emulator: the joint law's fit takes
    seconds, and every process that builds the emulator needs it."""
    import jax.numpy as jnp

    from .._cache import cached_arrays
    from ._error_model import RunToRun, fit_run_to_run

    names = [f.name for f in dataclasses.fields(RunToRun) if not f.metadata.get("static", False)]

    def fit():
        term = fit_run_to_run(error, z, miss)
        return {k: getattr(term, k) for k in names}

    inputs = {"version": 2, "scale": np.round(np.asarray(error.scale), 9), "slope": np.round(np.asarray(error.slope), 9),
              "df": round(float(error.df), 9), "correlation": np.round(np.asarray(error.correlation), 9),
              "z": np.round(np.asarray(z), 6), "miss": np.round(np.asarray(miss), 6)}
    a, _ = cached_arrays("emulator-run-to-run", inputs, fit, folder=cache_dir)
    return RunToRun(**{k: jnp.asarray(a[k]) for k in names})


def _analytic_mean(angles, names, held):
    """The physics-informed mean at these angles: the analytic single-scatter model, diffuse 0, on a
    coarse quadrature (24 × 16 nodes: L* within 0.01 of the default 64 × 48, 3× cheaper, keeps MCMC fast)."""
    from ..instrument._geometry import ma98_geometry
    from ._analytic import AnalyticForward

    return AnalyticForward(ma98_geometry(45.0, angles), tilt_nodes=24, azimuth_nodes=16).restrict(names, held | {"diffuse": 0.0})


def _degrees(angles) -> str:
    return ", ".join(f"{a:g}" for a in angles) + "°"


#: Emulator key → build/error information and the direct tracer callable (for `emulator_check`).
_INFO: dict[str, dict] = {}
_DIRECT: dict[str, TracerLStar] = {}


def _wrap(em, spread: dict | None, *, build_seconds: float, evaluations: int, direct: TracerLStar, checked: dict | None = None):
    from ._emulator import Emulator

    class_ = _tracer_emulator_class()
    fields = {f.name: getattr(em, f.name) for f in dataclasses.fields(Emulator)}
    sd = () if spread is None else tuple(float(v) for v in np.asarray(spread["sd"]))
    if checked is not None and fields["error"] is not None:  # against independent runs: the correlation and ν fitted there
        fields["error"] = checked["term"].law(fields["error"])
    out = class_(**fields, seed_spread_sd=sd, run_to_run=None if checked is None else checked["term"])
    _INFO[em.key] = {
        "held_out_rms_crn": list(em.held_out_rms),
        "loo_rms_crn": list(em.held_out_loo_rms),
        "cv_rms_crn": np.asarray(Emulator.error_sd.fget(em)).tolist(),
        "held_out_max": em.held_out_max,
        "held_out_max_by_angle": list(em.held_out_max_by_angle) or None,
        "seed_spread_sd": list(sd) or None,
        "seed_spread_L": None if spread is None else np.asarray(spread["L"]).tolist(),
        "seed_spread_L_crn": None if spread is None else np.asarray(spread["L_crn"]).tolist(),
        "seed_sd_independent": None if spread is None else np.asarray(spread["seed_sd"]).tolist(),
        "error_sd": np.asarray(out.error_sd).tolist(),
        "independent_rms": None if checked is None else checked["rms"].tolist(),
        "independent_max": None if checked is None else checked["max"].tolist(),
        "independent_rms_bias_corrected": None if checked is None else checked["rms_corrected"].tolist(),
        "run_to_run_bias": None if checked is None else np.asarray(checked["term"].bias).tolist(),
        "run_to_run_bias_se": None if checked is None else np.asarray(checked["term"].bias_se).tolist(),
        "run_to_run_sd": None if checked is None else np.asarray(checked["term"].sd).tolist(),
        "run_to_run_correlation": None if checked is None else np.asarray(checked["term"].correlation).tolist(),
        "run_to_run_df": None if checked is None else float(checked["term"].df),
        "run_to_run_df_grid": None if checked is None else np.asarray(checked["term"].df_grid).tolist(),
        "run_to_run_df_cv_log_density": None if checked is None else np.asarray(checked["term"].df_score).tolist(),
        "independent_runs": 0 if checked is None else checked["n"],
        "independent_no_array": 0 if checked is None else checked["no_array"],
        "build_seconds_this_call": build_seconds,
        "tracer_evaluations_this_call": evaluations,
        "key": em.key,
        "angles": list(em.angles),
    }
    _DIRECT[em.key] = direct
    return out


_CLASS = None


def __getattr__(name: str):
    # `TracerEmulator` is defined on first use (importing this module does not import the forward layer) and found here
    # by name, so pickle and cloudpickle send it to another process (Dask workers, process pools) by reference. Sent by
    # value, an equinox class is rebuilt without its fields: traced in the other process, an emulator then lost its
    # `run_to_run` bias and predicted the CRN tracer's L* instead of an independent run's.
    if name == "TracerEmulator":
        return _tracer_emulator_class()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _tracer_emulator_class():
    """`TracerEmulator`: an `Emulator` whose `error_sd` is cross-validated RMS ⊕ seed-to-seed spread
    (defined lazily so importing this module does not import the forward layer)."""
    global _CLASS
    if _CLASS is None:
        import equinox as eqx

        from ._emulator import Emulator
        from ._error_model import RunToRun

        class TracerEmulator(Emulator):
            """GP emulator of the tracer; `error_sd` = sqrt(cross-validated RMS² + seed-to-seed spread²). Where independent
            tracer runs were made (`run_to_run`, a `RunToRun`) it predicts what an independent run gives: the GP of the CRN
            tracer minus the CRN tracer's bias fitted over the box, and the likelihood's residual law is the GP's
            cross-validated `EmulatorError` with the correlation between the angles of the misses against those runs, plus
            the run-to-run spread and the bias's own uncertainty as a normal term;
            without them, plus the seed spread at `SPREAD_THETA`."""

            seed_spread_sd: tuple = eqx.field(static=True, default=())
            run_to_run: RunToRun | None = None

            @property
            def error_sd(self):
                held = Emulator.error_sd.fget(self)
                if not self.seed_spread_sd:
                    return held
                return np.sqrt(held**2 + np.asarray(self.seed_spread_sd) ** 2)

            def evaluate(self, theta):
                out = super().evaluate(theta)
                if self.run_to_run is None:
                    return out
                return out - self.run_to_run.mean(self.unit_coordinates(theta))

            def _with_spread(self, var, theta):
                """var + the run-to-run terms: fitted over the box where independent runs were made, else the
                seed spread (without an error law, error_sd already holds the spread)."""
                if self.error is None:
                    return var
                if self.run_to_run is not None:
                    return var + self.run_to_run.variance(self.unit_coordinates(theta))
                return var + np.asarray(self.seed_spread_sd) ** 2 if self.seed_spread_sd else var

            def residual_log_density(self, r, var, theta, have=None):
                return super().residual_log_density(r, self._with_spread(var, theta), theta, have)

            def sample_residual(self, rng, var, theta):
                return super().sample_residual(rng, np.asarray(self._with_spread(var, theta)), theta)

            def fingerprint(self):
                added = ""
                if self.run_to_run is not None:
                    t = self.run_to_run
                    added = f",run_to_run={[np.round(np.asarray(v), 6).tolist() for v in (t.bias, t.sd, t.slope, t.correlation, t.df)]}"
                return f"Tracer{super().fingerprint()},spread={self.seed_spread_sd}{added}"  # the GP fit too, as Emulator's

            def select(self, angles):
                out = super().select(angles)
                rows = [self.angles.index(a) for a in out.angles]
                if self.run_to_run is not None:
                    out = dataclasses.replace(out, run_to_run=self.run_to_run.select(rows))
                if not self.seed_spread_sd:
                    return out
                return dataclasses.replace(out, seed_spread_sd=tuple(self.seed_spread_sd[i] for i in rows))

        TracerEmulator.__qualname__ = "TracerEmulator"  # found by name (module `__getattr__`)
        _CLASS = TracerEmulator
    return _CLASS


def tracer_info(emulator) -> dict:
    """Build and error information of a tracer emulator built in this process (per-angle entries at its angles)."""
    info = dict(_INFO[emulator.key])
    idx = [info["angles"].index(a) for a in emulator.angles]
    for k in ("held_out_rms_crn", "loo_rms_crn", "cv_rms_crn", "held_out_max_by_angle", "seed_spread_sd", "seed_sd_independent",
              "error_sd", "independent_rms", "independent_max", "independent_rms_bias_corrected", "run_to_run_sd"):
        if info[k]:
            info[k] = [info[k][i] for i in idx]
    for k in ("run_to_run_bias", "run_to_run_bias_se"):  # (p + 1, m): the angles are the columns
        if info[k]:
            info[k] = [[row[i] for i in idx] for row in info[k]]
    for k in ("seed_spread_L", "seed_spread_L_crn"):
        if info[k] is not None:
            info[k] = np.asarray(info[k])[..., idx].tolist()
    if info["run_to_run_correlation"]:
        info["run_to_run_correlation"] = np.asarray(info["run_to_run_correlation"])[np.ix_(idx, idx)].tolist()
    if info["held_out_max_by_angle"]:
        info["held_out_max"] = max(info["held_out_max_by_angle"])
    return info | {"angles": list(emulator.angles)}


def direct_tracer(emulator) -> TracerLStar:
    """The direct `TracerLStar` behind a tracer emulator built in this process, at the emulator's angles."""
    fn = _DIRECT[emulator.key]
    return fn if fn.angles == emulator.angles else fn.with_angles(emulator.angles)


#: A box that holds what the published inputs read through their measurement models and what the L*
#: prefer (`docs/input_measurement.md`), and the BRDF-table grid that spans it (8 × 7 nodes, ratio ≈ 1.4).
WIDE_TRACER_BOX: dict[str, tuple[float, float]] = {"shape": (1.2, 12.0), "scale": (0.5, 5.0), "sigma": (0.015, 0.15), "tau": (0.25, 2.0)}
#: Its tracer settings also trace MA98's −15° (a second pass with the same seed; the five standard angles unchanged), and
#: each evaluation is the mean over four reference arrays (16 384 rays each): where the tilt law is wide and the platelets
#: smooth, arrays differ by up to 6–10 L* at 15° (`experiments/array_spread.py`), and an emulator of one array's CRN
#: tracer followed that array (up to 18–20 L* from the mean of four independent arrays at posterior draws).
WIDE_TRACER_SETTINGS = TracerSettings(sigma_nodes=(0.015, 0.15, 8), tau_nodes=(0.25, 2.0, 7), extra_aspecular=(-15.0,), arrays=4)
#: Its design is denser where the platelets are smooth (the lowest 40 % of log σ, 0.015–0.038 µm), where L* changes
#: fastest with σ (the coherent part, exp(−(2kσ cos θ)²), falls from 0.6 to 0.1 there): with the base design alone the
#: leave-one-out error there was 4.9–8.6 L* RMS in the smoothest fifth against 1.0–1.8 in the roughest third.
WIDE_REFINE, WIDE_N_REFINE = {"sigma": (0.0, 0.4)}, 48


def wide_tracer_emulator(free: Sequence[str] = TRACER_PARAMETERS, fixed: Mapping[str, float] | None = None, bounds=None, **kw):
    """`tracer_emulator` over `WIDE_TRACER_BOX` with `WIDE_TRACER_SETTINGS` and the design refined where the platelets are
    smooth (`WIDE_REFINE`; registered as ``"tracer-emulator-wide"``; ≈ 35 min to build from scratch with the 56 BRDF tables
    cached: the 168 design runs on 2 Dask workers on 2 cores (≈ 15 min), the seed spread's and the 192 independent runs
    after them; cached and shipped). Its error (RMS) per standard angle is 3.2–4.6 L* (held-out RMS over the whole box
    2.2–6.7, largest 31.0 L*: one held-out run whose reference is a next-event firefly of the coherent lobe near grazing
    in one of its four arrays, docs/inference.md; without it 2.2–3.6 L*, largest 10.0); at −15° (`angles=`, a sixth GP)
    4.1 L* (held-out RMS 2.5, largest 6.6 L*)."""
    box = dict(WIDE_TRACER_BOX) | dict(bounds or {})
    kw = {"refine": WIDE_REFINE, "n_refine": WIDE_N_REFINE} | kw
    return tracer_emulator(free, fixed, box, settings=kw.pop("settings", WIDE_TRACER_SETTINGS), **kw)

