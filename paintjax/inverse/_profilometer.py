"""A virtual profilometer: what the published roughness procedure reads on platelets of known (σ, τ).

The published σ = 51 ± 10 nm and τ = 640 ± 110 nm are not the surface's statistics but the output of
a procedure: a white-light interferometer scans 10 platelets extracted from the paint, one line over
each whole platelet (10–30 µm); a Gaussian filter with a cutoff of 50 % of the scan length removes
the curvature; the end points level the profile; σ is "the root-mean-square average of the
peak-to-valley heights" and τ the shortest lag at which the autocorrelation falls to 1/e.

`Profilometer` runs that procedure on synthesised Gaussian surfaces of known true (σ, τ), with the
interferometer's lateral resolution (a Gaussian point-spread function) and pixel, and returns what a
measurement campaign reads. Three readings of the σ definition are offered (`SIGMA_DEFINITIONS`):

* ``"rq"`` (default, the reading defended here): Rq, the RMS height of each processed profile about
  its mean; "σ_RMS" in the source names an RMS roughness, and the campaign value is the RMS over the
  platelets of their Rq;
* ``"local_pv"``: the RMS of the local peak-to-valley heights, i.e. of the height differences
  between successive local extrema of each profile;
* ``"scan_pv"``: the RMS over the platelets of each scan's total peak-to-valley height (Rt).

`campaign_distribution` gives the sampling distribution of a campaign's (σ̂, τ̂) for a true (σ, τ);
`ReadingModel` (from `build_reading_model`) makes it a smooth, jittable likelihood of the published
reading over the true (σ, τ), for the inverse layer.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..wave._profiles import LineScan, process_line_scan, profile_statistics, synthesize_profiles

SIGMA_DEFINITIONS = ("rq", "local_pv", "scan_pv")
#: FWHM [µm] of the default point-spread function: a 50× interferometer objective (NA ≈ 0.55) in
#: white light (mean λ ≈ 0.6 µm) resolves ≈ 0.51 λ/NA ≈ 0.55 µm (an assumption: the source gives the
#: instrument, Wyko NT3300, not the objective).
DEFAULT_RESOLUTION_UM = 0.55
#: Default pixel [µm] along the scan (sampling, not resolution, of the instrument).
DEFAULT_PIXEL_UM = 0.1
_FWHM_PER_SD = 2.0 * math.sqrt(2.0 * math.log(2.0))


def smoothed_gaussian_statistics(sigma_um, tau_um, resolution_um):
    """(σ, τ) of a Gaussian-correlated surface seen through a Gaussian PSF of FWHM `resolution_um`.

    C(x) = σ² e^{−x²/τ²} convolved twice with a Gaussian of SD s is again Gaussian with
    τ_s² = τ² + 4s² and σ_s² τ_s = σ² τ (the spectrum's K = 0 value is kept): the closed form the
    virtual instrument is tested against. Returns (σ_s, τ_s).
    """
    s = np.asarray(resolution_um, float) / _FWHM_PER_SD
    tau_s = np.sqrt(np.asarray(tau_um, float) ** 2 + 4.0 * s**2)
    return np.asarray(sigma_um, float) * np.sqrt(np.asarray(tau_um, float) / tau_s), tau_s


def _local_extrema_heights(h: np.ndarray) -> np.ndarray:
    """Heights of the interior local extrema of a profile, in order (plateaus count once)."""
    d = np.diff(h)
    d = d[d != 0.0]
    if d.size < 2:
        return np.empty(0)
    keep = np.flatnonzero(np.diff(np.sign(d)) != 0) + 1  # indices in the compressed profile
    hc = np.concatenate([[h[0]], h[1:][np.diff(h) != 0.0]])
    return hc[keep]


def profile_roughness(h: np.ndarray, definition: str = "rq") -> float:
    """One processed profile's roughness under a reading of the σ definition (`SIGMA_DEFINITIONS`)."""
    h = np.asarray(h, float)
    if definition == "rq":
        return float(np.sqrt(np.mean((h - h.mean()) ** 2)))
    if definition == "local_pv":
        e = _local_extrema_heights(h)
        return float(np.sqrt(np.mean(np.diff(e) ** 2))) if e.size >= 2 else 0.0
    if definition == "scan_pv":
        return float(h.max() - h.min())
    raise ValueError(f"definition must be one of {SIGMA_DEFINITIONS}, got {definition!r}")


class Profilometer(eqx.Module):
    """The published roughness procedure on a virtual white-light interferometer.

    Fields: `resolution_um` (FWHM of the Gaussian PSF; 0 = ideal), `pixel_um` (sampling step),
    `num_platelets` (scans per campaign), `scan_range_um` (each scan's length is uniform in this range),
    `cutoff_fraction` (Gaussian-filter cutoff as a fraction of the scan length; None = no filtering
    and no levelling, the closed-form check), `sigma_definition`.
    """

    resolution_um: float = DEFAULT_RESOLUTION_UM
    pixel_um: float = DEFAULT_PIXEL_UM
    num_platelets: int = 10
    scan_range_um: tuple[float, float] = (10.0, 30.0)
    cutoff_fraction: float | None = 0.5
    sigma_definition: str = "rq"

    def __check_init__(self):
        if not (math.isfinite(self.resolution_um) and 0.0 <= self.resolution_um <= 5.0):
            raise ValueError(f"resolution_um must lie in [0, 5] µm, got {self.resolution_um!r}")
        if not (math.isfinite(self.pixel_um) and 0.0 < self.pixel_um <= 1.0):
            raise ValueError(f"pixel_um must lie in (0, 1] µm, got {self.pixel_um!r}")
        if int(self.num_platelets) != self.num_platelets or not 1 <= self.num_platelets <= 10_000:
            raise ValueError(f"num_platelets must be an integer in [1, 10000], got {self.num_platelets!r}")
        lo, hi = self.scan_range_um
        if not (math.isfinite(lo) and math.isfinite(hi) and 2.0 <= lo <= hi <= 1000.0):
            raise ValueError(f"scan_range_um must be (lo, hi) with 2 ≤ lo ≤ hi ≤ 1000 µm, got {self.scan_range_um!r}")
        if self.cutoff_fraction is not None and not (0.0 < self.cutoff_fraction <= 1.0):
            raise ValueError(f"cutoff_fraction must lie in (0, 1] or be None (no filtering), got {self.cutoff_fraction!r}")
        if self.sigma_definition not in SIGMA_DEFINITIONS:
            raise ValueError(f"sigma_definition must be one of {SIGMA_DEFINITIONS}, got {self.sigma_definition!r}")

    def scans(self, key, sigma_um: float, tau_um: float) -> list[np.ndarray]:
        """The processed line scans (heights on the pixel grid) of one campaign over a true surface.

        Arguments:
            key: jax.random key (all randomness comes from it).
            sigma_um, tau_um: the true Gaussian surface's RMS height and 1/e correlation length [µm].

        Returns:
            `num_platelets` processed profiles (filtered and levelled unless `cutoff_fraction` is None).
        """
        if not (math.isfinite(sigma_um) and 0.0 < sigma_um <= 1.0):
            raise ValueError(f"sigma_um must lie in (0, 1] µm, got {sigma_um!r}")
        if not (math.isfinite(tau_um) and 0.01 <= tau_um <= self.scan_range_um[0] / 4.0):
            raise ValueError(f"tau_um must lie in [0.01, {self.scan_range_um[0] / 4.0:g}] µm (a quarter of the shortest scan), got {tau_um!r}")
        k_len, k_surf, k_off = jax.random.split(key, 3)
        lo, hi = self.scan_range_um
        lengths = np.asarray(jax.random.uniform(k_len, (self.num_platelets,), minval=lo, maxval=hi))
        psf_sd = self.resolution_um / _FWHM_PER_SD
        margin = 6.0 * psf_sd + 4.0 * tau_um  # periodic synthesis: the scan sees no wrap-around
        fine = min(tau_um / 8.0, self.pixel_um / 2.0, psf_sd / 3.0 if psf_sd > 0 else np.inf)
        surf = synthesize_profiles(k_surf, sigma_um, tau_um, length_um=hi + 2.0 * margin, spacing_um=fine,
                                   num_profiles=self.num_platelets)
        x = np.asarray(surf.x) - float(surf.x[0])
        h = np.asarray(surf.h)
        if psf_sd > 0:  # the instrument's Gaussian PSF, applied in Fourier space
            kk = 2.0 * np.pi * np.fft.rfftfreq(x.size, d=surf.spacing)
            h = np.fft.irfft(np.fft.rfft(h, axis=-1) * np.exp(-0.5 * (kk * psf_sd) ** 2), n=x.size, axis=-1)
        offsets = np.asarray(jax.random.uniform(k_off, (self.num_platelets,)))
        out = []
        for b, (length, u) in enumerate(zip(lengths, offsets)):
            start = margin + u * (hi - length)
            xs = start + self.pixel_um * np.arange(int(np.floor(length / self.pixel_um)) + 1)
            hs = np.interp(xs, x, h[b])
            if self.cutoff_fraction is None:
                out.append(hs - hs.mean())
            else:
                _, r = process_line_scan(LineScan(xs, hs), cutoff_fraction=self.cutoff_fraction, check_tau=False)
                out.append(r)
        return out

    def measure(self, key, sigma_um: float, tau_um: float) -> dict:
        """One campaign's reading of a true surface.

        Returns:
            dict with "sigma_um" (RMS over the platelets of their roughness under `sigma_definition`),
            "tau_um" (mean of the platelets' 1/e lengths), the per-platelet values "platelet_sigma_um",
            "platelet_tau_um", and "sigma_um_by_definition" (the campaign σ̂ under every reading, from
            the same scans).
        """
        profiles = self.scans(key, sigma_um, tau_um)
        by_def = {d: np.array([profile_roughness(p, d) for p in profiles]) for d in SIGMA_DEFINITIONS}
        tau = np.array([float(profile_statistics(p, self.pixel_um)["tau_um"]) for p in profiles])
        sig = by_def[self.sigma_definition]
        return {"sigma_um": float(np.sqrt(np.mean(sig**2))), "tau_um": float(np.mean(tau)), "platelet_sigma_um": sig,
                "platelet_tau_um": tau, "sigma_um_by_definition": {d: float(np.sqrt(np.mean(v**2))) for d, v in by_def.items()}}

    def campaign_distribution(self, key, sigma_um: float, tau_um: float, campaigns: int = 64) -> dict:
        """The sampling distribution of a campaign's (σ̂, τ̂) for a true (σ, τ).

        Arguments:
            key: jax.random key.
            sigma_um, tau_um: the true surface.
            campaigns: independent campaigns (each `num_platelets` scans).

        Returns:
            dict with the campaigns' "sigma_um", "tau_um" (arrays), their means and SDs, the mean and
            SD of log σ̂ and log τ̂ and their correlation ("log_sigma_mean", "log_sigma_sd",
            "log_tau_mean", "log_tau_sd", "log_correlation"), the mean across-platelet SDs within a
            campaign ("platelet_sigma_sd_um", "platelet_tau_sd_um": what a published "±" over the
            measured platelets would be), and "by_definition": the σ̂ statistics under every reading.
        """
        if int(campaigns) != campaigns or campaigns < 2:
            raise ValueError(f"campaigns must be an integer ≥ 2, got {campaigns!r}")
        runs = [self.measure(k, sigma_um, tau_um) for k in jax.random.split(key, int(campaigns))]
        t = np.array([r["tau_um"] for r in runs])
        by_def = {}
        for d in SIGMA_DEFINITIONS:
            s = np.array([r["sigma_um_by_definition"][d] for r in runs])
            by_def[d] = {"sigma_um": s, "sigma_mean_um": float(s.mean()), "sigma_sd_um": float(s.std(ddof=1)),
                         "log_sigma_mean": float(np.log(s).mean()), "log_sigma_sd": float(np.log(s).std(ddof=1)),
                         "log_correlation": float(np.corrcoef(np.log(s), np.log(t))[0, 1])}
        own = by_def[self.sigma_definition]
        return {
            **own, "tau_um": t, "tau_mean_um": float(t.mean()), "tau_sd_um": float(t.std(ddof=1)),
            "log_tau_mean": float(np.log(t).mean()), "log_tau_sd": float(np.log(t).std(ddof=1)),
            "platelet_sigma_sd_um": float(np.mean([r["platelet_sigma_um"].std(ddof=1) for r in runs])),
            "platelet_tau_sd_um": float(np.mean([r["platelet_tau_um"].std(ddof=1) for r in runs])),
            "by_definition": by_def,
        }


def normal2_log_density(dx, dy, sx, sy, r):
    """log density of a bivariate normal at offsets (dx, dy) from its mean, SDs (sx, sy), correlation r."""
    zx, zy = dx / sx, dy / sy
    q = (zx**2 - 2.0 * r * zx * zy + zy**2) / (1.0 - r**2)
    return -0.5 * q - jnp.log(2.0 * jnp.pi * sx * sy * jnp.sqrt(1.0 - r**2))


class ReadingModel(eqx.Module):
    """The sampling distribution of a campaign's reading (σ̂, τ̂) as a smooth function of the true (σ, τ).

    Heights scale with σ through every step of the procedure (PSF, filter, levelling are linear, and
    the three σ readings are homogeneous of degree one), and the 1/e length does not depend on σ at
    all. So σ̂ = σ ρ with a random ratio ρ whose law, like τ̂'s, depends on τ only: the model stores,
    at log-spaced τ nodes, the mean and SD of log ρ (per σ reading), of log τ̂, and their correlation,
    and interpolates them in log τ. `log_likelihood` is a bivariate normal in (log σ̂, log τ̂),
    jittable and differentiable in (σ, τ). Build it with `build_reading_model`.
    """

    log_tau_nodes: np.ndarray
    log_ratio_mean: dict
    log_ratio_sd: dict
    log_correlation: dict
    log_tau_hat_mean: np.ndarray
    log_tau_hat_sd: np.ndarray

    def moments(self, tau_um, definition: str = "rq"):
        """(mean log ρ, SD log ρ, mean log τ̂, SD log τ̂, correlation) at true τ, for a σ reading."""
        if definition not in SIGMA_DEFINITIONS:
            raise ValueError(f"definition must be one of {SIGMA_DEFINITIONS}, got {definition!r}")
        x = jnp.log(jnp.asarray(tau_um))
        f = lambda v: jnp.interp(x, jnp.asarray(self.log_tau_nodes), jnp.asarray(v))  # noqa: E731
        return (f(self.log_ratio_mean[definition]), f(self.log_ratio_sd[definition]), f(self.log_tau_hat_mean),
                f(self.log_tau_hat_sd), f(self.log_correlation[definition]))

    def log_likelihood(self, sigma_um, tau_um, sigma_hat_um, tau_hat_um, definition: str = "rq"):
        """log p(σ̂, τ̂ | σ, τ): the density of a published campaign reading given the true surface.

        Arguments:
            sigma_um, tau_um: the true surface (broadcast together; τ inside the node range).
            sigma_hat_um, tau_hat_um: the reading.
            definition: the σ reading (`SIGMA_DEFINITIONS`).
        """
        m_r, s_r, m_t, s_t, r = self.moments(tau_um, definition)
        density = normal2_log_density(jnp.log(sigma_hat_um) - jnp.log(sigma_um) - m_r, jnp.log(tau_hat_um) - m_t, s_r, s_t,
                                      jnp.clip(r, -0.99, 0.99))
        return density - jnp.log(sigma_hat_um * tau_hat_um)  # the Jacobian of (log σ̂, log τ̂)


#: Bumped when the reading model's construction changes (part of its cache key).
READING_MODEL_VERSION = 1


def build_reading_model(profilometer: Profilometer | None = None, *, tau_nodes_um=None, campaigns: int = 64, seed: int = 0,
                        cache_dir=None, use_cache: bool = True, progress: bool = False) -> ReadingModel:
    """Simulate the campaign reading at log-spaced true τ (σ = 50 nm, which only scales) and cache it.

    Arguments:
        profilometer: the instrument and procedure (default `Profilometer()`).
        tau_nodes_um: true τ nodes (default 16 log-spaced in 0.2–2.5 µm).
        campaigns: simulated campaigns per node.
        seed: the random stream.
        cache_dir: on-disk cache folder (None: `$PAINTJAX_CACHE`); `use_cache` False builds afresh.
        progress: print a line per node to stderr.
    """
    import sys

    from .._cache import cached_arrays

    prof = Profilometer() if profilometer is None else profilometer
    nodes = np.geomspace(0.2, 2.5, 16) if tau_nodes_um is None else np.asarray(tau_nodes_um, float)
    if nodes.ndim != 1 or nodes.size < 2 or np.any(np.diff(nodes) <= 0):
        raise ValueError(f"tau_nodes_um must be at least 2 increasing values, got {tau_nodes_um!r}")
    ref = 0.05

    def build():
        out = {"log_tau_hat_mean": [], "log_tau_hat_sd": []}
        for d in SIGMA_DEFINITIONS:
            out |= {f"mean_{d}": [], f"sd_{d}": [], f"corr_{d}": []}
        for j, t in enumerate(nodes):
            dist = prof.campaign_distribution(jax.random.fold_in(jax.random.PRNGKey(seed), j), ref, float(t), campaigns)
            out["log_tau_hat_mean"].append(dist["log_tau_mean"])
            out["log_tau_hat_sd"].append(dist["log_tau_sd"])
            for d, v in dist["by_definition"].items():
                out[f"mean_{d}"].append(v["log_sigma_mean"] - np.log(ref))
                out[f"sd_{d}"].append(v["log_sigma_sd"])
                out[f"corr_{d}"].append(v["log_correlation"])
            if progress:
                print(f"  reading model: τ = {t:.3f} µm → τ̂ {np.exp(dist['log_tau_mean']):.3f} µm", file=sys.stderr, flush=True)
        return {k: np.asarray(v) for k, v in out.items()}

    inputs = {"version": READING_MODEL_VERSION, "profilometer": [prof.resolution_um, prof.pixel_um, int(prof.num_platelets),
              list(prof.scan_range_um), prof.cutoff_fraction], "tau_nodes_um": nodes.tolist(), "campaigns": int(campaigns), "seed": int(seed)}
    a, _ = cached_arrays("roughness-reading-model", inputs, build, folder=cache_dir, use_cache=use_cache)
    return ReadingModel(np.log(nodes), {d: a[f"mean_{d}"] for d in SIGMA_DEFINITIONS}, {d: a[f"sd_{d}"] for d in SIGMA_DEFINITIONS},
                        {d: a[f"corr_{d}"] for d in SIGMA_DEFINITIONS}, a["log_tau_hat_mean"], a["log_tau_hat_sd"])
