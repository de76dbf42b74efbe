"""A Gaussian-process emulator of an expensive forward map (the tracer): design, fit, check, cache.

`build_emulator` evaluates the forward map on a space-filling design over the prior box (checkpointed,
cached under a content hash), fits one Matérn-5/2 GP per angle on top of an analytic mean, and
reports held-out errors; `Emulator` is then a jittable `ForwardModel` with a model-error term. The GPs
are tinygp's (`GaussianProcess`, Matérn-5/2 with ARD length scales); their hyperparameters are fitted
by Optimistix BFGS.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._cache import default_cache_dir, shipped
from .._io import atomic_savez
from ..instrument._geometry import STANDARD_ASPECULAR
from ._error_model import EmulatorError, fit_emulator_error
from ._forward import ForwardModel, Restricted, _assemble
from ._parameters import ParameterSpec

EMULATOR_VERSION = 1  # meaning of the cached design evaluations (bump to re-run them)
EMULATOR_FIT_VERSION = 6  # meaning of the fit on top of them (a change only re-fits, from the cached design); 6: the error law is multivariate

# ------------------------------------------------------------------------------------------
# Gaussian-process emulator
# ------------------------------------------------------------------------------------------
def _kernel(hyp, p: int):
    """Matérn-5/2 kernel with ARD length scales (tinygp) from packed hyperparameters (log length scales
    [p], log amplitude, log noise)."""
    from tinygp import kernels, transforms

    matern = kernels.Matern52(distance=kernels.distance.L2Distance())
    return jnp.exp(2.0 * hyp[p]) * transforms.Linear(jnp.exp(-hyp[:p]), matern)


def _noise(hyp, p: int):
    return jnp.exp(2.0 * hyp[p + 1]) + 1e-8


def _gp(X, hyp):
    """The training GP (tinygp `GaussianProcess`, direct Cholesky solver) at the design X."""
    from tinygp import GaussianProcess

    p = X.shape[1]
    return GaussianProcess(_kernel(hyp, p), X, diag=_noise(hyp, p))


def _gram(X, hyp):
    """Training covariance K (kernel + noise on the diagonal)."""
    p = X.shape[1]
    return _kernel(hyp, p)(X, X) + _noise(hyp, p) * jnp.eye(X.shape[0])


def _neg_log_marginal(hyp, X, y):
    p = X.shape[1]
    log_ls, log_noise = hyp[:p], hyp[p + 1]
    nll = -_gp(X, hyp).log_probability(y)
    # Weak log-normal regularisation of the hyperparameters keeps the optimum away from degenerate corners.
    reg = 0.5 * jnp.sum(((log_ls - jnp.log(0.3)) / 1.5) ** 2) + 0.5 * ((log_noise - jnp.log(1e-3)) / 3.0) ** 2
    return nll + reg


#: Starting (length scale, noise) pairs of the hyperparameter search; the best marginal likelihood wins
#: (one start alone landed in different local optima for near-identical data).
_GP_STARTS = ((0.3, 1e-2), (1.0, 1e-2), (0.1, 1e-2), (0.3, 0.1))


@jax.jit
def _fit_gp(X, Y):
    """Fit one GP per output column of Y (standardised): type-II maximum likelihood by optimistix BFGS
    from several starts (`_GP_STARTS`), keeping the best."""
    import optimistix as optx

    p = X.shape[1]
    objective = lambda h, y: _neg_log_marginal(h, X, y)  # noqa: E731

    def from_start(y, ls, noise):
        h0 = jnp.concatenate([jnp.full((p,), jnp.log(ls)), jnp.zeros(1), jnp.full((1,), jnp.log(noise))])
        sol = optx.minimise(objective, optx.BFGS(rtol=1e-6, atol=1e-6), h0, args=y, max_steps=300, throw=False)
        h = jnp.where(jnp.all(jnp.isfinite(sol.value)), sol.value, h0)
        val = objective(h, y)
        return h, jnp.where(jnp.isfinite(val), val, jnp.inf)

    starts = jnp.asarray(_GP_STARTS)

    def fit_one(y):
        hs, vals = jax.vmap(lambda st: from_start(y, st[0], st[1]))(starts)
        h = hs[jnp.argmin(vals)]
        h = h.at[p + 1].set(jnp.clip(h[p + 1], jnp.log(1e-5), jnp.log(0.3)))
        solver = _gp(X, h).solver
        return h, solver.solve_triangular(solver.solve_triangular(y), transpose=True)  # K⁻¹ y

    return jax.vmap(fit_one, in_axes=1)(Y)


class Emulator(ForwardModel):
    """Gaussian-process emulator of a forward map over the box of `spec` (see `build_emulator`).

    Inputs are the parameters of `spec` (physical units); outside the box they are clipped.
    `error_sd` is the cross-validated RMS error per angle: the held-out errors (independent LHS set)
    pooled with the leave-one-out errors of the training design, so that it rests on all
    n_train + n_test runs (the held-out set alone is small); `held_out_rms` and `held_out_loo_rms`
    are the two parts, `held_out_max` the largest held-out error (`held_out_max_by_angle` per angle).
    `error` is the heavy-tailed, regional model of the same cross-validated errors (`EmulatorError`,
    a multivariate Student-t over the angles with a scale that varies over the box) that the likelihood uses
    (`residual_log_density`).
    `select` gives the GPs of some angles.
    With a `mean_model`, L* = c₀ + c₁·L*_mean[`mean_rows`] + GP([unit θ, standardised L*_mean at `mean_features`]).
    """

    X: Float[Array, "n q"]
    alpha: Float[Array, "m n"]
    hyper: Float[Array, "m q"]
    y_mean: Float[Array, " m"]
    y_std: Float[Array, " m"]
    spec: ParameterSpec = eqx.field(static=True)
    angles: tuple[float, ...] = eqx.field(static=True)
    held_out_rms: tuple[float, ...] = eqx.field(static=True)
    held_out_max: float = eqx.field(static=True)
    source: str = eqx.field(static=True)
    key: str = eqx.field(static=True)
    mean_model: "ForwardModel | None" = None
    mean_cols: tuple[int, ...] = eqx.field(static=True, default=())
    mean_vals: tuple[float, ...] = eqx.field(static=True, default=())
    mean_features: tuple[int, ...] = eqx.field(static=True, default=())
    mean_coef: Float[Array, "m 2"] | None = None
    feature_shift: Float[Array, " f"] | None = None
    feature_scale: Float[Array, " f"] | None = None
    held_out_loo_rms: tuple[float, ...] = eqx.field(static=True, default=())
    fit_id: str = eqx.field(static=True, default="")
    n_test: int = eqx.field(static=True, default=0)
    held_out_max_by_angle: tuple[float, ...] = eqx.field(static=True, default=())
    error: EmulatorError | None = None
    mean_rows: tuple[int, ...] = eqx.field(static=True, default=())

    @property
    def parameter_names(self):
        return self.spec.names

    @property
    def aspecular_deg(self):
        return np.asarray(self.angles)

    @property
    def error_sd(self):
        held = np.asarray(self.held_out_rms)
        if not self.held_out_loo_rms:
            return held
        n_train, n_test = self.X.shape[0], self.n_test
        return np.sqrt((n_train * np.asarray(self.held_out_loo_rms) ** 2 + n_test * held**2) / (n_train + n_test))

    @property
    def error_df(self) -> float:
        return math.inf if self.error is None else self.error.df

    def unit_coordinates(self, theta):
        """θ in the unit cube of the box, clipped into it (as the GPs see it)."""
        return jnp.clip(self.spec.to_unit(jnp.asarray(theta)), 0.0, 1.0)

    def residual_log_density(self, r, var, theta, have=None):
        if self.error is None:
            return super().residual_log_density(r, var, theta, have)
        return self.error.residual_log_density(r, var, self.unit_coordinates(theta), have)

    def sample_residual(self, rng, var, theta):
        if self.error is None:
            return super().sample_residual(rng, var, theta)
        return self.error.sample(rng, var, np.asarray(self.unit_coordinates(theta)))

    def fingerprint(self):
        return f"Emulator({self.key},{hashlib.sha256(self.fit_id.encode()).hexdigest()[:12]},{list(self.angles)})"

    def select(self, angles) -> Emulator:
        """The GPs of some of the angles, in the order given: the arrays sliced, so the predictions and
        errors there are this emulator's (to rounding: XLA may sum in another order for fewer rows). A mean
        model keeps all its angles: the GP features may lie at angles not selected."""
        want = tuple(float(a) for a in angles)
        if not want or len(set(want)) != len(want) or not set(want) <= set(self.angles):
            raise ValueError(f"angles must be distinct angles of this emulator, {list(self.angles)}, got {list(angles)}")
        idx = [self.angles.index(a) for a in want]
        rows = np.array(idx)

        def pick(values):
            return tuple(float(values[i]) for i in idx) if len(values) else ()

        by_angle = pick(self.held_out_max_by_angle)
        out = {"alpha": self.alpha[rows], "hyper": self.hyper[rows], "y_mean": self.y_mean[rows], "y_std": self.y_std[rows], "angles": want,
               "held_out_rms": pick(self.held_out_rms), "held_out_loo_rms": pick(self.held_out_loo_rms), "held_out_max_by_angle": by_angle,
               "held_out_max": max(by_angle) if by_angle else self.held_out_max,
               "error": None if self.error is None else self.error.select(rows)}
        if self.mean_model is not None:
            out |= {"mean_coef": self.mean_coef[rows], "mean_rows": tuple(self.mean_rows[i] for i in idx)}
        return dataclasses.replace(self, **out)

    def evaluate(self, theta):
        z = self.unit_coordinates(theta)
        prior = 0.0
        if self.mean_model is not None:
            a = self.mean_model.evaluate(_assemble(self.spec.from_unit(z), self.mean_cols, self.mean_vals))
            prior = self.mean_coef[:, 0] + self.mean_coef[:, 1] * a[:, list(self.mean_rows)]
            z = jnp.concatenate([z, (a[:, list(self.mean_features)] - self.feature_shift) / self.feature_scale], axis=-1)
        q = z.shape[-1]

        def one(h, a):
            return _kernel(h, q)(z, self.X) @ a

        gp = jax.vmap(one, out_axes=1)(self.hyper, self.alpha)
        return prior + self.y_mean + self.y_std * gp


def _sobol(n: int, d: int, seed: int) -> np.ndarray:
    from scipy.stats import qmc

    m = int(math.ceil(math.log2(max(n, 2))))
    return qmc.Sobol(d, scramble=True, seed=seed).random_base2(m)[:n]


def _lhs(n: int, d: int, seed: int) -> np.ndarray:
    from scipy.stats import qmc

    return qmc.LatinHypercube(d, seed=seed).random(n)


def emulator_key(source: str, spec: ParameterSpec, n_train: int, n_test: int, seed: int, refine=None, n_refine: int = 0) -> str:
    """Content hash of everything that determines an emulator (without a refinement, the key of the base design alone)."""
    text = json.dumps([EMULATOR_VERSION, source, spec.fingerprint(), int(n_train), int(n_test), int(seed)])
    key = hashlib.sha256(text.encode()).hexdigest()[:20]
    if refine and n_refine:
        text = json.dumps([key, sorted((k, float(a), float(b)) for k, (a, b) in refine.items()), int(n_refine)])
        key = hashlib.sha256(text.encode()).hexdigest()[:20]
    return key


def _check_refine(spec: ParameterSpec, refine, n_refine: int) -> dict:
    """The refinement's sub-box in unit coordinates, checked ({} for none)."""
    if n_refine < 0:
        raise ValueError(f"n_refine must be >= 0, got {n_refine}")
    if not refine or not n_refine:
        return {}
    out = {}
    for name, (lo, hi) in refine.items():
        if name not in spec.names:
            raise ValueError(f"refine names {name!r}, which is not one of the free parameters {spec.names}")
        if not 0.0 <= float(lo) < float(hi) <= 1.0:
            raise ValueError(f"refine[{name!r}] must be a unit-coordinate range 0 <= lo < hi <= 1, got ({lo}, {hi})")
        out[name] = (float(lo), float(hi))
    return out


def _refine_design(spec: ParameterSpec, refine: dict, n: int, seed: int) -> np.ndarray:
    """A scrambled Sobol design of n points in the sub-box `refine` (unit coordinates per named parameter, the others whole)."""
    Z = _sobol(n, len(spec), seed)
    for name, (lo, hi) in refine.items():
        j = spec.names.index(name)
        Z[:, j] = lo + (hi - lo) * Z[:, j]
    return Z


def _evaluate_design(fn, Z: np.ndarray, spec: ParameterSpec, batch: int, checkpoint: Path | None, progress: bool, client=None) -> np.ndarray:
    """Evaluate fn on the unit-cube design Z in batches, check-pointing after each batch; with a Dask
    `client` the batches are tasks on its workers (results check-pointed as they arrive, in any order)."""
    n = Z.shape[0]
    Y, have = None, np.zeros(n, bool)
    if checkpoint is not None and checkpoint.exists():
        with np.load(checkpoint) as d:
            if d["Z"].shape == Z.shape and np.allclose(d["Z"], Z):
                Y = np.array(d["Y"])
                have = np.array(d["have"]) if "have" in d.files else np.arange(n) < int(d["done"])
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=n, initial=int(have.sum()), desc="emulator design", leave=False)
    todo = np.flatnonzero(~have)
    batches = [todo[i:i + batch] for i in range(0, todo.size, batch)]

    def store(rows, y):
        nonlocal Y
        y = np.asarray(y, dtype=float)
        if Y is None:
            Y = np.full((n, y.shape[1]), np.nan)
        Y[rows], have[rows] = y, True
        if checkpoint is not None:
            atomic_savez(checkpoint, Z=Z, Y=Y, have=have)
        if bar is not None:
            bar.update(len(rows))

    if client is None:
        for rows in batches:
            store(rows, fn(np.asarray(spec.from_unit(Z[rows]))))
    elif batches:
        from distributed import as_completed

        futures = {client.submit(fn, np.asarray(spec.from_unit(Z[rows])), pure=False): rows for rows in batches}
        for fut in as_completed(futures):
            store(futures[fut], fut.result())
    if bar is not None:
        bar.close()
    return Y


def build_emulator(
    fn: Callable | ForwardModel | "Restricted",
    spec: ParameterSpec,
    *,
    source: str | None = None,
    n_train: int = 256,
    n_test: int = 64,
    seed: int = 0,
    cache_dir: str | os.PathLike | None | Literal["default"] = "default",
    batch: int = 64,
    aspecular_deg=None,
    progress: bool = False,
    mean: "Restricted | None" = None,
    mean_features: Sequence[int] = (),
    client=None,
    refine: Mapping[str, tuple[float, float]] | None = None,
    n_refine: int = 0,
) -> Emulator:
    """Train (or load from cache) a GP emulator of `fn` over the box of `spec`.

    The training design is a scrambled Sobol sequence in the unit cube of `spec` (linear or log
    coordinates), the test design an independent Latin hypercube; `fn` is called in batches with
    physical θ (batch, len(spec)). Give `fn` common random numbers (a fixed key) when it is
    stochastic. The cache file is `<cache_dir>/emulator-<key>.npz`, key = hash of `source`,
    the spec, the design sizes and the seed; design evaluations are check-pointed to
    `<key>.partial.npz` so an interrupted build resumes.

    Arguments:
        fn: forward callable of the parameters of `spec`, a `ForwardModel` with exactly those
            inputs, or a `Restricted` model.
        spec: free parameters and their box.
        source: identity of `fn` for the cache key (defaults to its `fingerprint()`; required for
            plain callables).
        n_train, n_test: design sizes (n_train ≥ 8·len(spec) recommended).
        seed: seed of both designs.
        cache_dir: cache folder; "default" is `default_cache_dir()/emulators`; None for no cache.
        batch: evaluations per call of `fn`.
        aspecular_deg: output angles (defaults to those of `fn` or the five standard ones).
        progress: show a progress bar over the design.
        mean: optional cheap, jit-able model of the same parameters (a `Restricted`): the GP then
            emulates fn − (c₀ + c₁·mean) per angle, with the mean's L* at `mean_features` (output
            columns) as extra inputs. Changing it re-fits from the cached design, no new fn calls.
        mean_features: output columns of `mean` used as GP inputs.
        client: a Dask `distributed.Client`: the design's batches run as tasks on its workers (`fn`
            must pickle; the tracer's `TracerLStar` becomes each worker's own shared instance).
        refine, n_refine: a denser design where the map changes fastest: `n_refine` more training runs
            (a scrambled Sobol sequence, seed + 2) in the sub-box `{name: (lo, hi)}` given in unit
            coordinates of the named parameters (the others span the box). The base design is reused
            from its own cache file (or shipped emulator) and only the added runs are made.

    Returns:
        An `Emulator` (a `ForwardModel` over `spec.names`).
    """
    if n_train < 2 * len(spec) + 2 or n_test < 4:
        raise ValueError(f"n_train must be >= {2 * len(spec) + 2} and n_test >= 4, got {n_train}, {n_test}")
    if isinstance(fn, (ForwardModel, Restricted)):
        names = fn.names if isinstance(fn, Restricted) else fn.parameter_names
        if tuple(names) != spec.names:
            raise ValueError(f"fn inputs {tuple(names)} differ from the spec's parameters {spec.names}")
        source = source or fn.fingerprint()
        if aspecular_deg is None:
            aspecular_deg = (fn.model if isinstance(fn, Restricted) else fn).aspecular_deg
    if not source:
        raise ValueError("source must identify fn (a string that changes with its behaviour) for the cache key")
    angles = tuple(float(a) for a in (STANDARD_ASPECULAR if aspecular_deg is None else aspecular_deg))
    refine = _check_refine(spec, refine, int(n_refine))
    n_refine = int(n_refine) if refine else 0
    key = emulator_key(source, spec, n_train, n_test, seed, refine, n_refine)
    base_key = emulator_key(source, spec, n_train, n_test, seed)
    if cache_dir == "default":
        cache_dir = default_cache_dir() / "emulators"
    path = None if cache_dir is None else Path(cache_dir) / f"emulator-{key}.npz"
    if mean is not None:
        if not isinstance(mean, Restricted) or tuple(mean.names) != spec.names or not mean.jittable:
            raise ValueError(f"mean must be a jit-able Restricted model of exactly the parameters {spec.names} (in that order)")
        if tuple(float(a) for a in mean.model.aspecular_deg) != angles:
            raise ValueError(f"mean's angles {list(mean.model.aspecular_deg)} differ from the emulated ones {list(angles)}")
        if any(not 0 <= int(i) < len(angles) for i in mean_features):
            raise ValueError(f"mean_features must be output columns in [0, {len(angles) - 1}], got {list(mean_features)}")
    mean_id = "none" if mean is None else f"{mean.fingerprint()}|features={list(mean_features)}"
    fit_id = f"v{EMULATOR_FIT_VERSION}|{mean_id}"
    arrays, fitted = _stored_design(path, fit_id, n_train + n_refine)
    if fitted:
        return _emulator_from_arrays(arrays, spec, angles, source, key, mean, mean_features)
    if arrays is None and n_refine:  # the base design from its own file (cache or shipped)
        arrays, _ = _stored_design(None if path is None else path.with_name(f"emulator-{base_key}.npz"), None, n_train)
    checkpoints = []

    def evaluate(Z, name):
        ckpt = None if path is None else path.with_name(f"emulator-{key}{name}.partial.npz")
        checkpoints.append(ckpt)
        Y = _evaluate_design(fn, Z, spec, batch, ckpt, progress, client)
        if not np.all(np.isfinite(Y)):
            raise ValueError("the forward callable returned non-finite L* on the design; narrow the parameter bounds")
        return Y

    if arrays is None:
        t0 = time.perf_counter()
        Z = _sobol(n_train, len(spec), seed)
        Zt = _lhs(n_test, len(spec), seed + 1)
        Yall = evaluate(np.concatenate([Z, Zt]), "")
        arrays = dict(Z=Z, Y=Yall[:n_train], Zt=Zt, Yt=Yall[n_train:], design_seconds=time.perf_counter() - t0)
    if arrays["Z"].shape[0] < n_train + n_refine:  # the refinement's runs
        t0 = time.perf_counter()
        Zr = _refine_design(spec, refine, n_refine, seed + 2)
        Yr = evaluate(Zr, "-refine")
        arrays |= dict(Z=np.concatenate([arrays["Z"], Zr]), Y=np.concatenate([arrays["Y"], Yr]),
                       design_seconds=float(arrays.get("design_seconds", 0.0)) + time.perf_counter() - t0)
    arrays = arrays | fit_emulator(arrays["Z"], arrays["Y"], arrays["Zt"], arrays["Yt"], spec, mean, mean_features, angles, source, key)
    arrays["fit_id"] = np.array(fit_id)
    if path is not None:
        atomic_savez(path, **arrays)
        for ckpt in checkpoints:
            if ckpt is not None and ckpt.exists():
                ckpt.unlink()
    return _emulator_from_arrays(arrays, spec, angles, source, key, mean, mean_features)


def _stored_design(path: Path | None, fit_id: str | None, n_design: int) -> tuple[dict | None, bool]:
    """A stored emulator file (the cache, else a shipped one of the same name): (all of it, True) where its fit
    is `fit_id` on `n_design` training runs, else (its design Z, Y, Zt, Yt to re-fit, False); (None, False) where
    there is none. A design of fewer runs (the base of a refinement) is returned too: the caller adds the rest."""
    stored = None if path is None else shipped(path)
    if stored is None or not stored.exists():
        return None, False
    with np.load(stored) as d:
        arrays = {k: np.array(d[k]) for k in d.files}
    if "Z" not in arrays and "X" in arrays:  # files of fit version 1 stored the design as X
        arrays["Z"] = arrays["X"]
    if "Z" not in arrays:
        return None, False
    if fit_id is not None and str(arrays.get("fit_id", "")) == fit_id and arrays["Z"].shape[0] == n_design:
        return arrays, True
    arrays = {k: arrays[k] for k in ("Z", "Y", "Zt", "Yt", "design_seconds") if k in arrays}
    return {k: v[:n_design] if k in ("Z", "Y") else v for k, v in arrays.items()}, False


def _mean_inputs(spec, mean, mean_features, Z):
    """(L* of the mean model at the unit-cube points Z, the columns used as features)."""
    a = np.asarray(mean.evaluate(jnp.asarray(spec.from_unit(Z))))
    return a, a[:, list(mean_features)]


def fit_emulator(Z, Y, Zt, Yt, spec, mean, mean_features, angles, source, key) -> dict:
    """GP fit (with the optional physics-informed mean) and its held-out and leave-one-out errors."""
    t0 = time.perf_counter()
    out = {}
    X, target = Z, Y
    if mean is not None:
        a, f = _mean_inputs(spec, mean, mean_features, Z)
        coef = np.stack([np.linalg.lstsq(np.c_[np.ones(len(a)), a[:, k]], Y[:, k], rcond=None)[0] for k in range(Y.shape[1])])
        shift, scale = f.mean(0), f.std(0) + 1e-9
        X = np.concatenate([Z, (f - shift) / scale], axis=1)
        target = Y - (coef[:, 0] + coef[:, 1] * a)
        out |= dict(mean_coef=coef, feature_shift=shift, feature_scale=scale)
    y_mean, y_std = target.mean(0), target.std(0) + 1e-12
    hyper, alpha = _fit_gp(jnp.asarray(X), jnp.asarray((target - y_mean) / y_std))
    loo = _loo_errors(X, (target - y_mean) / y_std, np.asarray(hyper)) * y_std
    out |= dict(X=X, alpha=np.asarray(alpha), hyper=np.asarray(hyper), y_mean=y_mean, y_std=y_std, loo_rms=np.sqrt(np.mean(loo**2, axis=0)))
    em = _emulator_from_arrays(out | dict(held_out_rms=np.zeros(Y.shape[1]), held_out_max=0.0, Zt=Zt), spec, angles, source, key, mean, mean_features)
    err = np.asarray(em(np.asarray(spec.from_unit(Zt)))) - Yt
    out["held_out_rms"] = np.sqrt(np.mean(err**2, axis=0))
    out["held_out_max"] = float(np.max(np.abs(err)))
    out["held_out_max_by_angle"] = np.max(np.abs(err), axis=0)
    error = fit_emulator_error(np.concatenate([Z, Zt]), np.concatenate([loo, err]))
    out |= dict(error_scale=np.asarray(error.scale), error_slope=np.asarray(error.slope), error_df=np.asarray(error.df),
                error_correlation=np.asarray(error.correlation))
    out["train_seconds"] = time.perf_counter() - t0
    return out


def _loo_errors(X, Ys, hyper) -> np.ndarray:
    """Leave-one-out errors (n, m) of the standardised output columns (closed form, α_i / (K⁻¹)_ii)."""
    out = []
    for k in range(Ys.shape[1]):
        Ki = np.linalg.inv(np.asarray(_gram(jnp.asarray(X), jnp.asarray(hyper[k]))))
        out.append(Ki @ Ys[:, k] / np.diag(Ki))
    return np.stack(out, axis=1)


def _emulator_from_arrays(a: dict, spec, angles, source, key, mean=None, mean_features=()) -> Emulator:
    opt = lambda k: None if mean is None else jnp.asarray(a[k])  # noqa: E731
    return Emulator(
        X=jnp.asarray(a["X"]),
        alpha=jnp.asarray(a["alpha"]),
        hyper=jnp.asarray(a["hyper"]),
        y_mean=jnp.asarray(a["y_mean"]),
        y_std=jnp.asarray(a["y_std"]),
        spec=spec,
        angles=angles,
        held_out_rms=tuple(float(v) for v in np.asarray(a["held_out_rms"])),
        held_out_max=float(a["held_out_max"]),
        source=source,
        key=key,
        mean_model=None if mean is None else mean.model,
        mean_cols=() if mean is None else tuple(int(c) for c in mean._cols),
        mean_vals=() if mean is None else tuple(float(v) for v in mean._vals),
        mean_features=tuple(int(i) for i in mean_features) if mean is not None else (),
        mean_coef=opt("mean_coef"),
        feature_shift=opt("feature_shift"),
        feature_scale=opt("feature_scale"),
        held_out_loo_rms=tuple(float(v) for v in np.asarray(a.get("loo_rms", ()))),
        fit_id=str(a.get("fit_id", "")),
        n_test=int(np.asarray(a["Zt"]).shape[0]) if "Zt" in a else 0,
        held_out_max_by_angle=tuple(float(v) for v in np.asarray(a.get("held_out_max_by_angle", ()))),
        error=EmulatorError(a["error_scale"], a["error_slope"], float(a["error_df"]), a.get("error_correlation")) if "error_scale" in a else None,
        mean_rows=tuple(range(len(angles))) if mean is not None else (),
    )


def emulator_check(emulator: Emulator, direct: Callable, x: Float[ArrayLike, "n p"]) -> dict:
    """Compare an emulator with direct evaluations at parameter vectors x (e.g. posterior draws).

    Returns:
        dict with per-angle RMS and max |difference| and the emulator's own held-out RMS.
    """
    x = np.asarray(x, dtype=float)
    d = np.asarray(emulator(x)) - np.asarray(direct(x))
    return {"rms": np.sqrt(np.mean(d**2, 0)), "max_abs": np.max(np.abs(d), 0), "error_sd": emulator.error_sd, "n": x.shape[0]}
