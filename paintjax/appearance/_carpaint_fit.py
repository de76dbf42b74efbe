"""Fit the car-paint BRDF (`CarPaintBRDF`) to a paint's gonio table in CIELAB lightness, with Optimistix.

The residual of entry j is the lightness difference ΔL*_j = L*(π f_model) − L*_j (for an achromatic
paint ΔL* is the CIELAB ΔE), divided by √(1 + (SE_j / 0.5)²): entries the tracer resolved to
better than half a unit count fully, noisy ones less. Parameters are mapped to ℝ (softplus for
the diffuse albedo and lobe weights, logistic maps for roughness and F0, log χ for the colour
table, whose smoothness and size are penalised) and fitted by Levenberg–Marquardt from several
starts (three by default); the best converged start wins. The report gives ΔL* over all MA98
geometries (the goal: RMS ≤ 1) and names the entries the model cannot follow.
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
from ._carpaint import MAX_LOBES, MAX_TABLE_NODES, CarPaintBRDF
from ._gonio import GonioTable

#: SE [L*] at which an entry's weight falls to 1/√2.
SE_SCALE = 0.5
#: Fitted roughness range (inside the model's accepted range).
FIT_ROUGHNESS = (0.01, 1.0)
#: The colour table's default nodes in θ_h × θ_d, and the weight of its smoothness and size penalties:
#: chosen among 6 × 6 and 8 × 8 nodes and weights 1 and 3 on Silver #1 and #2 (the MA98 RMS moved by
#: < 0.05 between them; docs/appearance.md).
DEFAULT_TABLE = (6, 6)
SMOOTHNESS = 3.0
#: Levenberg–Marquardt tolerances (relative and absolute, on the parameters and the cost).
FIT_TOL = 1e-8
#: With a colour table, the joint fit runs in chunks of this many steps and stops when the cost changes
#: by at most `STATIONARY` (relative) over one.
POLISH_CHUNK = 100
STATIONARY = 1e-5
#: Goal for the RMS ΔL* over the MA98 geometries.
RMS_GOAL = 1.0
# starting roughnesses (narrow → broad) and weights per lobe count
_STARTS = ((0.05, 0.15, 0.45), (0.1, 0.3, 0.8), (0.03, 0.08, 0.25))


def _unpack(u, k: int, n: float, table: tuple[int, int] | None = None) -> CarPaintBRDF:
    lo, hi = FIT_ROUGHNESS
    chi = None if table is None else jnp.exp(u[1 + 3 * k:].reshape(table))  # the table as log χ
    return CarPaintBRDF(diffuse=jax.nn.softplus(u[0]), lobe_weight=jax.nn.softplus(u[1:1 + k]),
                        lobe_roughness=lo + (hi - lo) * jax.nn.sigmoid(u[1 + k:1 + 2 * k]),
                        lobe_f0=jax.nn.sigmoid(u[1 + 2 * k:1 + 3 * k]), coat_index=n, color_table=chi)


def _pack(diffuse, weights, roughness, f0) -> np.ndarray:
    lo, hi = FIT_ROUGHNESS
    inv_softplus = lambda x: np.asarray(x, dtype=float) + np.log(-np.expm1(-np.asarray(x, dtype=float)))  # noqa: E731 (stable for large x)
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


def fit_car_paint(table: GonioTable, *, lobes: int = MAX_LOBES, coat_index: float = 1.5, color_table: tuple[int, int] | None = DEFAULT_TABLE,
                  smoothness: float = SMOOTHNESS, max_steps: int = 2000, starts: int = 3, seed: int = 0) -> CarPaintFit:
    """Fit a `CarPaintBRDF` with `lobes` lobes to a gonio table (module docstring has the residual).

    Arguments:
        table: the paint's `GonioTable` (`gonio_table`).
        lobes: 1 to 3 Cook–Torrance lobes.
        coat_index: the clearcoat index (the paint's binder index; not fitted).
        color_table: nodes (nh, nd) of the colour table χ(θ_h, θ_d) fitted with the lobes (as log χ, with
            penalty residuals `smoothness` × its second differences along both axes and 0.1 × `smoothness`
            × log χ, which fixes its scale against the lobe weights); None: no table (χ = 1), the plain form.
        max_steps: Levenberg–Marquardt steps per start (the joint fit with a table: at most 4×, in chunks).
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
    if color_table is not None:
        color_table = tuple(int(v) for v in color_table)
        if len(color_table) != 2 or not all(2 <= v <= MAX_TABLE_NODES for v in color_table):
            raise ValueError(f"color_table must be two node counts in [2, {MAX_TABLE_NODES}] or None, got {color_table!r}")
    if not (np.isfinite(smoothness) and smoothness > 0):
        raise ValueError(f"smoothness must be a finite number > 0, got {smoothness!r}")
    k, n, shape = int(lobes), float(coat_index), color_table
    extra = 0 if shape is None else shape[0] * shape[1]
    t0 = time.perf_counter()
    wi, wo = jnp.asarray(table.wi), jnp.asarray(table.wo)
    L, se = table.lightness()
    target = jnp.asarray(L)
    weight = jnp.asarray(1.0 / np.sqrt(1.0 + (se / SE_SCALE) ** 2))

    def residual(u, shape):
        model = _unpack(u, k, n, shape)
        data = (lightness(100.0 * model.reflectance_factor(wi, wo)) - target) * weight
        if shape is None:
            return data
        g = u[1 + 3 * k:].reshape(shape)
        penalty = [jnp.ravel(g[2:] - 2 * g[1:-1] + g[:-2]), jnp.ravel(g[:, 2:] - 2 * g[:, 1:-1] + g[:, :-2]), 0.1 * jnp.ravel(g)]
        return jnp.concatenate([data, smoothness * jnp.concatenate(penalty)])

    solver = optx.LevenbergMarquardt(rtol=FIT_TOL, atol=FIT_TOL)

    def lm(fn, steps: int):
        @jax.jit
        def solve(u):
            sol = optx.least_squares(fn, solver, u, None, max_steps=steps, throw=False)
            return sol.value, sol.result._value, sol.stats["num_steps"], jnp.sum(fn(sol.value, None) ** 2)

        return solve

    # 1. the lobes alone, from several starts
    solve = lm(lambda u, _: residual(u, None), max_steps)
    best = None
    rng = np.random.default_rng(seed)
    for j in range(int(starts)):
        if j < len(_STARTS):
            u0 = _pack(0.02, 0.5 * np.geomspace(1.0, 0.1, k), _STARTS[j][:k], np.full(k, 0.9))
        else:
            u0 = 1.5 * rng.normal(size=1 + 3 * k)
        value, code, steps, cost = solve(jnp.asarray(u0))
        ok = bool(int(code) == 0 and np.isfinite(float(cost)))
        if best is None or (ok, -float(cost)) > (best[0], -best[1]):
            best = (ok, float(cost), (value, int(code), int(steps)))
    note = None
    if shape is not None and best[0]:
        # 2. the table alone with those lobes (a few steps), 3. everything together from there, in chunks: it
        # stops when LM converges or when the cost is stationary over a chunk (the degenerate lobe parameters,
        # F0 at 0 or 1 and roughness at its bound, then drift along flat directions without changing the fit)
        lobe_u, _, steps = best[2]
        g, _, more, _ = lm(lambda g, _: residual(jnp.concatenate([lobe_u, g]), shape), max_steps)(jnp.zeros(extra))
        polish = lm(lambda u, _: residual(u, shape), POLISH_CHUNK)
        value, steps, previous, stationary = jnp.concatenate([lobe_u, g]), steps + int(more), None, False
        while steps < 4 * max_steps:
            value, code, more, cost = polish(value)
            steps, cost = steps + int(more), float(cost)
            if int(code) == 0 or not np.isfinite(cost):
                break
            if previous is not None and previous - cost <= STATIONARY * previous:
                stationary = True
                break
            previous = cost
        best = (bool(np.isfinite(cost) and (int(code) == 0 or stationary)), cost, (value, 0 if stationary else int(code), steps))
        if stationary:
            note = f"cost stationary (relative change ≤ {STATIONARY:g} over {POLISH_CHUNK} steps)"
    ok, _, (value, code, steps) = best
    with_table = shape if value.size > 1 + 3 * k else None  # an unconverged first stage never reached the table
    fitted = jax.tree_util.tree_map(lambda x: jnp.asarray(np.asarray(x)), _unpack(value, k, n, with_table))  # concrete arrays
    order = np.argsort(np.asarray(fitted.lobe_roughness))  # lobes narrow → broad
    model = CarPaintBRDF(diffuse=fitted.diffuse, lobe_weight=fitted.lobe_weight[order], lobe_roughness=fitted.lobe_roughness[order],
                         lobe_f0=fitted.lobe_f0[order], coat_index=n, color_table=fitted.color_table)
    resid = np.asarray(lightness(100.0 * model.reflectance_factor(wi, wo))) - L
    message = note if (ok and note) else result_message(int(code))
    return CarPaintFit(model=model, table=table, residual_L=resid, converged=ok, message=message,
                       steps=int(steps), seconds=time.perf_counter() - t0)


def car_paint_for_sample(sample: str = "silver1", *, lobes: int = MAX_LOBES, color_table: tuple[int, int] | None = DEFAULT_TABLE,
                         progress: bool = False, **table_options) -> CarPaintFit:
    """The car-paint fit of a reference sample's simulated paint: `gonio_table` (cached; shipped for
    silver1 and silver2 at the defaults) and `fit_car_paint` with the sample's clearcoat index.

    Arguments:
        sample: "silver1" or "silver2"; lobes: 1 to 3; color_table: as for `fit_car_paint`.
        progress: a line per traced incidence when the table is not cached.
        **table_options: passed to `gonio_table` (rays, seed, brdf, paint overrides).
    """
    from .._samples import load_sample
    from ._gonio import gonio_table

    s = load_sample(sample)
    return fit_car_paint(gonio_table(s.name, progress=progress, **table_options), lobes=lobes, coat_index=s.binder_index,
                         color_table=color_table)
