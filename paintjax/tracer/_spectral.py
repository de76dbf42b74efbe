"""Spectral mode: tracer runs at several wavelengths combined as the instrument does (D65, CIE 1964 10°).

The platelet optics depend on the wavelength (kσ, kτ of the roughness, the aluminium index, the
coherent lobe's width); the paint's geometry does not. A spectral prediction traces the same array
with the same seed at each node wavelength λ_k and integrates the piecewise-linear reflectance
spectrum (held constant beyond the end nodes) against D65 × x̄ȳz̄(10°) on the 5 nm grid:

    XYZ = Σ_k R_k ω_k,   ω_k = Σ_λ W(λ) h_k(λ),

h_k the hat functions of the nodes, W `spectral_weights` (a perfect reflector gives Y = 100). Runs
with one seed are correlated: the reflectance factor's standard error is the bound Σ_k |ω_k| SE_k
(Cauchy–Schwarz, attained for fully correlated runs), and L* carries it; a* and b* get batch-means
standard errors of the linearised combination, batch b of every run taken together (under common
random numbers their node errors largely cancel, which a bound would not see).
"""

from __future__ import annotations

import numpy as np

from ..instrument._lightness import spectral_weights
from ._result import TraceResult
from ._trace import lightness_with_se

#: Node wavelengths [nm] of the spectral mode (every 50 nm across the visible; Y's weight outside
#: 400–700 nm is 0.03 %).
SPECTRAL_NODES_NM = (400, 450, 500, 550, 600, 650, 700)

_DELTA = 6.0 / 29.0
#: L*a*b* = _LAB @ f(XYZ / white) + (−16, 0, 0), f the CIE 1976 companding function.
_LAB = np.array([[0.0, 116.0, 0.0], [500.0, -500.0, 0.0], [0.0, 200.0, -200.0]])


def spectral_node_weights(nodes_nm) -> np.ndarray:
    """XYZ weights (3, K) of reflectance values at increasing node wavelengths [nm] (see module docstring)."""
    nodes = np.asarray(nodes_nm, dtype=float)
    if nodes.ndim != 1 or nodes.size < 2 or np.any(np.diff(nodes) <= 0) or nodes[0] < 360 or nodes[-1] > 830:
        raise ValueError(f"nodes_nm must be at least two increasing wavelengths in [360, 830] nm, got {nodes_nm!r}")
    wl, W = spectral_weights()
    hats = np.stack([np.interp(wl, nodes, np.eye(nodes.size)[k]) for k in range(nodes.size)])  # (K, nλ), constant beyond the ends
    return W @ hats.T


def lab_from_xyz(xyz, white) -> np.ndarray:
    """CIE 1976 L*a*b* of tristimulus values (..., 3) relative to the white (3,) (unclipped above L* 100)."""
    t = np.asarray(xyz, dtype=float) / np.asarray(white, dtype=float)
    f = np.where(t > _DELTA**3, np.cbrt(t), t / (3 * _DELTA**2) + 4.0 / 29.0)
    return f @ _LAB.T + np.array([-16.0, 0.0, 0.0])


def combine_spectral(results: list[TraceResult], nodes_nm) -> tuple[TraceResult, dict]:
    """Combine tracer runs at the node wavelengths into the instrument's Y (and XYZ, L*a*b*).

    Arguments:
        results: one `TraceResult` per node wavelength (same geometry, batches).
        nodes_nm: the node wavelengths [nm].

    Returns:
        (a `TraceResult` of the Y-weighted reflectance factor Y/100 with its bounded SE, L* and the
        Y-weighted energy ledger; a dict with "wavelengths_nm", "spectral_reflectance_factor"
        (K, m), "XYZ" (m, 3), "Lab" (m, 3) and "Lab_se" (m, 3): L* the bound, a*, b* batch means).
    """
    omega = spectral_node_weights(nodes_nm)
    if len(results) != omega.shape[1]:
        raise ValueError(f"need one result per node wavelength ({omega.shape[1]}), got {len(results)}")
    R = np.stack([r.reflectance_factor for r in results])  # (K, m)
    wy = omega[1] / 100.0  # sums to 1

    def mix(field):
        return np.tensordot(wy, np.stack([np.asarray(getattr(r, field)) for r in results]), axes=1)

    def bound(field):
        return np.tensordot(np.abs(wy), np.stack([np.asarray(getattr(r, field)) for r in results]), axes=1)

    Y, Y_se = mix("reflectance_factor"), bound("reflectance_factor_se")
    L, L_se = lightness_with_se(Y, Y_se)
    energy = {k: float(np.dot(wy, [r.energy[k] for r in results])) for k in results[0].energy}
    combined = TraceResult(
        aspecular_deg=results[0].aspecular_deg, reflectance_factor=Y, reflectance_factor_se=Y_se, L_star=L, L_star_se=L_se,
        histogram_reflectance_factor=mix("histogram_reflectance_factor"), histogram_se=bound("histogram_se"), energy=energy,
        rays=int(sum(r.rays for r in results)), seconds=float(sum(r.seconds for r in results)),
        batch_reflectance_factor=mix("batch_reflectance_factor"), batch_histogram=mix("batch_histogram"),
    )
    xyz = (omega @ R).T  # (m, 3)
    white = omega.sum(axis=1)
    # SE of a*, b* by batch means: the runs share the seed, so batch b of every run is linearised
    # together, Lab_b ≈ Lab + Σ_k D_k (B_kb − R_k) with D_k = ∂Lab/∂R_k = J(XYZ) ω_k (J: lab_from_xyz).
    t = xyz / white
    tt = np.maximum(t, 1e-300)
    df = np.where(t > _DELTA**3, np.cbrt(tt) / (3.0 * tt), 1.0 / (3 * _DELTA**2)) / white  # (m, 3): df(X/Xn)/dX …
    jac = _LAB[None] * df[:, None, :]  # (m, Lab, XYZ)
    D = np.einsum("mcx,xk->mck", jac, omega)
    B = np.stack([np.asarray(r.batch_reflectance_factor) for r in results])  # (K, batches, m)
    e = np.einsum("mck,kbm->bmc", D, B - B.mean(axis=1, keepdims=True))
    lab_se = e.std(axis=0, ddof=1) / np.sqrt(e.shape[0])
    lab_se[:, 0] = L_se  # one L* standard error in every output: the bound of the reflectance factor's
    return combined, {"wavelengths_nm": np.asarray(nodes_nm, dtype=float), "spectral_reflectance_factor": R, "XYZ": xyz,
                      "Lab": lab_from_xyz(xyz, white), "Lab_se": lab_se}
