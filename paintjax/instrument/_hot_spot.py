"""The hot spot: correlated entry and exit paths through a layer of platelets of finite width.

A ray that reached a platelet at depth z unobstructed has a clear entry path; its exit path toward
ω_o starts at the same point, and near it the two paths are closer than a platelet width, so a
platelet that would block the exit would often have blocked the entry too. For platelets much
narrower than the mean free path the two attenuations are independent (the `paintjax.instrument._single_scatter`
denominator D = A_i μ_o + A_o μ_i); for the paint's 16 µm platelets and a mean free depth of
t/PVC = 5 µm they are not, and single scattering is up to twice as bright.

Boolean model of thin platelets (centres Poisson, widths from the size law, uniform in-plane
rotation). With α = A(ω)/μ the first-hit rate per mean free depth ℓ = t/PVC along ω, the joint
probability that both paths are clear from depth z = uℓ up (Kuusk's canopy hot spot) is

    P(u) = exp{−u(α_i + α_o) + √(α_i α_o) ∫_0^u ρ(v ℓ |d|) dv},   d = ω_i,h/μ_i − ω_o,h/μ_o,

where ρ(s) = E_w[w² ρ_w(s)] / E[w²] is the area-weighted overlap fraction of a platelet with its own
copy shifted by s (a square of width w, rotation averaged:
ρ_w = 1 − 4x/π + x²/π for x = s/w ≤ 1, a closed form up to x = √2, then 0). The depth integral
G = ∫_0^∞ P du replaces μ_i μ_o / D in the single-scatter BRDF. It is exact for horizontal
platelets (α = 1) and Kuusk's approximation for tilted ones (their projection is taken as the
square). Limits: ρ ≡ 0 gives the independent form, d = 0 (the retro direction) full correlation.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..microstructure._sizes import SizeDistribution, as_size_distribution, positive_finite

_SEPARATION_NODES = 2049
_WIDTH_NODES = 512
_DEPTH_NODES = 48


def square_overlap_fraction(x) -> np.ndarray:
    """Rotation-averaged overlap of a unit square with its copy shifted by x (in widths), NumPy.

    E_ψ[(1 − x|cos ψ|)₊ (1 − x|sin ψ|)₊], ψ uniform: 1 − 4x/π + x²/π for x ≤ 1; for 1 < x < √2 the
    closed form over the rotations ψ ∈ [arccos 1/x, arcsin 1/x] where both factors stay positive; 0 beyond.
    """
    x = np.abs(np.asarray(x, dtype=float))
    near = 1.0 - 4.0 * x / np.pi + x**2 / np.pi
    xs = np.clip(x, 1.0, np.sqrt(2.0))
    a, b = np.arccos(1.0 / xs), np.arcsin(1.0 / xs)

    def antiderivative(p):  # ∫ (1 − x cos ψ)(1 − x sin ψ) dψ
        return p - xs * np.sin(p) + xs * np.cos(p) + 0.5 * xs**2 * np.sin(p) ** 2

    far = (2.0 / np.pi) * (antiderivative(b) - antiderivative(a))
    return np.where(x <= 1.0, near, np.where(x < np.sqrt(2.0), far, 0.0))


class HotSpot(eqx.Module):
    """Entry–exit path correlation of a platelet layer (see the module docstring).

    Build with `HotSpot.for_layer`; pass to `single_scatter_brdf` / `microfacet_reflectance_factor`.

    Fields:
        mean_free_depth: ℓ = t / PVC [µm], the mean depth between platelets along the normal.
        separation: uniform grid of lateral separations s [µm] (0 … √2 w_max).
        overlap_integral: ∫_0^s ρ(s') ds' on that grid [µm] (constant beyond it).
        overlap: ρ(s) on that grid, the integral's slope (cubic Hermite interpolation: exact to
            O(Δs⁴), so the mean overlap F(s)/s → ρ(0) = 1 as the paths merge).
    """

    mean_free_depth: float = eqx.field(static=True)
    separation: Float[Array, " k"]
    overlap_integral: Float[Array, " k"]
    overlap: Float[Array, " k"]

    @classmethod
    def for_layer(cls, sizes: SizeDistribution | tuple | None = None, *, thickness: float = 1.0, pvc: float = 0.2) -> "HotSpot":
        """Hot spot of a layer of square platelets of the given width law, thickness [µm] and PVC.

        Arguments:
            sizes: width law (`SizeDistribution`, (d10, d50, d90) or None for the default log-normal).
            thickness: platelet thickness t [µm].
            pvc: pigment volume concentration in (0, 1).
        """
        t = positive_finite("thickness", thickness, "µm")
        pvc = float(pvc)
        if not (0.0 < pvc < 1.0):
            raise ValueError(f"pvc must lie in (0, 1), got {pvc!r}")
        sizes = as_size_distribution(sizes)
        w = np.asarray(sizes.ppf_np((np.arange(_WIDTH_NODES) + 0.5) / _WIDTH_NODES), dtype=float)
        s = np.linspace(0.0, np.sqrt(2.0) * float(np.max(w)), _SEPARATION_NODES)
        rho = np.sum(w[None, :] ** 2 * square_overlap_fraction(s[:, None] / w[None, :]), axis=1) / np.sum(w**2)
        integral = np.concatenate([[0.0], np.cumsum(0.5 * (rho[1:] + rho[:-1]) * np.diff(s))])
        return cls(mean_free_depth=t / pvc, separation=jnp.asarray(s), overlap_integral=jnp.asarray(integral), overlap=jnp.asarray(rho))

    @classmethod
    def for_sample(cls, sample) -> "HotSpot":
        """Hot spot of a reference sample's platelet layer (its D10/D50/D90 log-normal widths, thickness, PVC).

        Arguments:
            sample: a `Sample` (`load_sample`).
        """
        return cls.for_layer((sample.size_d10, sample.size_d50, sample.size_d90), thickness=sample.platelet_thickness, pvc=sample.pvc.value)

    def fingerprint(self) -> str:
        """Short text that changes with the layer (for cache keys)."""
        import hashlib

        digest = hashlib.sha256(np.asarray(self.overlap_integral, dtype=np.float64).tobytes()).hexdigest()[:12]
        return f"HotSpot(ell={self.mean_free_depth:.6g},{digest})"

    def joint_escape(self, wi: Float[Array, "... 3"], wo: Float[Array, "... 3"], alpha_i, alpha_o) -> Float[Array, "..."]:
        """G = ∫_0^∞ P(u) du for entry ω_i and exit ω_o (unit, z > 0) with first-hit rates α = A(ω)/μ.

        Gauss–Laguerre in u scaled by the slowest possible decay α_i + α_o − √(α_i α_o).
        """
        mu_i, mu_o = wi[..., 2], wo[..., 2]
        d = wi[..., :2] / mu_i[..., None] - wo[..., :2] / mu_o[..., None]
        d2 = jnp.sum(d**2, axis=-1)
        alpha_i, alpha_o, d2 = jnp.broadcast_arrays(jnp.asarray(alpha_i), jnp.asarray(alpha_o), d2)
        coincide = self.mean_free_depth**2 * d2 < 1e-18  # the paths part by < 1e-9 µm per unit u (retro)
        length = self.mean_free_depth * jnp.sqrt(jnp.where(coincide, 1.0, d2))[..., None]  # lateral separation per unit u [µm]
        root, total = jnp.sqrt(alpha_i * alpha_o), alpha_i + alpha_o
        rate = total - root
        x, w = np.polynomial.laguerre.laggauss(_DEPTH_NODES)
        u = jnp.asarray(x) / rate[..., None]
        correlated = jnp.where(coincide[..., None], u, self._integral(u * length) / length)
        exponent = -u * total[..., None] + root[..., None] * correlated + jnp.asarray(x)
        return jnp.sum(jnp.asarray(w) * jnp.exp(exponent), axis=-1) / rate

    def _integral(self, x):
        """∫_0^x ρ ds [µm] by cubic Hermite interpolation of the tabulated integral and its slope ρ."""
        s, F, rho = self.separation, self.overlap_integral, self.overlap
        xc = jnp.clip(x, s[0], s[-1])
        h = s[1] - s[0]  # uniform grid: the cell by division, not by search (this is the wavy model's hot loop)
        k = jnp.clip(jnp.floor((xc - s[0]) / h).astype(jnp.int32), 0, s.shape[0] - 2)
        t = (xc - s[k]) / h
        h00, h10, h01, h11 = 2 * t**3 - 3 * t**2 + 1, t**3 - 2 * t**2 + t, -2 * t**3 + 3 * t**2, t**3 - t**2
        return h00 * F[k] + h10 * h * rho[k] + h01 * F[k + 1] + h11 * h * rho[k + 1]


def _segment_meets_square(p0, p1, cx, cy, cos_r, sin_r, half):
    """Whether lateral segments p0 → p1 (…, 2) meet squares (centre, rotation, half-width), NumPy."""

    def local(p):
        dx, dy = p[..., 0] - cx, p[..., 1] - cy
        return cos_r * dx + sin_r * dy, -sin_r * dx + cos_r * dy

    (x0, y0), (x1, y1) = local(p0), local(p1)
    lo, hi = np.zeros_like(x0), np.ones_like(x0)
    for q0, q1 in ((x0, x1), (y0, y1)):
        dq = q1 - q0
        still = np.abs(dq) < 1e-300
        dq = np.where(still, 1.0, dq)
        t1, t2 = (-half - q0) / dq, (half - q0) / dq
        inside = np.abs(q0) <= half
        lo = np.maximum(lo, np.where(still, np.where(inside, -np.inf, np.inf), np.minimum(t1, t2)))
        hi = np.minimum(hi, np.where(still, np.where(inside, np.inf, -np.inf), np.maximum(t1, t2)))
    return lo <= hi


def boolean_escape_monte_carlo(width: float, thickness: float, mean_free_depth: float, wi, wo, *, samples: int = 20_000,
                               seed: int = 0, batch: int = 500) -> tuple[float, float]:
    """Independent Monte Carlo of the single-scatter G of a Boolean layer of horizontal square boxes.

    Reference for `HotSpot.joint_escape`, sharing no code with it or with the tracer: for each
    sample, fresh Poisson boxes (w × w × t, uniform rotation, density 1/(ℓ w²), tops below the
    surface) are drawn in the region the two paths can touch; the entry path along −ω_i from the top meets its first box, and
    G counts the samples whose first box is met on its top face (a black side wall ends the path)
    and whose exit path along ω_o from there to the top meets no box. Samples that reach depth 10ℓ
    unhit count as lost (probability < e⁻¹⁰).

    Arguments:
        width, thickness: square edge w > 0 and box thickness t ≥ 0 [µm] (t = 0: thin platelets).
        mean_free_depth: ℓ = t/PVC of the layer [µm], > 0.
        wi, wo: unit internal directions (3,), z > 0, toward the source and the detector.
        samples, seed, batch: sample count, NumPy seed, samples per vectorised batch.

    Returns:
        (G, its binomial standard error).
    """
    w = positive_finite("width", width, "µm")
    ell = positive_finite("mean_free_depth", mean_free_depth, "µm")
    t = float(thickness)
    if not (np.isfinite(t) and 0.0 <= t < w):
        raise ValueError(f"thickness must lie in [0, width) µm, got {thickness!r}")
    for name, value in (("samples", samples), ("batch", batch)):
        if isinstance(value, bool) or int(value) != value or value < 1:
            raise ValueError(f"{name} must be a positive integer, got {value!r}")
    samples, batch = int(samples), int(batch)
    wi, wo = np.asarray(wi, float), np.asarray(wo, float)
    if wi.shape != (3,) or wo.shape != (3,) or wi[2] <= 0 or wo[2] <= 0:
        raise ValueError("wi and wo must be internal directions (3,) with z > 0")
    rng = np.random.default_rng(int(seed))
    depth = 10.0 * ell
    step_in, step_out = -wi[:2] / wi[2], wo[:2] / wo[2]  # lateral shift per unit depth (entry, down) and height (exit, up)
    corners = np.array([[0.0, 0.0], step_in * depth, (step_in + step_out) * depth, step_out * depth])
    reach = w / np.sqrt(2.0)
    lo, hi = corners.min(0) - reach, corners.max(0) + reach
    mean_count = (hi - lo).prod() * depth / (ell * w * w)
    good = done = 0
    while done < samples:
        b = min(batch, samples - done)
        counts = rng.poisson(mean_count, b)
        m = max(int(counts.max()), 1)
        real = np.arange(m)[None] < counts[:, None]
        cx, cy = rng.uniform(lo[0], hi[0], (b, m)), rng.uniform(lo[1], hi[1], (b, m))
        cz = rng.uniform(t / 2, t / 2 + depth, (b, m))  # boxes wholly below the surface, as in a film
        rot = rng.uniform(0.0, 2.0 * np.pi, (b, m))
        cr, sr = np.cos(rot), np.sin(rot)
        top, bottom = cz - t / 2, cz + t / 2
        entry = lambda d: d[..., None] * step_in  # noqa: E731
        met = real & _segment_meets_square(entry(top), entry(bottom), cx, cy, cr, sr, w / 2)
        first = np.argmin(np.where(met, top, np.inf), axis=1)
        rows = np.arange(b)
        hit = met[rows, first]
        z_hit = np.where(hit, top[rows, first], 0.0)
        x_hit = entry(z_hit)
        pick = lambda a: a[rows, first][:, None]  # noqa: E731
        on_top = hit & _segment_meets_square(x_hit[:, None], x_hit[:, None], pick(cx), pick(cy), pick(cr), pick(sr), w / 2)[:, 0]
        exit_at = lambda d: x_hit[:, None, :] + (z_hit[:, None] - d)[..., None] * step_out  # noqa: E731
        upper, lower = top, np.minimum(bottom, z_hit[:, None])
        above = real & (top < z_hit[:, None]) & (np.arange(m)[None] != first[:, None])
        blocked = np.any(above & _segment_meets_square(exit_at(lower), exit_at(upper), cx, cy, cr, sr, w / 2), axis=1)
        good += int(np.sum(on_top & ~blocked))
        done += b
    g = good / samples
    return g, float(np.sqrt(g * (1.0 - g) / samples))
