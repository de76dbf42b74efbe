"""Inverse design: microstructure parameters whose predicted five-angle L* reaches a target curve.

A weighted least-squares problem solved with the same multi-start Levenberg–Marquardt as
`fit_least_squares`: residuals w_j (L*_model,j − L*_target,j) / tolerance. The target counts as
reached when every weighted angle is within `tolerance` L*; otherwise the result is marked
infeasible and its message gives the closest reachable curve the forward model found (with the
parameters that produce it), so the user sees how far off the target is and where.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence

import numpy as np

from ..instrument._lightness import flop_index
from ._fit import FitResult, fit_least_squares
from ._forward import ForwardModel
from ._observations import check_measured


@dataclasses.dataclass
class DesignResult:
    """Outcome of `design_to_target`.

    Attributes:
        params: designed values of the free parameters; fixed: the held ones.
        L_star: predicted L* at the design; target, weights: as given.
        residual: L_star − target; max_abs_residual over weighted angles; rms_residual.
        flop_index, target_flop_index: X-Rite flop index of the prediction and of the target.
        feasible: every weighted angle within `tolerance`; message: human-readable verdict.
        fit: the underlying `FitResult`.
    """

    params: dict
    fixed: dict
    L_star: np.ndarray
    target: np.ndarray
    weights: np.ndarray
    residual: np.ndarray
    max_abs_residual: float
    rms_residual: float
    flop_index: float
    target_flop_index: float
    feasible: bool
    tolerance: float
    message: str
    fit: FitResult
    aspecular_deg: np.ndarray

    def to_dict(self) -> dict:
        return {
            "params": dict(self.params),
            "fixed": dict(self.fixed),
            "L_star": self.L_star.tolist(),
            "target": self.target.tolist(),
            "weights": self.weights.tolist(),
            "residual": self.residual.tolist(),
            "max_abs_residual": self.max_abs_residual,
            "rms_residual": self.rms_residual,
            "flop_index": self.flop_index,
            "target_flop_index": self.target_flop_index,
            "feasible": self.feasible,
            "tolerance": self.tolerance,
            "message": self.message,
            "seconds": self.fit.seconds,
        }


def _fi(L, angles) -> float:
    a = list(np.round(np.asarray(angles, dtype=float), 6))
    try:
        i15, i45, i110 = a.index(15.0), a.index(45.0), a.index(110.0)
    except ValueError:
        return float("nan")
    if L[i15] <= L[i110] or L[i45] <= 0:
        return float("nan")
    return float(flop_index(L[i15], L[i45], L[i110]))


def design_to_target(
    forward: ForwardModel,
    target,
    *,
    weights=None,
    free: Sequence[str] | None = None,
    fixed: Mapping[str, float] | None = None,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    tolerance: float = 1.0,
    n_starts: int = 16,
    seed: int = 0,
) -> DesignResult:
    """Find parameters whose predicted L* matches `target` (weighted), or report the closest.

    Arguments:
        forward: a `ForwardModel`.
        target: target L* per angle of `forward.aspecular_deg`.
        weights: non-negative weight per angle (default 1; 0 ignores an angle).
        free: parameters to design (default: the forward's inputs except ``diffuse``).
        fixed: values of the other inputs (defaults: registered defaults).
        bounds: `{name: (lower, upper)}` limits of what may be manufactured.
        tolerance: largest acceptable |L*_model − L*_target| on weighted angles (> 0).
        n_starts: least-squares starts.
        seed: seed of the start design.

    Returns:
        A `DesignResult`; `feasible` False (with the closest curve in `message`) when the target
        cannot be reached within `tolerance`.
    """
    m = len(forward.aspecular_deg)
    y = check_measured(target, m, name="target")
    if not (0 < float(tolerance) < float("inf")):
        raise ValueError(f"tolerance must be a finite number > 0 [L*], got {tolerance!r}")
    if free is not None and "discrepancy" in free:
        raise ValueError("free must not include discrepancy (a statistical, not a design, parameter)")
    fr = fit_least_squares(forward, y, free=free, fixed=fixed, bounds=bounds, instrument_sd=float(tolerance), weights=weights,
                           n_starts=n_starts, seed=seed)
    w = np.ones(m) if weights is None else np.asarray(weights, dtype=float).reshape(-1)
    L = fr.L_star_fit
    res = L - y
    on = w > 0
    max_abs = float(np.max(np.abs(res[on])))
    rms = float(np.sqrt(np.mean(res[on] ** 2)))
    feasible = max_abs <= float(tolerance)
    angles = np.asarray(forward.aspecular_deg)
    fmt = lambda a: "[" + ", ".join(f"{v:.1f}" for v in a) + "]"  # noqa: E731
    ptxt = ", ".join(f"{k}={v:.4g}" for k, v in fr.values.items())
    if feasible:
        msg = f"target reached within ±{tolerance:g} L* (max |ΔL*| = {max_abs:.2f}) with {ptxt}"
    else:
        worst = int(np.argmax(np.where(on, np.abs(res), -1)))
        msg = (
            f"target {fmt(y)} is not reachable within ±{tolerance:g} L* by this forward model and these bounds; "
            f"closest reachable curve: {fmt(L)} (residual {fmt(res)}, worst at {angles[worst]:g}°: {res[worst]:+.1f} L*) "
            f"with {ptxt}"
        )
    return DesignResult(
        params=dict(fr.values),
        fixed=dict(fr.fixed),
        L_star=L,
        target=y,
        weights=w,
        residual=res,
        max_abs_residual=max_abs,
        rms_residual=rms,
        flop_index=_fi(L, angles),
        target_flop_index=_fi(y, angles),
        feasible=feasible,
        tolerance=float(tolerance),
        message=msg,
        fit=fr,
        aspecular_deg=angles,
    )
