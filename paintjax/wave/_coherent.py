"""The ensemble estimators of a platelet lobe: the Kirchhoff control variate and the unbiased coherent part.

Each profile's far field ψ carries speckle; its Kirchhoff sum S = Σ e^{−x²/g²} e^{−i(q_x x + q_z h)}
(one matrix product per profile) follows the same speckle, and its ensemble moments E|S|² and E S
are closed forms for a synthesised Gaussian process (`Profiles.covariance`). Regressing |ψ|² on
|S|² (`control_variate_mean`) removes most of the speckle from the incoherent lobe. The coherent
part |⟨ψ⟩|² is estimated without the var(ψ)/N bias of a finite ensemble, inside the specular beam
only, with a delete-a-group jackknife standard error (`coherent_estimate`).
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

#: Half-width of the specular beam window for the coherent part, in units of 1/(k g) in u = sinθ_s − sinθ_i
#: (the tapered beam's coherent intensity ∝ e^{−(k g u)²/2} is e^{−18} at its edge).
COHERENT_WINDOW = 6.0
#: Fewest profiles for the control variate (its coefficient is a regression over the profiles).
MIN_PROFILES_CONTROL = 4
#: Groups of the delete-a-group jackknife of the coherent reflectance.
JACKKNIFE_GROUPS = 16


def expected_control_power(covariance, x, dx: float, g: float, k: float, inc_rad, ang_rad) -> np.ndarray:
    """E|S|² of the Kirchhoff control sum S = Σ_n w_n e^{−i(q_x x_n + q_z h_n)}, w_n = e^{−x_n²/g²}, exactly
    for the Gaussian process with periodic covariance C (lags 0…N−1): for jointly Gaussian heights
    E e^{−iq_z(h_n − h_m)} = e^{−q_z²(C_0 − C_{n−m})}, so
    E|S|² = Σ_d (Σ_m w_{m+d} w_m) cos(q_x d Δx) e^{−q_z²(C_0 − C_d)},  d = −(N−1)…N−1.

    Returns:
        (A, I) for the angles `ang_rad` (A,) and incidences `inc_rad` (I,).
    """
    cov = np.asarray(covariance, float)
    n = cov.size
    w = np.exp(-np.asarray(x, float) ** 2 / g**2)
    lags = np.arange(-(n - 1), n)
    cw = np.correlate(w, w, mode="full")  # Σ_m w_{m+d} w_m at d = −(N−1)…N−1
    keep = cw > 1e-18 * cw.max()
    lags, cw = lags[keep], cw[keep]
    dc = cov[0] - cov[np.abs(lags) % n]
    out = np.empty((np.size(ang_rad), np.size(inc_rad)))
    for i, ti in enumerate(np.atleast_1d(inc_rad)):
        qx = k * (np.sin(ang_rad) - np.sin(ti))
        qz = k * (np.cos(ang_rad) + np.cos(ti))
        out[:, i] = np.sum(cw * np.cos(qx[:, None] * lags * dx) * np.exp(-(qz[:, None] ** 2) * dc), -1)
    return out


def control_variate_mean(samples, control, expected):
    """Ensemble mean of per-profile samples (B, ...) with a control variate, and its standard error.

    With the Kirchhoff control K_p = |S_p|² of the same profiles (speckle nearly identical to the wave
    solution's wherever Kirchhoff is good) and its exact expectation E K, the estimate
    W̄ − β (K̄ − E K), β = cov(W, K)/var(K) per angle (the regression estimator: variance
    var(W)(1 − ρ²), bias O(1/B)), keeps the wave solution's mean and removes the part of its
    speckle that Kirchhoff predicts. `expected=None`: the plain mean. SE from the residuals
    W_p − β K_p (ddof 2), or the plain SE (ddof 1); 0 for one profile.
    """
    b = samples.shape[0]
    mean = jnp.mean(samples, axis=0)
    if b < 2:
        return mean, jnp.zeros_like(mean)
    if expected is None:
        return mean, jnp.std(samples, axis=0, ddof=1) / math.sqrt(b)
    dk = control - jnp.mean(control, axis=0)
    var_k = jnp.sum(dk**2, axis=0)
    beta = jnp.where(var_k > 0, jnp.sum((samples - mean) * dk, axis=0) / jnp.where(var_k > 0, var_k, 1.0), 0.0)
    est = mean - beta * (jnp.mean(control, axis=0) - jnp.asarray(expected))
    resid = samples - beta * control
    return est, jnp.std(resid, axis=0, ddof=2) / math.sqrt(b)


def expected_control_amplitude(covariance, x, g: float, k: float, inc_rad, ang_rad) -> np.ndarray:
    """E S = Σ_n w_n e^{−iq_x x_n} e^{−q_z² C_0/2} of the Kirchhoff control sum (see
    `expected_control_power`), (A, I) complex."""
    c0 = float(np.asarray(covariance)[0])
    w = np.exp(-np.asarray(x, float) ** 2 / g**2)
    qx = k * (np.sin(ang_rad)[:, None] - np.sin(inc_rad)[None, :])
    qz = k * (np.cos(ang_rad)[:, None] + np.cos(inc_rad)[None, :])
    phase = np.exp(-1j * qx[..., None] * np.asarray(x, float))  # (A, I, N)
    return (phase @ w) * np.exp(-0.5 * qz**2 * c0)


def coherent_estimate(amps, norm, window, theta_rad, control=None, expected=None):
    """Unbiased coherent part from per-profile amplitudes (B, C, S, I).

    Per angle and channel, the mean field Eψ is estimated by ψ̄ (or, with the Kirchhoff control
    amplitudes S_p (B, S, I) and their exact mean E S, by the regression estimate
    ψ̄ − β (S̄ − E S), β = Σ(ψ − ψ̄)(S − S̄)*/Σ|S − S̄|², which removes the diffuse field's noise
    wherever Kirchhoff follows the wave solution), and |Eψ|² by |ψ̂|² − v/B with v the residual
    variance (ddof 1, or 2 with the control): unbiased for any B (to O(1/B²) with the control),
    where |ψ̄|² alone carries the diffuse power / B. Channels are averaged (unpolarised), the result
    is kept inside the specular beam `window` (S, I) and integrated over θ_s; its standard error is
    a delete-a-group jackknife (`JACKKNIFE_GROUPS` groups).

    Returns:
        (σ_coherent (S, I), R_coh (I,), SE of R_coh (I,)); with one profile |ψ|² and SE 0.
    """
    b = amps.shape[0]
    amps = np.asarray(amps)
    win = np.asarray(window, float)
    norm = np.asarray(norm)
    use_control = control is not None and expected is not None and b >= MIN_PROFILES_CONTROL
    if use_control:
        control = np.asarray(control)[:, None]  # (B, 1, S, I), shared by the channels
        expected = np.asarray(expected)

    def estimate(idx):
        a = amps[idx]
        m = a.shape[0]
        bar = a.mean(0)
        if m < 2:
            power = np.abs(bar) ** 2
        elif use_control:
            s = control[idx]
            ds = s - s.mean(0)
            var_s = np.sum(np.abs(ds) ** 2, 0)
            beta = np.where(var_s > 0, np.sum((a - bar) * np.conj(ds), 0) / np.where(var_s > 0, var_s, 1.0), 0.0)
            est = bar - beta * (s.mean(0) - expected)
            resid = a - beta * s
            power = np.abs(est) ** 2 - np.sum(np.abs(resid - resid.mean(0)) ** 2, 0) / (m - 2) / m
        else:
            power = np.abs(bar) ** 2 - np.sum(np.abs(a - bar) ** 2, 0) / (m - 1) / m
        sig = power.mean(0) / norm * win  # (S, I)
        return sig, np.trapezoid(sig, theta_rad, axis=0)

    sig, r = estimate(np.arange(b))
    if b < 4:
        return jnp.asarray(sig), jnp.asarray(r), jnp.zeros_like(jnp.asarray(r))
    groups = np.array_split(np.arange(b), min(JACKKNIFE_GROUPS, b))
    rg = np.stack([estimate(np.setdiff1d(np.arange(b), gi))[1] for gi in groups])
    G = len(groups)
    se = np.sqrt((G - 1) / G * np.sum((rg - rg.mean(0)) ** 2, 0))
    return jnp.asarray(sig), jnp.asarray(r), jnp.asarray(se)
