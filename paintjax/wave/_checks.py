"""The wave solver's input checks and its energy refusal (each names the API argument; the CLI writes its flag)."""

from __future__ import annotations

import math

import numpy as np

from .._validate import SEED, Range
from ..optics._aluminium import WAVELENGTH_RANGE

#: Most scattering angles of one solve.
MAX_ANGLES = 20000


def _check_angles(name: str, deg, lo: float, hi: float) -> np.ndarray:
    a = np.atleast_1d(np.asarray(deg, dtype=float))
    if a.ndim != 1 or a.size == 0 or a.size > MAX_ANGLES or not np.all(np.isfinite(a)) or np.any(a < lo) or np.any(a > hi):
        got = repr(deg) if a.size <= 8 else f"{a.size} values from {np.nanmin(a):.6g} to {np.nanmax(a):.6g}"
        raise ValueError(f"{name} must be a non-empty 1-D list of at most {MAX_ANGLES} angles in [{lo:.4g}, {hi:.4g}] degrees, got {got}")
    return a


#: Reflected + absorbed power above 1 + this at any incidence marks an unconverged solve (a converged
#: one conserves energy to ~1e-3; the truncated profile's runoff loses ≲ 2 % near grazing, not refused).
WAVE_ENERGY_TOLERANCE = 0.01
#: Largest rms roughness and correlation length of a synthesised surface [µm].
MAX_SIGMA_UM, MAX_TAU_UM = 10.0, 100.0
#: Most profiles of one average (each is a dense solve; the tables use 40).
MAX_PROFILES = 2000
#: Most points on one profile (a dense complex system of this order per profile and polarisation).
MAX_PROFILE_POINTS = 8000


def check_energy(reflected, absorbed, incidence_deg, *, solved=None, what: str = "the wave solution",
                 fix: str = "more points per wavelength or a gentler slope") -> None:
    """Refuse an unconverged solve: a ValueError with the energy ledger where reflected + absorbed
    power exceeds 1 + `WAVE_ENERGY_TOLERANCE` at any incidence (`solved`: where `absorbed` was solved;
    elsewhere the reflected power alone is checked)."""
    R = np.atleast_1d(np.asarray(reflected, float))
    A = np.broadcast_to(np.asarray(absorbed, float), R.shape)
    inc = np.broadcast_to(np.asarray(incidence_deg, float), R.shape)
    total = np.where(np.ones(R.shape, bool) if solved is None else np.asarray(solved, bool), R + A, R)
    if np.all(total <= 1.0 + WAVE_ENERGY_TOLERANCE):
        return
    j = int(np.argmax(total))
    raise ValueError(f"{what} reflects {R[j]:.3g} and absorbs {A[j]:.3g} of the incident power at {inc[j]:g}° incidence "
                     f"(sum {total[j]:.3g} > 1 + {WAVE_ENERGY_TOLERANCE:g}), so it is not converged; use {fix}")


def _check_profile_points(points: float) -> None:
    if not points <= MAX_PROFILE_POINTS:
        raise ValueError(f"length_um / spacing = {points:.4g} points on one profile, more than {MAX_PROFILE_POINTS}: shorten "
                         "length_um, or raise wavelength_um or lower points_per_wavelength")


def _check_scalar(name: str, value, lo: float, hi: float) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number in ({lo}, {hi}], got {value!r}") from None
    if not (np.isfinite(v) and lo < v <= hi):
        raise ValueError(f"{name} must lie in ({lo}, {hi}], got {value!r}")
    return v


#: The ranges of `profile_averaged_lobes`' arguments (and of `paintjax lobe`'s and `paintjax brdf`'s flags): the binder
#: a dielectric (1 for air), the wavelength the aluminium model's (`paintjax.optics._aluminium.WAVELENGTH_RANGE`).
LOBE_RANGES = {
    "sigma_um": Range(0.0, MAX_SIGMA_UM, "µm", lo_open=True),
    "tau_um": Range(0.0, MAX_TAU_UM, "µm", lo_open=True),
    "wavelength_um": WAVELENGTH_RANGE,
    "n_medium": Range(1.0, 5.0, why="binder refractive index"),
    "length_um": Range(0.0, 1e6, "µm", lo_open=True),
    "num_profiles": Range(1, MAX_PROFILES, integer=True),
    "seed": SEED,
    "points_per_wavelength": Range(4.0, 200.0),
}
#: The wavelength range for perfect conductors or a given metal index.
OTHER_WAVELENGTHS = Range(0.0, 20.0, "µm", lo_open=True)


def check_lobe_sizes(length_um: float, dx: float, tau_um: float, k: float, points_per_wavelength=None) -> None:
    """The profile's sizes, before any mesh is built: at most `MAX_PROFILE_POINTS` points, a grid step that
    resolves the roughness (≤ τ/2), and a profile long enough for the Thorsos beam (taper L/4 ≥ 1/(k√0.04)),
    each a ValueError naming the argument to change."""
    from ._beam import MAX_BEAM_CORRECTION

    _check_profile_points(length_um / dx)
    if dx > tau_um / 2.0:
        raise ValueError(f"tau_um must be at least two grid steps, {2 * dx:.3g} µm at this wavelength_um, n_medium and "
                         f"points_per_wavelength ({points_per_wavelength or 'default'}): raise points_per_wavelength, got {tau_um!r}")
    shortest = 4.0 / (k * math.sqrt(2.0 * MAX_BEAM_CORRECTION))
    if length_um < shortest:
        raise ValueError(f"length_um must be at least {shortest:.3g} µm at this wavelength_um and n_medium (the tapered beam's "
                         f"width L/4 must exceed {shortest / 4:.3g} µm), got {length_um!r}")
