"""Multi-angle spectrophotometer geometry (ASTM E2194 / MA98 style) and its refraction into a coat.

Conventions (domain brief §3): z is the paint normal; direction vectors point *away* from the
surface (toward the source, toward the detector). The illuminator sits in the x–z plane on the
−x side, so the specular direction is on the +x side. The aspecular angle γ is measured from the
specular direction toward the illuminator; the detector's signed polar angle is θ_i − γ
(positive: specular side, negative: illuminator side).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

#: MA98 aspecular angles for 45° illumination.
ASPECULAR_45 = (-15.0, 15.0, 25.0, 45.0, 75.0, 110.0)
#: MA98 aspecular angles for 15° illumination.
ASPECULAR_15 = (-45.0, -15.0, 15.0, 45.0, 80.0)
#: The five standard angles reported for 45° illumination.
STANDARD_ASPECULAR = (15.0, 25.0, 45.0, 75.0, 110.0)
#: Largest detector or illumination polar angle accepted [deg].
MAX_POLAR_DEG = 85.0


def direction(polar_deg, azimuth_deg):
    """Unit vector(s) at polar/azimuth angles in degrees (z up)."""
    t = jnp.deg2rad(jnp.asarray(polar_deg, dtype=jnp.result_type(float)))
    p = jnp.deg2rad(jnp.asarray(azimuth_deg, dtype=jnp.result_type(float)))
    return jnp.stack([jnp.sin(t) * jnp.cos(p), jnp.sin(t) * jnp.sin(p), jnp.cos(t)], axis=-1)


def refract_into_coat(w_air: Float[Array, "... 3"], n: float) -> Float[Array, "... 3"]:
    """Direction inside a flat coat of index n for an upward direction w_air in air.

    Both point away from the surface; the tangential component shrinks by 1/n.
    """
    t = w_air[..., :2] / n
    return jnp.concatenate([t, jnp.sqrt(1.0 - jnp.sum(t**2, axis=-1, keepdims=True))], axis=-1)


def mirror_tilt_deg(w_in: Float[Array, "... 3"], w_out: Float[Array, "... 3"]) -> Float[Array, "..."]:
    """Tilt from the paint normal of the mirror whose normal is the half vector of w_in, w_out."""
    h = w_in + w_out
    h = h / jnp.linalg.norm(h, axis=-1, keepdims=True)
    return jnp.rad2deg(jnp.arccos(jnp.clip(h[..., 2], -1.0, 1.0)))


class Geometry(eqx.Module):
    """One illumination direction and m detectors, with optional finite aperture half-angles.

    Build with `ma98_geometry` or `custom_geometry` (which validate their input).
    """

    illumination_polar_deg: Float[Array, ""]
    illumination_azimuth_deg: Float[Array, ""]
    detector_polar_deg: Float[Array, " m"]
    detector_azimuth_deg: Float[Array, " m"]
    aspecular_deg: Float[Array, " m"]  # NaN for detectors outside the illumination plane
    illumination_aperture_deg: float = eqx.field(static=True, default=0.0)
    detector_aperture_deg: float = eqx.field(static=True, default=0.0)

    @property
    def num_detectors(self) -> int:
        return int(self.detector_polar_deg.shape[0])

    def illumination_air(self) -> Float[Array, "3"]:
        """Unit vector toward the source, in air."""
        return direction(self.illumination_polar_deg, self.illumination_azimuth_deg)

    def detectors_air(self) -> Float[Array, "m 3"]:
        """Unit vectors toward the detectors, in air."""
        return direction(self.detector_polar_deg, self.detector_azimuth_deg)

    def illumination_in_coat(self, n: float) -> Float[Array, "3"]:
        return refract_into_coat(self.illumination_air(), n)

    def detectors_in_coat(self, n: float) -> Float[Array, "m 3"]:
        return refract_into_coat(self.detectors_air(), n)

    def probed_tilt_deg(self, n: float) -> Float[Array, " m"]:
        """Platelet tilt that mirrors the refracted illumination into each refracted detector."""
        return mirror_tilt_deg(self.illumination_in_coat(n)[None, :], self.detectors_in_coat(n))


def _validate_polar(name: str, values) -> np.ndarray:
    try:
        v = np.atleast_1d(np.asarray(values, dtype=float))
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be finite polar angles within ±{MAX_POLAR_DEG}°, got {values!r}") from None
    if v.size == 0 or np.any(~np.isfinite(v)) or np.any(np.abs(v) > MAX_POLAR_DEG):
        raise ValueError(f"{name} must be finite polar angles within ±{MAX_POLAR_DEG}°, got {values!r}")
    return v


def _validate_aperture(name: str, value: float, polar_deg=0.0) -> float:
    """Aperture half-angle in [0, 20]° whose cone around every direction of `polar_deg` stays above the horizon."""
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must lie in [0, 20] degrees, got {value!r}") from None
    if not (0.0 <= value <= 20.0):
        raise ValueError(f"{name} must lie in [0, 20] degrees, got {value!r}")
    steepest = float(np.max(np.abs(np.asarray(polar_deg, dtype=float))))
    if steepest + value >= 90.0:
        raise ValueError(f"{name} must be below {90.0 - steepest:g}° here: its cone around the {steepest:g}° direction "
                         f"would reach below the horizon, got {value!r}")
    return value


def ma98_geometry(
    illumination_deg: float = 45.0,
    aspecular_deg=STANDARD_ASPECULAR,
    *,
    illumination_aperture_deg: float = 0.0,
    detector_aperture_deg: float = 0.0,
) -> Geometry:
    """In-plane multi-angle geometry: illumination polar angle and aspecular detector angles.

    Arguments:
        illumination_deg: illumination polar angle (45 or 15 on an MA98; any in (0, 85]).
        aspecular_deg: aspecular angles γ; the detector polar angle is illumination_deg − γ and
            must stay within ±85°, i.e. γ ∈ [illumination_deg − 85, illumination_deg + 85].
        illumination_aperture_deg, detector_aperture_deg: aperture half-angles in [0, 20]°.

    Returns:
        A `Geometry`.
    """
    theta_i = float(_validate_polar("illumination_deg", illumination_deg)[0])
    if theta_i <= 0:
        raise ValueError(f"illumination_deg must lie in (0, {MAX_POLAR_DEG}], got {illumination_deg!r}")
    gamma = np.atleast_1d(np.asarray(aspecular_deg, dtype=float))
    lo, hi = theta_i - MAX_POLAR_DEG, theta_i + MAX_POLAR_DEG
    if gamma.size == 0 or np.any(~np.isfinite(gamma)) or np.any((gamma < lo) | (gamma > hi)):
        raise ValueError(
            f"aspecular_deg must lie in [{lo:g}, {hi:g}] for {theta_i:g}° illumination "
            f"(detector within ±{MAX_POLAR_DEG}° of the normal), got {aspecular_deg!r}"
        )
    signed = theta_i - gamma
    return Geometry(
        illumination_polar_deg=jnp.asarray(theta_i),
        illumination_azimuth_deg=jnp.asarray(180.0),
        detector_polar_deg=jnp.asarray(np.abs(signed)),
        detector_azimuth_deg=jnp.asarray(np.where(signed >= 0, 0.0, 180.0)),
        aspecular_deg=jnp.asarray(gamma),
        illumination_aperture_deg=_validate_aperture("illumination_aperture_deg", illumination_aperture_deg, theta_i),
        detector_aperture_deg=_validate_aperture("detector_aperture_deg", detector_aperture_deg, signed),
    )


def custom_geometry(
    illumination_polar_deg: float,
    detector_polar_deg,
    detector_azimuth_deg=0.0,
    *,
    illumination_azimuth_deg: float = 180.0,
    illumination_aperture_deg: float = 0.0,
    detector_aperture_deg: float = 0.0,
) -> Geometry:
    """User-defined geometry: any illumination and detector directions (polar, azimuth in degrees).

    Detectors in the illumination plane get their aspecular angle; others get NaN. Under normal
    illumination every detector lies in a plane with the source, and its aspecular angle is
    −θ_detector (beyond the specular direction, the normal).
    """
    theta_i = float(_validate_polar("illumination_polar_deg", illumination_polar_deg)[0])
    if theta_i < 0:
        raise ValueError(f"illumination_polar_deg must lie in [0, {MAX_POLAR_DEG}] (the side is set by "
                         f"illumination_azimuth_deg), got {illumination_polar_deg!r}")
    det = _validate_polar("detector_polar_deg", detector_polar_deg)
    if np.any(det < 0):
        raise ValueError(f"detector_polar_deg must lie in [0, {MAX_POLAR_DEG}] (the side is set by "
                         f"detector_azimuth_deg), got {detector_polar_deg!r}")
    az = np.broadcast_to(np.asarray(detector_azimuth_deg, dtype=float), det.shape).copy()
    if np.any(~np.isfinite(az)) or np.any(np.abs(az) > 720.0):
        raise ValueError(f"detector_azimuth_deg must be finite, within ±720°, got {detector_azimuth_deg!r}")
    phi_i = float(illumination_azimuth_deg)
    if not (np.isfinite(phi_i) and abs(phi_i) <= 720.0):
        raise ValueError(f"illumination_azimuth_deg must be finite, within ±720°, got {illumination_azimuth_deg!r}")
    # Signed polar of each detector within the illumination plane (specular side positive).
    rel = np.mod(az - phi_i + 180.0, 360.0)
    in_plane = np.isclose(rel, 0.0) | np.isclose(rel, 360.0) | np.isclose(rel, 180.0) | (det == 0.0) | (theta_i == 0.0)
    signed = np.where(np.isclose(rel, 180.0), -det, det)
    gamma = np.where(in_plane, theta_i - signed, np.nan)
    return Geometry(
        illumination_polar_deg=jnp.asarray(theta_i),
        illumination_azimuth_deg=jnp.asarray(phi_i),
        detector_polar_deg=jnp.asarray(det),
        detector_azimuth_deg=jnp.asarray(az),
        aspecular_deg=jnp.asarray(gamma),
        illumination_aperture_deg=_validate_aperture("illumination_aperture_deg", illumination_aperture_deg, theta_i),
        detector_aperture_deg=_validate_aperture("detector_aperture_deg", detector_aperture_deg, det),
    )


def hemisphere_quadrature(n: float = 1.5, nodes: int = 16) -> tuple[Geometry, np.ndarray]:
    """Normal illumination and detectors at azimuth 0 whose weights integrate the exit hemisphere.

    Σ_j w_j R_j ≈ (1/π) ∫ R cos θ dω, the fraction of the incident light that leaves, for a
    statistically isotropic paint (under normal illumination it reflects alike at every azimuth).
    Gauss–Legendre in θ on [0, MAX_POLAR_DEG]; the rest of the hemisphere is added to the last
    node's weight, with radiance ∝ the coat's transmittance T_o(θ) there (isotropic radiance under
    a coat of index n; 0.23 % of the light for n = 1.5).

    Arguments:
        n: coat index (for the part beyond MAX_POLAR_DEG).
        nodes: Gauss–Legendre nodes in θ.

    Returns:
        (geometry, weights of shape (nodes,)).
    """
    from scipy import integrate

    from ..optics._fresnel import fresnel_dielectric

    def transmittance(mu):
        return 1.0 - float(fresnel_dielectric(float(mu), 1.0, n)[2])

    x, wx = np.polynomial.legendre.leggauss(nodes)
    top = np.deg2rad(MAX_POLAR_DEG)
    theta, w_theta = top * 0.5 * (x + 1), top * 0.5 * wx
    weights = 2.0 * np.cos(theta) * np.sin(theta) * w_theta
    tail = 2.0 * integrate.quad(lambda m: m * transmittance(m), 0.0, np.cos(top))[0]  # (1/π)∫R cos dω = 2∫R μ dμ
    weights[-1] += tail / transmittance(np.cos(theta[-1]))
    return custom_geometry(0.0, np.rad2deg(theta), 0.0), weights
