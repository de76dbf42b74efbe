"""Fit the car-paint BRDF (`CarPaintBRDF`) to a paint's gonio table in CIELAB lightness, with Optimistix.

The residual of entry j is the lightness difference ΔL*_j = L*(π f_model) − L*_j (for an achromatic
paint ΔL* is the CIELAB ΔE), divided by √(1 + (SE_j / 0.5)²): entries the tracer resolved to
better than half a unit count fully, noisy ones less. Parameters are mapped to ℝ (softplus for
the diffuse albedo and lobe weights, logistic maps for roughness and F0) and fitted by
Levenberg–Marquardt from several starts (three by default); the best converged start wins. The report gives ΔL*
over all MA98 geometries (the goal: RMS ≤ 1) and names the entries the model cannot follow.
"""

from __future__ import annotations

import dataclasses
import os

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .._optx import result_message
from ..instrument._lightness import lightness
from ._carpaint import MAX_LOBES, CarPaintBRDF
from ._gonio import GonioTable

#: SE [L*] at which an entry's weight falls to 1/√2.
SE_SCALE = 0.5
#: Fitted roughness range (inside the model's accepted range).
FIT_ROUGHNESS = (0.01, 1.0)
#: Goal for the RMS ΔL* over the MA98 geometries.
RMS_GOAL = 1.0
# starting roughnesses (narrow → broad) and weights per lobe count
_STARTS = ((0.05, 0.15, 0.45), (0.1, 0.3, 0.8), (0.03, 0.08, 0.25))


def _unpack(u, k: int, n: float) -> CarPaintBRDF:
    lo, hi = FIT_ROUGHNESS
    return CarPaintBRDF(diffuse=jax.nn.softplus(u[0]), lobe_weight=jax.nn.softplus(u[1:1 + k]),
                        lobe_roughness=lo + (hi - lo) * jax.nn.sigmoid(u[1 + k:1 + 2 * k]),
                        lobe_f0=jax.nn.sigmoid(u[1 + 2 * k:1 + 3 * k]), coat_index=n)


def _pack(diffuse, weights, roughness, f0) -> np.ndarray:
    lo, hi = FIT_ROUGHNESS
    inv_softplus = lambda x: np.log(np.expm1(np.asarray(x, dtype=float)))  # noqa: E731
    logit = lambda p: np.log(p / (1.0 - p))  # noqa: E731
    r = (np.asarray(roughness, dtype=float) - lo) / (hi - lo)
    return np.concatenate([[inv_softplus(diffuse)], inv_softplus(weights), logit(r), logit(np.asarray(f0, dtype=float))])


@dataclasses.dataclass(frozen=True)
class CarPaintFit:
    """A fitted `CarPaintBRDF` and its report.

    `residual_L` is ΔL* (model − table) per table entry; `rms_ma98` and `max_ma98` summarise it over
    the MA98 geometries, `rms_all` over every entry; `converged` is Optimistix's verdict on the best
    start; `worst` lists the entries the model misses by more than max(1, 3 SE) L*.
    """

    model: CarPaintBRDF
    table: GonioTable
    residual_L: np.ndarray
    converged: bool
    message: str
    steps: int
    seconds: float

    @property
    def rms_ma98(self) -> float:
        return float(np.sqrt(np.mean(self.residual_L[self.table.is_ma98] ** 2)))

    @property
    def max_ma98(self) -> float:
        return float(np.max(np.abs(self.residual_L[self.table.is_ma98])))

    @property
    def rms_all(self) -> float:
        return float(np.sqrt(np.mean(self.residual_L**2)))

    @property
    def at_bounds(self) -> list[str]:
        """Lobe parameters that ended on an edge of the fit's range (roughness) or of [0, 1] (F0)."""
        lo, hi = FIT_ROUGHNESS
        notes = []
        for j, (a, f) in enumerate(zip(np.asarray(self.model.lobe_roughness), np.asarray(self.model.lobe_f0))):
            if min(a - lo, hi - a) < 1e-3 * (hi - lo):
                notes.append(f"lobe {j + 1} roughness at the fit's {'lower' if a - lo < hi - a else 'upper'} bound {lo if a - lo < hi - a else hi:g}")
            if min(f, 1.0 - f) < 1e-3:
                notes.append(f"lobe {j + 1} F0 at {round(f):d}")
        return notes

    @property
    def worst(self) -> list[dict]:
        L, se = self.table.lightness()
        bad = np.abs(self.residual_L) > np.maximum(1.0, 3.0 * se)
        order = np.argsort(-np.abs(np.where(bad, self.residual_L, 0.0)))
        t = self.table
        return [{"illumination_deg": float(t.illumination_deg[j]), "polar_deg": float(t.polar_deg[j]),
                 "azimuth_deg": float(t.azimuth_deg[j]), "name": str(t.name[j]), "L_star": float(L[j]),
                 "L_star_se": float(se[j]), "delta_L": float(self.residual_L[j])} for j in order if bad[j]]

    def ma98_report(self) -> list[dict]:
        """Per MA98 geometry: the table's L* (with SE), the model's L* and ΔL*."""
        L, se = self.table.lightness()
        return [{"name": str(self.table.name[j]), "L_star": float(L[j]), "L_star_se": float(se[j]),
                 "model_L_star": float(L[j] + self.residual_L[j]), "delta_L": float(self.residual_L[j])}
                for j in np.flatnonzero(self.table.is_ma98)]

    def summary(self) -> str:
        verdict = "converged" if self.converged else f"NOT converged ({self.message})"
        goal = "meets" if self.rms_ma98 <= RMS_GOAL else "misses"
        lines = [f"car-paint fit ({self.model.num_lobes} lobes, {verdict}, {self.steps} steps, {self.seconds:.1f} s): "
                 f"ΔL* RMS {self.rms_ma98:.2f} over the 19 MA98 geometries ({goal} the goal {RMS_GOAL:g}), max {self.max_ma98:.2f}; "
                 f"RMS {self.rms_all:.2f} over all {self.residual_L.size} entries"]
        if self.at_bounds:
            lines.append("  at a bound: " + "; ".join(self.at_bounds))
        worst = self.worst
        if worst:
            lines.append(f"  the model cannot follow {len(worst)} entries (|ΔL*| > max(1, 3 SE)); the largest:")
            for w in worst[:5]:
                lines.append(f"    θi {w['illumination_deg']:g}°, θo {w['polar_deg']:.1f}°, φ {w['azimuth_deg']:.1f}° {w['name']}: "
                             f"L* {w['L_star']:.1f} ± {w['L_star_se']:.1f}, ΔL* {w['delta_L']:+.1f}")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """The exported JSON document: the model (`CarPaintBRDF.to_dict`) plus the fit report."""
        return self.model.to_dict() | {"fit": {
            "converged": self.converged, "message": self.message, "steps": self.steps, "seconds": self.seconds,
            "rms_delta_L_ma98": self.rms_ma98, "max_delta_L_ma98": self.max_ma98, "rms_delta_L_all": self.rms_all,
            "entries": int(self.residual_L.size), "at_bounds": self.at_bounds, "paint": self.table.paint, "rays_per_incidence": self.table.rays,
            "ma98": self.ma98_report(), "not_followed": self.worst}}

    def save(self, path: str | os.PathLike):
        """Write the JSON document atomically; a fit that did not converge is refused (ValueError)."""
        from .._io import atomic_write_json

        if not self.converged:
            raise ValueError(f"the car-paint fit did not converge ({self.message}); refusing to export it as a model")
        return atomic_write_json(path, self.to_dict())


def fit_car_paint(table: GonioTable, *, lobes: int = MAX_LOBES, coat_index: float = 1.5, max_steps: int = 2000, starts: int = 3,
                  seed: int = 0) -> CarPaintFit:
    """Fit a `CarPaintBRDF` with `lobes` lobes to a gonio table (module docstring has the residual).

    Arguments:
        table: the paint's `GonioTable` (`gonio_table`).
        lobes: 1 to 3 Cook–Torrance lobes.
        coat_index: the clearcoat index (the paint's binder index; not fitted).
        max_steps: Levenberg–Marquardt steps per start.
        starts: Levenberg–Marquardt starts (≥ 1): three fixed ones (narrow to broad lobes, F0 0.9), then
            random ones (unconstrained coordinates ~ N(0, 1.5²), from `seed`); the best converged one wins.

    Returns:
        A `CarPaintFit` (check `converged`; `save` refuses an unconverged fit).
    """
    import time

    if int(lobes) != lobes or not (1 <= int(lobes) <= MAX_LOBES):
        raise ValueError(f"lobes must be an integer in [1, {MAX_LOBES}], got {lobes!r}")
    if int(starts) != starts or int(starts) < 1:
        raise ValueError(f"starts must be an integer >= 1, got {starts!r}")
    if not isinstance(table, GonioTable) or table.reflectance_factor.size < 3 * int(lobes) + 1:
        raise ValueError("table must be a GonioTable with more entries than the model has parameters")
    k, n = int(lobes), float(coat_index)
    t0 = time.perf_counter()
    wi, wo = jnp.asarray(table.wi), jnp.asarray(table.wo)
    L, se = table.lightness()
    target = jnp.asarray(L)
    weight = jnp.asarray(1.0 / np.sqrt(1.0 + (se / SE_SCALE) ** 2))

    def residual(u, _):
        model = _unpack(u, k, n)
        return (lightness(100.0 * model.reflectance_factor(wi, wo)) - target) * weight

    solver = optx.LevenbergMarquardt(rtol=1e-8, atol=1e-8)

    @jax.jit
    def solve(u):
        sol = optx.least_squares(residual, solver, u, None, max_steps=max_steps, throw=False)
        return sol.value, sol.result._value, sol.stats["num_steps"]

    best = None
    rng = np.random.default_rng(seed)
    for j in range(int(starts)):
        if j < len(_STARTS):
            u0 = jnp.asarray(_pack(0.02, 0.5 * np.geomspace(1.0, 0.1, k), _STARTS[j][:k], np.full(k, 0.9)))
        else:
            u0 = jnp.asarray(1.5 * rng.normal(size=1 + 3 * k))
        sol = solve(u0)
        cost = float(jnp.sum(residual(sol[0], None) ** 2))
        ok = bool(int(sol[1]) == 0 and np.isfinite(cost))
        if best is None or (ok, -cost) > (best[0], -best[1]):
            best = (ok, cost, sol)
    ok, _, (value, code, steps) = best
    model = _unpack(value, k, n)
    model = CarPaintBRDF(diffuse=jnp.asarray(float(model.diffuse)), lobe_weight=jnp.asarray(np.asarray(model.lobe_weight)),
                         lobe_roughness=jnp.asarray(np.asarray(model.lobe_roughness)), lobe_f0=jnp.asarray(np.asarray(model.lobe_f0)),
                         coat_index=n)
    order = np.argsort(np.asarray(model.lobe_roughness))  # lobes narrow → broad
    model = CarPaintBRDF(diffuse=model.diffuse, lobe_weight=model.lobe_weight[order], lobe_roughness=model.lobe_roughness[order],
                         lobe_f0=model.lobe_f0[order], coat_index=n)
    resid = np.asarray(lightness(100.0 * model.reflectance_factor(wi, wo))) - L
    message = result_message(int(code))
    return CarPaintFit(model=model, table=table, residual_L=resid, converged=ok, message=message,
                       steps=int(steps), seconds=time.perf_counter() - t0)


def car_paint_for_sample(sample: str = "silver1", *, lobes: int = MAX_LOBES, progress: bool = False, **table_options) -> CarPaintFit:
    """The car-paint fit of a reference sample's simulated paint: `gonio_table` (cached; shipped for
    silver1 and silver2 at the defaults) and `fit_car_paint` with the sample's clearcoat index.

    Arguments:
        sample: "silver1" or "silver2"; lobes: 1 to 3.
        progress: a line per traced incidence when the table is not cached.
        **table_options: passed to `gonio_table` (rays, seed, brdf, paint overrides).
    """
    from .._samples import load_sample
    from ._gonio import gonio_table

    s = load_sample(sample)
    return fit_car_paint(gonio_table(s.name, progress=progress, **table_options), lobes=lobes, coat_index=s.binder_index)
