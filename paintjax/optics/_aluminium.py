"""Optical constants of aluminium.

Source: the Lorentz–Drude model of A. D. Rakić, A. B. Djurišić, J. M. Elazar and
M. L. Majewski, "Optical properties of metallic films for vertical-cavity optoelectronic
devices", Appl. Opt. 37, 5271 (1998), Table 1 (Al), fitted to the data of A. D. Rakić,
"Algorithm for the determination of intrinsic optical constants of metal films: application
to aluminum", Appl. Opt. 34, 4755 (1995). Valid 0.1–6 eV; used here over 380–780 nm.

At 550 nm the model gives n + ik = 0.966 + 6.458i against Rakić (1995)'s tabulated
1.015 + 6.627i; the normal reflectance into n = 1.5 differs by < 0.002 (0.879 vs 0.880).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Complex

from .._validate import Range
from ._fresnel import fresnel_conductor

_HC_EV_UM = 1.23984198  # photon energy [eV] × wavelength [µm]
_PLASMA_EV = 14.98
_F0, _GAMMA0 = 0.523, 0.047
_OSC_F = (0.227, 0.050, 0.166, 0.030)
_OSC_GAMMA = (0.333, 0.312, 1.351, 3.382)
_OSC_OMEGA = (0.162, 1.544, 1.808, 3.473)

#: Rakić (1995) tabulated index at 550 nm, quoted in the domain brief.
RAKIC1995_550NM = 1.015 + 6.627j

VISIBLE_RANGE_UM = (0.38, 0.78)
#: Where the Lorentz–Drude model holds (its 0.1–6 eV window, in µm).
WAVELENGTH_RANGE = Range(0.2, 12.0, "µm", why="Lorentz–Drude validity")


def _check_wavelength(wavelength_um) -> None:
    try:
        w = np.asarray(wavelength_um, dtype=float)
    except (TypeError, ValueError):
        return
    if not all(WAVELENGTH_RANGE.contains(float(v)) for v in np.ravel(w)):
        raise ValueError(f"wavelength_um must {WAVELENGTH_RANGE.describe()}, got {wavelength_um!r}")


def aluminium_permittivity(wavelength_um: ArrayLike) -> Complex[Array, "..."]:
    """Relative permittivity ε = ε' + iε'' of aluminium (exp(−iωt), ε'' > 0).

    Arguments:
        wavelength_um: vacuum wavelength in micrometres.
    """
    _check_wavelength(wavelength_um)
    w = _HC_EV_UM / jnp.asarray(wavelength_um, dtype=jnp.result_type(float))
    wp2 = _PLASMA_EV**2
    eps = 1.0 - _F0 * wp2 / (w * (w + 1j * _GAMMA0))
    for f, g, w0 in zip(_OSC_F, _OSC_GAMMA, _OSC_OMEGA):
        eps = eps + f * wp2 / (w0**2 - w**2 - 1j * w * g)
    return eps


def aluminium_index(wavelength_um: ArrayLike) -> Complex[Array, "..."]:
    """Complex refractive index n + ik of aluminium at the given vacuum wavelength [µm]."""
    return jnp.sqrt(aluminium_permittivity(wavelength_um))


def aluminium_reflectance(cos_i: ArrayLike, wavelength_um: ArrayLike = 0.55, n_binder: float = 1.5):
    """Unpolarised reflectance of a flat aluminium surface embedded in a binder of index n_binder."""
    return fresnel_conductor(cos_i, n_binder, aluminium_index(wavelength_um))[2]
