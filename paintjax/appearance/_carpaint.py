"""The car-paint BRDF used by renderers and appearance-exchange files: a diffuse term and up to
three Cook–Torrance (Beckmann) lobes with Schlick Fresnel, under a flat dielectric clearcoat.

Directions are unit vectors in the paint frame (z = paint normal), pointing *away* from the surface,
in air. Under the coat (index n) the directions are refracted (`refract_into_coat`), and

    f(ω_i, ω_o) = T(θ_i) T(θ_o) / n² · f_base(ω_i', ω_o')                         [1/sr]
    f_base      = a/π + Σ_k s_k D_k(h) F_k(ω_i'·h) G(ω_i', ω_o', h) / (4 cos θ_i' cos θ_o')
    D_k(h)      = exp(−tan²θ_h / α_k²) / (π α_k² cos⁴θ_h)          (Beckmann, RMS slope α_k)
    F_k(c)      = F0_k + (1 − F0_k)(1 − c)⁵                          (Schlick)
    G           = min(1, 2 cosθ_h cosθ_o' / (ω_o'·h), 2 cosθ_h cosθ_i' / (ω_o'·h))   (Cook–Torrance)

with h the half vector of the refracted directions, T = 1 − R the clearcoat's Fresnel
transmittance (unpolarised) and 1/n² the radiance change across the interface (domain brief §3,
single scatter through a smooth coat). The clearcoat's own mirror reflection R(θ_i) is a delta
term (`coat_reflectance`); `evaluate` leaves it out, as a multi-angle instrument does.

The model is the form of the automotive car-paint BRDFs (Rump et al. 2008; the AxF "CPA2"
model) without their flake texture: paintjax paints are achromatic, so their BRDF colour table
χ(θ_h, θ_d) is a table of lightness multipliers (optional, `color_table`): f_base is multiplied by χ,
interpolated bilinearly between nodes uniform in θ_h (half vector from the normal) and θ_d (between
ω_i' and h), both on [0, θ_c] with θ_c = asin(1/n) the largest angle inside the coat. The lobes (and
the table) are fitted to the tracer's reflectance over the hemisphere (`fit_car_paint`).
"""

from __future__ import annotations

import json
import os

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ..instrument._geometry import refract_into_coat
from ..optics._fresnel import fresnel_dielectric

#: Most lobes the model carries (the AxF car-paint model's limit).
MAX_LOBES = 3
#: Beckmann roughness (RMS slope) range accepted.
ROUGHNESS_RANGE = (1e-3, 1.5)
#: JSON format tag of an exported model.
JSON_FORMAT = "paintjax-car-paint-brdf"
JSON_VERSION = 2  # 2: the optional colour table (version 1 files, without it, still load)
#: Most nodes per axis of the colour table.
MAX_TABLE_NODES = 16


def _beckmann(cos_h, alpha):
    c2 = jnp.clip(cos_h, 1e-6, 1.0) ** 2
    tan2 = (1.0 - c2) / c2
    return jnp.exp(-tan2 / alpha**2) / (jnp.pi * alpha**2 * c2**2)


class CarPaintBRDF(eqx.Module):
    """Diffuse + Cook–Torrance lobes under a flat clearcoat (module docstring has the formulas).

    Arguments:
        diffuse: albedo a ≥ 0 of the Lambertian term under the coat.
        lobe_weight: s_k ≥ 0, one per lobe (1 to 3 lobes).
        lobe_roughness: Beckmann α_k in `ROUGHNESS_RANGE`.
        lobe_f0: Schlick F0_k in [0, 1].
        coat_index: clearcoat index n in (1, 3].
        color_table: χ at (nh, nd) nodes (2 to `MAX_TABLE_NODES` each), finite and > 0; None: χ = 1.
    """

    diffuse: Float[Array, ""]
    lobe_weight: Float[Array, " k"]
    lobe_roughness: Float[Array, " k"]
    lobe_f0: Float[Array, " k"]
    coat_index: float = eqx.field(static=True, default=1.5)
    color_table: Float[Array, "nh nd"] | None = None

    def __check_init__(self):
        try:
            values = [np.asarray(v, dtype=float) for v in (self.diffuse, self.lobe_weight, self.lobe_roughness, self.lobe_f0)]
        except Exception:  # traced inside a fit: checked where concrete
            return
        a, s, alpha, f0 = values
        k = s.shape
        if not (len(k) == 1 and 1 <= k[0] <= MAX_LOBES) or alpha.shape != k or f0.shape != k:
            raise ValueError(f"lobe_weight, lobe_roughness and lobe_f0 must be 1-D with the same 1 to {MAX_LOBES} lobes, "
                             f"got shapes {s.shape}, {alpha.shape}, {f0.shape}")
        if a.shape != () or not (np.isfinite(a) and a >= 0):
            raise ValueError(f"diffuse must be a finite albedo >= 0, got {self.diffuse!r}")
        if np.any(~np.isfinite(s)) or np.any(s < 0):
            raise ValueError(f"lobe_weight must be finite and >= 0, got {s.tolist()}")
        lo, hi = ROUGHNESS_RANGE
        if np.any(~np.isfinite(alpha)) or np.any((alpha < lo) | (alpha > hi)):
            raise ValueError(f"lobe_roughness must lie in [{lo:g}, {hi:g}], got {alpha.tolist()}")
        if np.any(~np.isfinite(f0)) or np.any((f0 < 0) | (f0 > 1)):
            raise ValueError(f"lobe_f0 must lie in [0, 1], got {f0.tolist()}")
        if not (1.0 < float(self.coat_index) <= 3.0):
            raise ValueError(f"coat_index must lie in (1, 3], got {self.coat_index!r}")
        if self.color_table is not None:
            chi = np.asarray(self.color_table, dtype=float)
            if chi.ndim != 2 or not all(2 <= d <= MAX_TABLE_NODES for d in chi.shape):
                raise ValueError(f"color_table must be 2-D with 2 to {MAX_TABLE_NODES} nodes per axis, got shape {chi.shape}")
            if np.any(~np.isfinite(chi)) or np.any(chi <= 0):
                raise ValueError("color_table must hold finite values > 0")

    @property
    def num_lobes(self) -> int:
        return int(np.shape(self.lobe_weight)[0])

    @property
    def table_max_deg(self) -> float:
        """θ_c = asin(1/n): the colour table's nodes span [0, θ_c] on both axes."""
        return float(np.degrees(np.arcsin(1.0 / float(self.coat_index))))

    def color(self, wi_coat: Float[Array, "... 3"], wo_coat: Float[Array, "... 3"]) -> Float[Array, "..."]:
        """χ(θ_h, θ_d) of refracted directions, bilinear between the table's nodes (1 without a table); the
        angles by atan2 of sine and cosine (accurate near 0 in float32 too)."""
        if self.color_table is None:
            return jnp.ones(wi_coat.shape[:-1])
        nh, nd = self.color_table.shape
        scale = 1.0 / np.radians(self.table_max_deg)
        h = wi_coat + wo_coat
        theta_h = jnp.arctan2(jnp.linalg.norm(h[..., :2], axis=-1), h[..., 2])
        theta_d = jnp.arctan2(jnp.linalg.norm(jnp.cross(wi_coat, h), axis=-1), jnp.sum(wi_coat * h, axis=-1))
        u = jnp.clip(theta_h * scale * (nh - 1), 0.0, nh - 1)
        v = jnp.clip(theta_d * scale * (nd - 1), 0.0, nd - 1)
        wu = jnp.maximum(0.0, 1.0 - jnp.abs(u[..., None] - jnp.arange(nh)))
        wv = jnp.maximum(0.0, 1.0 - jnp.abs(v[..., None] - jnp.arange(nd)))
        return jnp.einsum("...i,ij,...j->...", wu, self.color_table, wv)

    def base(self, wi_coat: Float[Array, "... 3"], wo_coat: Float[Array, "... 3"]) -> Float[Array, "..."]:
        """f_base under the coat [1/sr] for refracted directions (both away from the surface)."""
        ci, co = wi_coat[..., 2], wo_coat[..., 2]
        h = wi_coat + wo_coat
        h = h / jnp.linalg.norm(h, axis=-1, keepdims=True)
        ch = h[..., 2]
        ih = jnp.clip(jnp.sum(wi_coat * h, axis=-1), 1e-9, 1.0)  # = ω_o'·h for a reflection half vector
        G = jnp.minimum(1.0, jnp.minimum(2.0 * ch * co / ih, 2.0 * ch * ci / ih))
        D = _beckmann(ch[..., None], self.lobe_roughness)
        F = self.lobe_f0 + (1.0 - self.lobe_f0) * (1.0 - ih[..., None]) ** 5
        spec = jnp.sum(self.lobe_weight * D * F, axis=-1) * G / (4.0 * ci * co)
        return self.color(wi_coat, wo_coat) * (self.diffuse / jnp.pi + spec)

    def evaluate(self, wi: Float[ArrayLike, "... 3"], wo: Float[ArrayLike, "... 3"]) -> Float[Array, "..."]:
        """BRDF in air [1/sr] without the clearcoat's delta reflection; 0 below the horizon."""
        wi, wo = jnp.asarray(wi), jnp.asarray(wo)
        n = self.coat_index
        up = (wi[..., 2] > 0) & (wo[..., 2] > 0)
        wi_s = jnp.where(up[..., None], wi, jnp.array([0.0, 0.0, 1.0]))
        wo_s = jnp.where(up[..., None], wo, jnp.array([0.0, 0.0, 1.0]))
        Ti = 1.0 - fresnel_dielectric(wi_s[..., 2], 1.0, n)[2]
        To = 1.0 - fresnel_dielectric(wo_s[..., 2], 1.0, n)[2]
        f = Ti * To / n**2 * self.base(refract_into_coat(wi_s, n), refract_into_coat(wo_s, n))
        return jnp.where(up, f, 0.0)

    def reflectance_factor(self, wi, wo) -> Float[Array, "..."]:
        """π f: the reflectance factor a multi-angle instrument reads (no coat reflection)."""
        return jnp.pi * self.evaluate(wi, wo)

    def coat_reflectance(self, cos_theta: ArrayLike) -> Float[Array, "..."]:
        """The clearcoat's mirror reflectance R(θ) (the delta term)."""
        return fresnel_dielectric(cos_theta, 1.0, self.coat_index)[2]

    # ---- exchange ------------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """The documented JSON content (docs/appearance.md)."""
        return {
            "format": JSON_FORMAT,
            "version": JSON_VERSION,
            "model": "diffuse + Cook-Torrance (Beckmann, Schlick) lobes under a flat dielectric clearcoat",
            "units": {"brdf": "1/sr", "angles": "radians inside formulas; roughness is the Beckmann RMS slope"},
            "coat_index": float(self.coat_index),
            "diffuse": float(self.diffuse),
            "lobes": [{"weight": float(s), "roughness": float(a), "f0": float(f)}
                      for s, a, f in zip(np.asarray(self.lobe_weight), np.asarray(self.lobe_roughness), np.asarray(self.lobe_f0))],
            "color_table": None if self.color_table is None else {
                "theta_h_deg": np.linspace(0.0, self.table_max_deg, self.color_table.shape[0]).tolist(),
                "theta_d_deg": np.linspace(0.0, self.table_max_deg, self.color_table.shape[1]).tolist(),
                "values": np.asarray(self.color_table, dtype=float).tolist()},
        }

    @classmethod
    def from_dict(cls, d: dict) -> CarPaintBRDF:
        """Inverse of `to_dict` (validated: a clear ValueError names what is wrong)."""
        if not isinstance(d, dict) or d.get("format") != JSON_FORMAT:
            raise ValueError(f"not a paintjax car-paint BRDF file (format must be {JSON_FORMAT!r})")
        if d.get("version") not in (1, JSON_VERSION):
            raise ValueError(f"car-paint BRDF file version {d.get('version')!r} is not supported (expected 1 or {JSON_VERSION})")
        table = d.get("color_table")
        if table is not None and not (isinstance(table, dict) and "values" in table):
            raise ValueError("color_table must be null or an object with values (nh × nd χ at nodes uniform on [0, asin(1/n)])")
        lobes = d.get("lobes")
        if not isinstance(lobes, list) or not lobes:
            raise ValueError("lobes must be a non-empty list of {weight, roughness, f0}")
        try:
            values = dict(diffuse=jnp.asarray(float(d["diffuse"])),
                          lobe_weight=jnp.asarray([float(lb["weight"]) for lb in lobes]),
                          lobe_roughness=jnp.asarray([float(lb["roughness"]) for lb in lobes]),
                          lobe_f0=jnp.asarray([float(lb["f0"]) for lb in lobes]),
                          coat_index=float(d["coat_index"]),
                          color_table=None if table is None else jnp.asarray(np.asarray(table["values"], dtype=float)))
        except (KeyError, TypeError, ValueError) as err:
            raise ValueError(f"car-paint BRDF file is missing or mistypes {err}") from None
        return cls(**values)  # checks the values (a ValueError names the parameter)


def load_car_paint(path: str | os.PathLike) -> tuple[CarPaintBRDF, dict]:
    """Read an exported car-paint JSON file: (model, the whole document with its fit report)."""
    try:
        with open(path) as fh:
            doc = json.load(fh)
    except FileNotFoundError:
        raise ValueError(f"car-paint BRDF file not found: {path}") from None
    except json.JSONDecodeError as err:
        raise ValueError(f"car-paint BRDF file {path} is not JSON: {err}") from None
    return CarPaintBRDF.from_dict(doc), doc
