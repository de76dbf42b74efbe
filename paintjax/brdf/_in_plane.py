"""In-plane platelet lobes: the wave solver's or Kirchhoff's σ(θ_i, θ_s), and their grazing extension.

`InPlaneLobes` carries a lobe source's in-plane differential cross-sections (incoherent and coherent),
reflected and absorbed power per incidence and, for the wave solver, their standard errors. The
tables (`platelet_table_arrays`) turn these into a 3-D BRDF.
"""

from __future__ import annotations

import equinox as eqx
import numpy as np
from scipy.special import gammaln as np_gammaln

from ..wave._beam import max_incidence_deg
from ..wave._solver import profile_averaged_lobes
from ._analytic import check_positive, metal_index_or_aluminium, series_terms

#: Default tabulated incidences [deg] (0–89°).
DEFAULT_INCIDENCE_DEG = np.concatenate([np.arange(0.0, 88.0, 3.0), [89.0]])
#: Profiles per wave table (with the Kirchhoff control variate their lobe's relative SE is ≲ 1 % in
#: the Kirchhoff regime; see experiments/wave_convergence.py).
DEFAULT_NUM_PROFILES = 40


class InPlaneLobes(eqx.Module):
    """In-plane lobes with the fields of `paintjax.wave._solver.WaveLobes` (any lobe source).

    Fields: incidence_deg (I,), theta_s_deg (S,), sigma (I, S) [1/rad], sigma_coherent (I, S),
    reflected (I,), absorbed (I,); optional statistical errors (None for closed forms): sigma_sem
    (I, S), reflected_se (I,), coherent_reflectance_se (I,).
    """

    incidence_deg: np.ndarray
    theta_s_deg: np.ndarray
    sigma: np.ndarray
    sigma_coherent: np.ndarray
    reflected: np.ndarray
    absorbed: np.ndarray
    sigma_sem: np.ndarray | None = None
    reflected_se: np.ndarray | None = None
    coherent_reflectance_se: np.ndarray | None = None

    def errors(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(sigma_sem, reflected_se, coherent_reflectance_se) with zeros where not given."""
        z = lambda a, shape: np.zeros(shape) if a is None else np.asarray(a, float)  # noqa: E731
        return z(self.sigma_sem, self.sigma.shape), z(self.reflected_se, self.reflected.shape), z(self.coherent_reflectance_se, self.reflected.shape)


def check_medium_index(n_medium) -> None:
    """The dielectric above the metal: a real index in [1, 5]."""
    try:
        v = float(n_medium)
    except (TypeError, ValueError):
        raise ValueError(f"n_medium must be a number in [1, 5], got {n_medium!r}") from None
    if not (1.0 <= v <= 5.0):
        raise ValueError(f"n_medium must lie in [1, 5] (a dielectric above the metal), got {n_medium!r}")


def _fresnel_np(cos_i, n1, n2):
    """Unpolarised metal reflectance on the host (same formula as `fresnel_conductor`)."""
    cos_i = np.clip(np.abs(cos_i), 0.0, 1.0)
    cos_t = np.sqrt(1.0 - (n1 / n2) ** 2 * (1.0 - cos_i**2) + 0j)
    rs = (n1 * cos_i - n2 * cos_t) / (n1 * cos_i + n2 * cos_t)
    rp = (n2 * cos_i - n1 * cos_t) / (n2 * cos_i + n1 * cos_t)
    return 0.5 * (np.abs(rs) ** 2 + np.abs(rp) ** 2)


def leontovich_reflectance(cos_i, n_medium, metal_index):
    """Unpolarised reflectance of a flat surface with the wave solver's impedance (Leontovich) boundary:
    r = (cosθ − η)/(cosθ + η), η_TE = √ε_r, η_TM = 1/√ε_r, ε_r = (metal index / n)² (exact Fresnel keeps
    sin²θ in √(ε_r − sin²θ); for Al in the binder they differ by ≲ 5e-3 up to 85°)."""
    c = np.abs(np.asarray(cos_i, float))
    root = np.sqrt((complex(metal_index) / n_medium) ** 2 + 0j)
    r = lambda eta: np.abs((c - eta) / (c + eta)) ** 2  # noqa: E731
    return 0.5 * (r(root) + r(1.0 / root))


def kirchhoff_lobes(
    sigma_um: float,
    tau_um: float,
    *,
    incidence_deg=DEFAULT_INCIDENCE_DEG,
    theta_s_deg=None,
    wavelength_um: float = 0.5,
    n_medium: float = 1.5,
    metal_index=None,
    coherent_width_deg: float = 0.25,
) -> InPlaneLobes:
    """In-plane lobes of a 1-D Gaussian metal profile from the Kirchhoff closed form (brief §4).

    σ(θ_s) = R(χ) (1 + cos(θ_i + θ_s))² k / (cosθ_i c²) Σ_m e^{−X} X^m/m! τ/(2√(πm)) e^{−K²τ²/(4m)},
    c = cosθ_i + cosθ_s, X = (kσc)², K = k(sinθ_s − sinθ_i), χ = |θ_i + θ_s|/2; the coherent part
    R(θ_i) e^{−(2kσ cosθ_i)²} is a narrow Gaussian in θ_s normalised on the grid.

    Arguments:
        sigma_um, tau_um: rms height and correlation length [µm].
        incidence_deg: incidence angles (I,); theta_s_deg: scattering angles (S,) (default 0.25° steps).
        wavelength_um, n_medium: vacuum wavelength and index of the medium above the metal.
        metal_index: complex metal index (default aluminium at λ0).
        coherent_width_deg: standard deviation of the coherent line on the θ_s grid.

    Returns:
        `InPlaneLobes`.
    """
    check_positive("sigma_um", sigma_um, 10.0)
    check_positive("tau_um", tau_um, 1e3)
    check_medium_index(n_medium)
    if theta_s_deg is None:
        theta_s_deg = np.linspace(-89.75, 89.75, 719)
    metal = metal_index_or_aluminium(metal_index, wavelength_um)
    ti = np.deg2rad(np.asarray(incidence_deg, float))[:, None]
    ts = np.deg2rad(np.asarray(theta_s_deg, float))[None, :]
    k = 2.0 * np.pi * n_medium / wavelength_um
    c = np.cos(ti) + np.cos(ts)
    X = np.maximum((k * sigma_um * c) ** 2, 1e-300)
    K = k * (np.sin(ts) - np.sin(ti))
    m = np.arange(1, series_terms(2.0 * k * sigma_um) + 1, dtype=float)
    log_t = -X[..., None] + m * np.log(X[..., None]) - np_gammaln(m + 1) - 0.5 * np.log(np.pi * m) + np.log(tau_um / 2.0) - (K**2)[..., None] * tau_um**2 / (4 * m)
    series = np.exp(log_t).sum(-1)
    R_local = _fresnel_np(np.cos(0.5 * np.abs(ti + ts)), n_medium, metal)
    sigma_inc = R_local * (1.0 + np.cos(ti + ts)) ** 2 * k / (np.cos(ti) * c**2) * series
    R_coh = _fresnel_np(np.cos(ti[:, 0]), n_medium, metal) * np.exp(-((2 * k * sigma_um * np.cos(ti[:, 0])) ** 2))
    line = np.exp(-0.5 * ((ts - ti) / np.deg2rad(coherent_width_deg)) ** 2)
    line = line / np.trapezoid(line, ts[0], axis=-1)[:, None]
    sigma_coh = R_coh[:, None] * line
    sigma = sigma_inc + sigma_coh
    reflected = np.trapezoid(sigma, ts[0], axis=-1)
    return InPlaneLobes(np.asarray(incidence_deg, float), np.asarray(theta_s_deg, float), sigma, sigma_coh, reflected, 1.0 - reflected)


def as_numpy_lobes(lobes) -> InPlaneLobes:
    """Any lobe source (fields of `WaveLobes`) as `InPlaneLobes` of numpy arrays (errors kept when present)."""
    f = lambda name: np.asarray(getattr(lobes, name), float)  # noqa: E731
    opt = lambda name: None if getattr(lobes, name, None) is None else f(name)  # noqa: E731
    return InPlaneLobes(f("incidence_deg"), f("theta_s_deg"), f("sigma"), f("sigma_coherent"), f("reflected"), f("absorbed"),
                        opt("sigma_sem"), opt("reflected_se"), opt("coherent_reflectance_se"))


def coherent_positive_part(lobes) -> InPlaneLobes:
    """The coherent part of a wave average with negative estimates removed.

    The wave solver's coherent part is already unbiased and confined to the specular beam
    (`paintjax.wave._solver.coherent_estimate`). For rough surfaces (true coherent fraction below its
    noise) the estimate of an incidence's coherent reflectance can integrate to < 0; such an
    incidence gets 0 (all of σ incoherent), the estimator's positive part, which lies within the
    stated standard error of the truth. σ itself is unchanged.
    """
    lob = as_numpy_lobes(lobes)
    ts = np.deg2rad(lob.theta_s_deg)
    coh = np.where(np.trapezoid(lob.sigma_coherent, ts, axis=-1)[:, None] > 0.0, lob.sigma_coherent, 0.0)
    return InPlaneLobes(lob.incidence_deg, lob.theta_s_deg, lob.sigma, coh, lob.reflected, lob.absorbed,
                        lob.sigma_sem, lob.reflected_se, lob.coherent_reflectance_se)


def concatenate_lobes(first: InPlaneLobes, second: InPlaneLobes) -> InPlaneLobes:
    """Lobes of two sources on the same θ_s grid, stacked along incidence (missing errors → 0)."""
    if first.theta_s_deg.shape != second.theta_s_deg.shape or not np.allclose(first.theta_s_deg, second.theta_s_deg):
        raise ValueError("lobes to concatenate must share theta_s_deg")
    cat = lambda name: np.concatenate([getattr(first, name), getattr(second, name)])  # noqa: E731
    errs = [np.concatenate(pair) for pair in zip(first.errors(), second.errors())]
    return InPlaneLobes(cat("incidence_deg"), first.theta_s_deg, cat("sigma"), cat("sigma_coherent"), cat("reflected"), cat("absorbed"), *errs)


def wave_lobes(sigma_um, tau_um, *, num_profiles: int = DEFAULT_NUM_PROFILES, **kwargs):
    """In-plane lobes from the wave solver (`profile_averaged_lobes`) with the tables' default number of profiles."""
    return profile_averaged_lobes(sigma_um, tau_um, num_profiles=num_profiles, **kwargs)


def _wave_with_grazing_extension(sigma_um, tau_um, inc, ts, *, length_um, num_profiles, wavelength_um, n_medium, metal_index, **kw):
    """Wave lobes up to the solver's largest incidence; beyond it, rescaled 1-D Kirchhoff lobes.

    The Thorsos beam limits the incidence (`paintjax.wave._solver.max_incidence_deg`, ≈74° for 20 µm
    profiles in the binder). Tabulated incidences above the limit take the *shape* and the coherent
    share of the 1-D Kirchhoff lobes of the same (σ, τ), and a total reflectance that follows the
    flat surface's reflectance under the solver's own (Leontovich) boundary from the last solved
    incidence: R(θ) = R_wave(θ_last) R_L(θ) / R_L(θ_last) (`leontovich_reflectance`; → 1 at grazing,
    never the unphysical growth of the Kirchhoff integral; R_L ≡ 1 for
    the perfect conductors, boundary "pec", "dirichlet", "neumann"). Which incidences were solved is
    stored as `wave_solved`.

    Returns:
        (InPlaneLobes, solved incidences).
    """
    lim = max_incidence_deg(length_um, wavelength_um, n_medium)
    inc_w, inc_k = inc[inc <= lim], inc[inc > lim]
    if inc_w.size == 0:
        raise ValueError(f"incidence_deg must include angles ≤ {lim:.1f}° (the wave solver's limit for length_um={length_um})")
    lobes = wave_lobes(
        sigma_um, tau_um, length_um=length_um, num_profiles=num_profiles, incidence_deg=inc_w, theta_s_deg=ts,
        wavelength_um=wavelength_um, n_medium=n_medium, metal_index=metal_index, **kw,
    )
    lobes = coherent_positive_part(lobes)
    if inc_k.size:
        kl = kirchhoff_lobes(sigma_um, tau_um, incidence_deg=inc_k, theta_s_deg=ts, wavelength_um=wavelength_um, n_medium=n_medium, metal_index=metal_index)
        cos_ext = np.cos(np.deg2rad(np.concatenate([inc_w[-1:], inc_k])))
        perfect = kw.get("boundary", "impedance") != "impedance"  # a perfect conductor reflects everything
        fres = np.ones_like(cos_ext) if perfect else leontovich_reflectance(cos_ext, n_medium, metal_index)
        target = lobes.reflected[-1] * fres[1:] / fres[0]
        r = (target / kl.reflected)[:, None]
        rel_se = lobes.errors()[1][-1] / lobes.reflected[-1]  # the last solved incidence's relative error, carried over
        ext = InPlaneLobes(inc_k, ts, r * kl.sigma, r * kl.sigma_coherent, target, 1.0 - target, None, rel_se * target, None)
        lobes = concatenate_lobes(lobes, ext)
    return lobes, inc_w
