"""Forward maps of the inverse layer: microstructure parameters θ → L* at the instrument's angles.

A `ForwardModel` names the parameters it consumes (`parameter_names`, a subset of
`paintjax.inverse._parameters.PARAMETERS`), maps a batch θ (leading dim, columns in that order) to L* at
the instrument's angles, and states its own error: `error_sd` per angle (zero for direct models, the
cross-validated RMS for emulators), which least squares adds to the instrument's, and the law the
likelihood uses, `residual_log_density` (normal with `error_sd` by default; an emulator's is a
heavy-tailed multivariate Student-t over the angles whose scale varies over its box, `paintjax.inverse._error_model`).
Implementations:

* `AnalyticForward` – the analytic single-scatter model of `paintjax.instrument._single_scatter` (milliseconds, jit and
  differentiable). Smooth (mirror) platelets, or rough platelets whose σ, τ enter through a
  platelet BRDF. To stay jit-able and differentiable its rough BRDF is the *analytic* Kirchhoff (Beckmann–Spizzichino) BRDF of a Gaussian surface from
  `paintjax.brdf._analytic` (coherent part exp(−(2kσ cosθ)²) as a mirror, incoherent lobe by quadrature), with
  σ, τ traced (`KirchhoffLobeBRDF`). No multiple scattering and no primer: far from specular
  (75°, 110°) it predicts almost no light (the ray tracer, with the wave-based BRDF grid, is the
  forward model of `_tracer_forward`, "tracer-emulator"). The
  optional `diffuse` parameter adds a Lambertian floor under the coat as a crude stand-in for the
  missing multiple scattering (off unless freed).
* `CallableForward` – any Python callable (the ray tracer, with common random numbers, i.e. a
  fixed key closed over so its output is a smooth function of θ). Not assumed jit-able. The
  tracer's callable lives in `_tracer_forward`, its registered emulators ("tracer-emulator", "-wide") in `_tracer_emulator`.
* `Emulator` – a Gaussian-process emulator (Matérn-5/2, ARD, one GP per angle) of any forward
  callable, trained on a scrambled-Sobol design in the parameters' unit cube, with its held-out
  RMS error measured on an independent Latin-hypercube set, pooled with the training design's
  leave-one-out errors, and exposed as `error_sd` (and, for the likelihood, as `EmulatorError`). Built by
  `build_emulator`, cached on disk under a content-hashed key (atomic writes; the expensive design
  evaluations are check-pointed so an interrupted build resumes). Optionally physics-informed: a
  cheap `mean` model (the tracer emulator uses the analytic single-scatter model) gives a linear
  prior mean per angle and, at chosen angles, extra GP inputs; the GP then learns only what the
  cheap model misses.
"""

from __future__ import annotations

import abc
import json
import math
from collections.abc import Callable, Mapping, Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float

from ..instrument._geometry import STANDARD_ASPECULAR
from ._parameters import get_parameter


# ------------------------------------------------------------------------------------------
# Interface
# ------------------------------------------------------------------------------------------
class ForwardModel(eqx.Module):
    """θ (batch, p) → L* (batch, m) at `aspecular_deg`; columns of θ in `parameter_names` order."""

    @property
    @abc.abstractmethod
    def parameter_names(self) -> tuple[str, ...]:
        """Names of the parameters this model consumes, in column order."""

    @property
    @abc.abstractmethod
    def aspecular_deg(self) -> np.ndarray:
        """Aspecular angles [deg] of the outputs."""

    @property
    def error_sd(self) -> np.ndarray:
        """Per-angle standard deviation of the model's own error (added to the likelihood)."""
        return np.zeros(len(self.aspecular_deg))

    @property
    def error_df(self) -> float:
        """Degrees of freedom of the model's own error (inf: normal, as `error_sd` says)."""
        return math.inf

    def residual_log_density(self, r: Float[Array, "n m"], var: Float[Array, "n m"], theta: Float[Array, "n p"],
                             have: Bool[Array, "n m"] | None = None) -> Float[Array, " n"]:
        """log p(r) of the residual vector r = measured − model at θ over the angles in `have` (broadcast to r;
        default all), with Normal(0, var) measurement terms (instrument, discrepancy) plus the model's own
        error (here normal with `error_sd`, independent between the angles; an emulator's is a heavy-tailed law
        correlated between them). Traceable; one value per row."""
        v = var + jnp.asarray(self.error_sd) ** 2
        logp = -0.5 * (r**2 / v + jnp.log(2.0 * jnp.pi * v))
        return jnp.sum(logp if have is None else jnp.where(have, logp, 0.0), axis=-1)

    def sample_residual(self, rng: np.random.Generator, var, theta) -> np.ndarray:
        """Draws of the residual law of `residual_log_density` at θ (NumPy; var broadcast to (n, m))."""
        v = np.asarray(var, float) + np.asarray(self.error_sd, float) ** 2
        shape = (np.shape(theta)[0], len(self.aspecular_deg))
        return rng.standard_normal(shape) * np.sqrt(np.broadcast_to(v, shape))

    @property
    def jittable(self) -> bool:
        """Whether `evaluate` may be traced by JAX (jit, vmap, jacfwd)."""
        return True

    @abc.abstractmethod
    def evaluate(self, theta: Float[Array, "batch p"]) -> Float[Array, "batch m"]:
        """Traceable batched evaluation (no validation)."""

    @abc.abstractmethod
    def fingerprint(self) -> str:
        """Stable text identifying the model and its settings (for cache keys)."""

    def __call__(self, theta: Float[ArrayLike, "batch p"]) -> Float[Array, "batch m"]:
        """L* for a batch of parameter vectors (a 1-D θ gives a 1-D result).

        Arguments:
            theta: (batch, p) or (p,) values in `parameter_names` order.

        Returns:
            (batch, m) or (m,) L*.
        """
        t = jnp.asarray(theta, dtype=jnp.result_type(float))
        if t.shape[-1:] != (len(self.parameter_names),) or t.ndim not in (1, 2):
            raise ValueError(
                f"theta must have shape (batch, {len(self.parameter_names)}) with columns "
                f"{', '.join(self.parameter_names)}, got {t.shape}"
            )
        one = t.ndim == 1
        t2 = t[None] if one else t
        out = _jit_evaluate(self, t2) if self.jittable else jnp.asarray(self.evaluate(t2))
        return out[0] if one else out

    def restrict(self, names: Sequence[str], fixed: Mapping[str, float] | None = None) -> "Restricted":
        """This model as a function of the parameters `names` only, the others held at `fixed`
        (or their registered defaults)."""
        return Restricted(self, tuple(names), dict(fixed or {}))


@eqx.filter_jit
def _jit_evaluate(model: ForwardModel, theta):
    return model.evaluate(theta)


def _assemble(x, cols, vals):
    """Full parameter vectors of a restricted model: column c of x, or the fixed value where c < 0."""
    return jnp.stack([x[..., c] if c >= 0 else jnp.full(x.shape[:-1], v, dtype=x.dtype) for c, v in zip(cols, vals)], axis=-1)


class Restricted:
    """A forward model as a function of a subset of its parameters (others held fixed).

    Calling it maps (batch, len(names)) → (batch, m); `full(x)` gives the full θ.
    """

    def __init__(self, model: ForwardModel, names: tuple[str, ...], fixed: dict[str, float]):
        unknown = [n for n in names if n not in model.parameter_names]
        if unknown:
            raise ValueError(f"free parameters {unknown} are not inputs of this forward model (inputs: {', '.join(model.parameter_names)})")
        extra = [n for n in fixed if n not in model.parameter_names and n != "discrepancy"]
        if extra:
            raise ValueError(f"fixed parameters {extra} are not inputs of this forward model (inputs: {', '.join(model.parameter_names)})")
        both = [n for n in names if n in fixed]
        if both:
            raise ValueError(f"parameters {both} cannot be both free and fixed")
        self.model, self.names = model, names
        self.fixed = {n: float(fixed.get(n, get_parameter(n).default)) for n in model.parameter_names if n not in names}
        for n, v in self.fixed.items():
            p = get_parameter(n)
            if not (p.lower <= v <= p.upper) or not math.isfinite(v):
                raise ValueError(f"fixed value of {n} must lie in [{p.lower:g}, {p.upper:g}] {p.unit}".rstrip() + f", got {v!r}")
        self._cols = [names.index(n) if n in names else -1 for n in model.parameter_names]
        self._vals = np.array([self.fixed.get(n, 0.0) for n in model.parameter_names])

    def full(self, x: Float[ArrayLike, "batch k"]) -> Float[Array, "batch p"]:
        return _assemble(jnp.asarray(x), self._cols, self._vals)

    def evaluate(self, x):
        return self.model.evaluate(self.full(x))

    def __call__(self, x):
        return self.model(self.full(x))

    @property
    def jittable(self) -> bool:
        return self.model.jittable

    def fingerprint(self) -> str:
        return f"{self.model.fingerprint()}|free={','.join(self.names)}|fixed={json.dumps(self.fixed, sort_keys=True)}"


# ------------------------------------------------------------------------------------------
# Any callable (the tracer)
# ------------------------------------------------------------------------------------------
class CallableForward(ForwardModel):
    """Wrap a Python callable θ (batch, p) → L* (batch, m) as a `ForwardModel`.

    For the ray tracer: close over a fixed PRNG key (common random numbers) so the output is a
    smooth, deterministic function of θ. Not traced by JAX unless `jittable=True`.

    Arguments:
        fn: the callable.
        parameter_names: its input columns (registered parameter names).
        identity: a string that changes whenever `fn`'s behaviour does (cache keys depend on it).
        aspecular_deg: output angles.
        jittable: whether `fn` may be traced by JAX.
    """

    fn: Callable = eqx.field(static=True)
    names: tuple[str, ...] = eqx.field(static=True)
    identity: str = eqx.field(static=True)
    angles: tuple[float, ...] = eqx.field(static=True)
    is_jittable: bool = eqx.field(static=True)

    def __init__(self, fn: Callable, parameter_names: Sequence[str], identity: str, aspecular_deg=STANDARD_ASPECULAR, jittable: bool = False):
        if not callable(fn):
            raise ValueError("fn must be callable")
        for n in parameter_names:
            get_parameter(n)
        if not identity:
            raise ValueError("identity must be a non-empty string describing the callable and its settings")
        self.fn, self.names, self.identity = fn, tuple(parameter_names), str(identity)
        self.angles = tuple(float(a) for a in aspecular_deg)
        self.is_jittable = bool(jittable)

    @property
    def parameter_names(self):
        return self.names

    @property
    def aspecular_deg(self):
        return np.asarray(self.angles)

    @property
    def jittable(self):
        return self.is_jittable

    def evaluate(self, theta):
        return jnp.asarray(self.fn(theta))

    def fingerprint(self):
        return f"CallableForward({self.identity},{','.join(self.names)},{self.angles})"

