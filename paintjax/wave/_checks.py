"""The wave solver's input checks and its energy refusal (each names the API argument; the CLI writes its flag)."""

from __future__ import annotations

import numpy as np

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
