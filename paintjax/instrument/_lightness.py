"""Reflectance factor → CIE Y → CIE 1976 lightness L*, the spectral path, and the flop index.

`lightness` / `lightness_np` follow CIE 1976 with Y_n = 100 and never clip: metallic
paints exceed L* = 100 near the specular direction. The NumPy path calls colour-science; the
JAX path is the same formula, differentiable, and is tested against it.
"""

from __future__ import annotations

from functools import lru_cache

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

_EPSILON = 216.0 / 24389.0  # (6/29)^3
_KAPPA = 24389.0 / 27.0


def _check_finite(name: str, x) -> None:
    try:
        a = np.asarray(x, dtype=float)
    except (TypeError, ValueError):
        return
    if np.any(~np.isfinite(a)):
        raise ValueError(f"{name} must be finite, got {x!r}")


def lightness(Y: ArrayLike) -> Float[Array, "..."]:
    """CIE 1976 L* of tristimulus Y (Y_n = 100), JAX, differentiable, unclipped above 100."""
    y = jnp.asarray(Y, dtype=jnp.result_type(float)) / 100.0
    safe = jnp.where(y > _EPSILON, y, 1.0)
    return jnp.where(y > _EPSILON, 116.0 * jnp.cbrt(safe) - 16.0, _KAPPA * y)


def lightness_np(Y) -> np.ndarray:
    """CIE 1976 L* via colour-science (reference path)."""
    import colour

    _check_finite("Y", Y)
    return np.asarray(colour.colorimetry.lightness_CIE1976(np.asarray(Y, dtype=float), Y_n=100.0))


def _check_reflectance(name: str, R) -> None:
    """Concrete values only (traced values pass): finite, real and ≥ 0, else a ValueError naming `name`."""
    if R is None or isinstance(R, (str, bytes)):
        raise ValueError(f"{name} must be a finite reflectance factor >= 0, got {R!r}")
    try:
        a = np.asarray(R)
    except Exception:  # a JAX tracer: checked where it was concrete
        return
    if a.dtype == object or not (np.issubdtype(a.dtype, np.number) or np.issubdtype(a.dtype, np.bool_)) or np.iscomplexobj(a):
        raise ValueError(f"{name} must be a finite real reflectance factor >= 0, got {R!r}")
    if np.any(~np.isfinite(a)) or np.any(a < 0):
        raise ValueError(f"{name} must be a finite reflectance factor >= 0, got {R!r}")


def reflectance_factor_to_lightness(R: ArrayLike) -> Float[Array, "..."]:
    """L* of a reflectance factor R (Y = 100 R); concrete R must be finite and ≥ 0 (ValueError)."""
    _check_reflectance("R", R)
    return lightness(100.0 * jnp.asarray(R))


def lightness_to_reflectance_factor(L_star) -> np.ndarray:
    """Inverse of `reflectance_factor_to_lightness` (NumPy)."""
    L = np.asarray(L_star, dtype=float)
    _check_finite("L_star", L)
    y = np.where(L > _KAPPA * _EPSILON, ((L + 16.0) / 116.0) ** 3, L / _KAPPA)
    return y


def flop_index(L15: ArrayLike, L45: ArrayLike, L110: ArrayLike) -> Float[Array, "..."]:
    """X-Rite flop index FI = 2.69 (L*15 − L*110)^1.11 / (L*45)^0.86."""
    return 2.69 * jnp.power(jnp.asarray(L15) - jnp.asarray(L110), 1.11) / jnp.power(jnp.asarray(L45), 0.86)


@lru_cache(maxsize=8)
def spectral_weights(start_nm: int = 380, end_nm: int = 780, interval_nm: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """Wavelengths [nm] and XYZ weights (3, nλ) for D65 × CIE 1964 10° observer.

    The weights are normalised so that a perfect reflector (R = 1) gives Y = 100, exactly as
    `colour.sd_to_XYZ(..., method="Integration")` computes it on the same grid.
    """
    import colour

    if not (360 <= start_nm < end_nm <= 830) or interval_nm <= 0:
        raise ValueError(
            f"spectral grid must satisfy 360 <= start_nm < end_nm <= 830 and interval_nm > 0, "
            f"got {start_nm}, {end_nm}, {interval_nm}"
        )
    shape = colour.SpectralShape(start_nm, end_nm, interval_nm)
    cmfs = colour.MSDS_CMFS["CIE 1964 10 Degree Standard Observer"].copy().align(shape)
    illuminant = colour.SDS_ILLUMINANTS["D65"].copy().align(shape)
    wl = shape.wavelengths
    S = illuminant.values
    xyz_bar = cmfs.values.T  # (3, nλ)
    k = 100.0 / np.sum(S * xyz_bar[1] * interval_nm)
    return np.asarray(wl, dtype=float), k * xyz_bar * S * interval_nm


def spectral_to_xyz(reflectance: Float[ArrayLike, "... nl"], weights: Float[ArrayLike, "3 nl"]) -> Float[Array, "... 3"]:
    """XYZ (Y = 100 for a perfect reflector) of reflectance spectra on the weights' grid (JAX)."""
    return jnp.einsum("...l,cl->...c", jnp.asarray(reflectance), jnp.asarray(weights))


def spectral_lightness(reflectance: Float[ArrayLike, "... nl"], weights: Float[ArrayLike, "3 nl"]) -> Float[Array, "..."]:
    """L* of reflectance-factor spectra (JAX)."""
    return lightness(spectral_to_xyz(reflectance, weights)[..., 1])
