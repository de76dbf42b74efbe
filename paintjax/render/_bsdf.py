"""The car-paint BRDF (`appearance.CarPaintBRDF`) as a Mitsuba 3 BSDF plugin written with Dr.Jit.

The plugin "paintjax_carpaint" evaluates exactly the formula of `CarPaintBRDF.evaluate` (diffuse +
Cook–Torrance Beckmann lobes at the directions refracted into a flat clearcoat, × T(θi) T(θo) / n²)
and adds the clearcoat's mirror reflection R(θi) as a delta component. Properties: `diffuse`,
`coat_index` and, per lobe k = 0, 1, 2 (contiguous from 0), `weight_k`, `roughness_k`, `f0_k`; an
optional colour table χ as `table_nh`, `table_nd` and `chi_i_j` (the model's `color_table`).

Components: 0 the coat's delta reflection (`DeltaReflection`), 1 the lobes (`GlossyReflection`),
2 the diffuse term (`DiffuseReflection`); all front-side only (wrap in `twosided` for two faces).

Sampling is a mixture: the delta reflection with probability R(θi); otherwise one of the diffuse term
(cosine-weighted) and the lobes (Beckmann half vector h, p(h) = D cosθh) inside the coat, picked with
probabilities ∝ the components' sizes with a floor, mapped to air by refraction with the Jacobian
p_air = p_coat cosθo / (n² cosθo'). A direction that cannot leave the coat (total internal
reflection) has weight 0, so the non-delta pdf integrates to at most 1 − R(θi).
"""

from __future__ import annotations

import importlib
import importlib.util
import math

PLUGIN_NAME = "paintjax_carpaint"
#: Fewest of the non-delta sampling probability a present component gets (mixture floor).
MIXTURE_FLOOR = 0.1
#: Oldest LLVM that Dr.Jit's LLVM backend works with here (16 aborts on `llvm.minimum`; 19 verified).
MIN_LLVM = 17
_INSTALL = "the paintjax renderer needs Mitsuba 3: pip install paintjax[render]"
_CLASSES: dict = {}


def require_mitsuba(variant: str | None = None):
    """Import Mitsuba, set `variant` and register the "paintjax_carpaint" plugin for it (once).

    Arguments:
        variant: a Mitsuba variant, RGB, mono or spectral, not polarised (e.g. "llvm_ad_rgb", "scalar_rgb");
            None: `default_variant()`.

    Returns:
        The `mitsuba` module with `variant` set.

    Raises:
        ImportError: Mitsuba is not installed (the message says `pip install paintjax[render]`).
        ValueError: `variant` is not one of the variants this Mitsuba build offers, or cannot load here.
    """
    if variant is None:
        variant = default_variant()
    try:
        mi = importlib.import_module("mitsuba")
    except ImportError as err:
        raise ImportError(f"{_INSTALL} ({err})") from None
    available = [v for v in mi.variants() if "polarized" not in v]
    if not isinstance(variant, str) or variant not in available:
        raise ValueError(f"variant must be one of the Mitsuba variants available here, {', '.join(available)}; got {variant!r}")
    try:
        mi.set_variant(variant)
    except Exception as err:  # e.g. a cuda variant without a GPU
        raise ValueError(f"variant {variant!r} cannot be loaded on this machine: {err}") from None
    if variant.startswith("llvm"):
        _check_llvm(variant)
    if variant not in _CLASSES:
        cls = _make_class(getattr(mi, variant), mi)
        mi.register_bsdf(PLUGIN_NAME, lambda props: cls(props))
        _CLASSES[variant] = cls
    return mi


def default_variant() -> str:
    """The variant to render with: `$PAINTJAX_MITSUBA_VARIANT` if set; else "llvm_ad_rgb" where Dr.Jit
    finds LLVM 17 or newer (fast, vectorised); else "scalar_rgb" (works everywhere, one Python call per
    path: slow for full-size images)."""
    import os

    chosen = os.environ.get("PAINTJAX_MITSUBA_VARIANT")
    if chosen:
        return chosen
    try:
        import drjit as dr

        version = tuple(int(v) for v in dr.detail.llvm_version())
    except Exception:  # no Dr.Jit (require_mitsuba names the extra) or no LLVM
        return "scalar_rgb" if importlib.util.find_spec("drjit") else "llvm_ad_rgb"
    return "llvm_ad_rgb" if version[0] >= MIN_LLVM else "scalar_rgb"


def _check_llvm(variant: str) -> None:
    """Dr.Jit 1.x emits `llvm.minimum`, which LLVM 16 and older cannot compile on x86 (the process aborts)."""
    import drjit as dr

    query = getattr(dr.detail, "llvm_version", None)
    if query is None:  # another Dr.Jit: nothing to tell
        return
    try:
        version = tuple(int(v) for v in query())
    except Exception:  # no LLVM library found
        version = (0, 0, 0)
    if version[0] < MIN_LLVM:
        raise ValueError(f"variant {variant!r} needs Dr.Jit's LLVM backend with LLVM {MIN_LLVM} or newer, found "
                         f"{'.'.join(map(str, version)) if version[0] else 'none'}: install one (Debian: apt-get install libllvm19) "
                         f"or point DRJIT_LIBLLVM_PATH at it, or use variant 'scalar_rgb' (slow)")


def bsdf_dict(model) -> dict:
    """The Mitsuba dict of a `CarPaintBRDF` (or of its `to_dict()` JSON content).

    Arguments:
        model: a `CarPaintBRDF`, or a dict in the exchange format of `CarPaintBRDF.to_dict`.

    Returns:
        {"type": "paintjax_carpaint", "diffuse": …, "coat_index": …, "weight_0": …, "roughness_0": …, "f0_0": …, …}
        with Python floats (usable after `require_mitsuba`).
    """
    d = as_model(model).to_dict()
    out = {"type": PLUGIN_NAME, "diffuse": float(d["diffuse"]), "coat_index": float(d["coat_index"])}
    for k, lobe in enumerate(d["lobes"]):
        out |= {f"weight_{k}": float(lobe["weight"]), f"roughness_{k}": float(lobe["roughness"]), f"f0_{k}": float(lobe["f0"])}
    if d.get("color_table") is not None:
        chi = d["color_table"]["values"]
        out |= {"table_nh": len(chi), "table_nd": len(chi[0])}
        out |= {f"chi_{i}_{j}": float(x) for i, row in enumerate(chi) for j, x in enumerate(row)}
    return out


def as_model(model):
    """A `CarPaintBRDF` from itself or from its JSON dict; ValueError naming `model` otherwise."""
    from ..appearance._carpaint import CarPaintBRDF

    if isinstance(model, CarPaintBRDF):
        return model
    if isinstance(model, dict):
        return CarPaintBRDF.from_dict(model)
    raise ValueError(f"model must be a CarPaintBRDF or its to_dict() content, got {type(model).__name__}")


def mixture_weights(diffuse: float, weights, f0s) -> list[float]:
    """Sampling probabilities of [diffuse, lobe 0, …] among the non-delta components.

    Sizes: the diffuse albedo a and s_k (F0_k + 0.1 (1 − F0_k)) for lobe k; each present (size > 0)
    component gets at least `MIXTURE_FLOOR` before normalisation; absent ones get 0.
    """
    sizes = [max(float(diffuse), 0.0)] + [max(float(s), 0.0) * (float(f) + 0.1 * (1.0 - float(f))) for s, f in zip(weights, f0s)]
    total = sum(sizes)
    if total <= 0.0:
        return [1.0] + [0.0] * len(weights)
    q = [max(s / total, MIXTURE_FLOOR) if s > 0 else 0.0 for s in sizes]
    return [v / sum(q) for v in q]


# ---- the formula in Dr.Jit (generic over the variant's types) --------------------------------------------
def _fresnel_air(dr, cos_i, n):
    """Unpolarised Fresnel reflectance from air into index n (no total internal reflection on this side)."""
    cos_t = dr.safe_sqrt(1.0 - (1.0 - cos_i * cos_i) / (n * n))
    rs = (cos_i - n * cos_t) / (cos_i + n * cos_t)
    rp = (n * cos_i - cos_t) / (n * cos_i + cos_t)
    return 0.5 * (rs * rs + rp * rp)


def _into_coat(dr, m, w, n):
    x, y = w.x / n, w.y / n
    return m.Vector3f(x, y, dr.safe_sqrt(1.0 - x * x - y * y))


def _base_terms(dr, m, wi_c, wo_c, lobes):
    """Per lobe (D_k, F_k) and the shared G, cosθh, ω'·h of the refracted pair (formulas of `CarPaintBRDF.base`)."""
    hx, hy, hz = wi_c.x + wo_c.x, wi_c.y + wo_c.y, wi_c.z + wo_c.z
    inv = dr.rsqrt(hx * hx + hy * hy + hz * hz)
    ch = dr.clip(hz * inv, 1e-6, 1.0)
    ih = dr.clip((wi_c.x * hx + wi_c.y * hy + wi_c.z * hz) * inv, 1e-9, 1.0)
    tan2 = (hx * hx + hy * hy) / dr.maximum(hz * hz, 1e-12)  # tan²θh from the components: exact where cosθh → 1
    c2 = ch * ch
    g = dr.minimum(1.0, dr.minimum(2.0 * ch * wo_c.z / ih, 2.0 * ch * wi_c.z / ih))
    schlick = (1.0 - ih) ** 5
    terms = []
    for _, alpha, f0 in lobes:
        a2 = alpha * alpha
        terms.append((dr.exp(-tan2 / a2) / (math.pi * a2 * c2 * c2), f0 + (1.0 - f0) * schlick))
    return terms, g, ch, ih


def _make_class(m, mi):
    """The BSDF class for one variant module `m` (mitsuba.<variant>); `mi` the mitsuba package (flags)."""
    import drjit as dr

    Flags = mi.BSDFFlags
    delta_flags = Flags.DeltaReflection | Flags.FrontSide
    glossy_flags = Flags.GlossyReflection | Flags.FrontSide
    diffuse_flags = Flags.DiffuseReflection | Flags.FrontSide
    jit = dr.is_jit_v(m.Float)

    def param(x):
        return dr.opaque(m.Float, x) if jit else m.Float(x)

    class PaintjaxCarPaintBSDF(m.BSDF):
        def __init__(self, props):
            m.BSDF.__init__(self, props)
            k = 0
            values = {"diffuse": float(props.get("diffuse", 0.0)), "coat_index": float(props.get("coat_index", 1.5))}
            while f"weight_{k}" in props:
                for name in ("weight", "roughness", "f0"):
                    values[f"{name}_{k}"] = float(props.get(f"{name}_{k}", {"roughness": 0.1}.get(name, 0.0)))
                k += 1
            if not 1 <= k <= 3:
                raise ValueError(f"{PLUGIN_NAME}: give 1 to 3 lobes as weight_0, roughness_0, f0_0, …, got {k}")
            self.table = (int(props.get("table_nh", 0)), int(props.get("table_nd", 0)))  # (0, 0): no colour table
            for i in range(self.table[0]):
                for j in range(self.table[1]):
                    values[f"chi_{i}_{j}"] = float(props.get(f"chi_{i}_{j}", 1.0))
            self.num_lobes = k
            self.values = values
            self._check()
            self.params = {key: param(v) for key, v in values.items()}
            self._update()
            self.m_components = [delta_flags, glossy_flags, diffuse_flags]
            self.m_flags = delta_flags | glossy_flags | diffuse_flags

        def _check(self):
            v = self.values
            if not (1.0 < v["coat_index"] <= 3.0) or not (v["diffuse"] >= 0.0):
                raise ValueError(f"{PLUGIN_NAME}: coat_index must lie in (1, 3] and diffuse be >= 0, got {v}")
            if self.table != (0, 0) and (min(self.table) < 2 or any(not (v[key] > 0.0) for key in v if key.startswith("chi_"))):
                raise ValueError(f"{PLUGIN_NAME}: a colour table needs table_nh, table_nd >= 2 and every chi_i_j > 0")
            for k in range(self.num_lobes):
                if not (v[f"weight_{k}"] >= 0.0 and 1e-3 <= v[f"roughness_{k}"] <= 1.5 and 0.0 <= v[f"f0_{k}"] <= 1.0):
                    raise ValueError(f"{PLUGIN_NAME}: lobe {k} needs weight >= 0, roughness in [0.001, 1.5], f0 in [0, 1], got {v}")

        def _update(self):
            v, nl = self.values, self.num_lobes
            q = mixture_weights(v["diffuse"], [v[f"weight_{k}"] for k in range(nl)], [v[f"f0_{k}"] for k in range(nl)])
            self.q = [param(x) for x in q]
            self.q_py = q

        # ---- pieces --------------------------------------------------------------------------------
        def _color(self, wi_c, wo_c):
            """χ(θh, θd): bilinear (hat functions) between nodes uniform on [0, asin(1/n)] (as `CarPaintBRDF.color`);
            the angles by atan2 of sine and cosine, which float32 keeps accurate near 0 (acos does not)."""
            (nh, nd), p = self.table, self.params
            scale = 1.0 / math.asin(1.0 / self.values["coat_index"])
            h = wi_c + wo_c
            theta_h = dr.atan2(dr.sqrt(h.x * h.x + h.y * h.y), h.z)
            theta_d = dr.atan2(dr.norm(dr.cross(wi_c, h)), dr.dot(wi_c, h))
            u = dr.clip(theta_h * (scale * (nh - 1)), 0.0, nh - 1.0)
            v = dr.clip(theta_d * (scale * (nd - 1)), 0.0, nd - 1.0)
            wu = [dr.maximum(0.0, 1.0 - dr.abs(u - i)) for i in range(nh)]
            wv = [dr.maximum(0.0, 1.0 - dr.abs(v - j)) for j in range(nd)]
            chi = m.Float(0.0)
            for i in range(nh):
                row = m.Float(0.0)
                for j in range(nd):
                    row = row + p[f"chi_{i}_{j}"] * wv[j]
                chi = chi + wu[i] * row
            return chi

        def _lobes(self):
            p = self.params
            return [(p[f"weight_{k}"], p[f"roughness_{k}"], p[f"f0_{k}"]) for k in range(self.num_lobes)]

        def _enabled(self, ctx):
            return (ctx.is_enabled(Flags.DeltaReflection, 0), ctx.is_enabled(Flags.GlossyReflection, 1),
                    ctx.is_enabled(Flags.DiffuseReflection, 2))

        def _delta_probability(self, ctx, r_i):
            has_delta, has_glossy, has_diffuse = self._enabled(ctx)
            if not has_delta:
                return m.Float(0.0) * r_i
            return r_i if (has_glossy or has_diffuse) else m.Float(1.0) + 0.0 * r_i

        def _non_delta_q(self, ctx):
            """Probabilities [diffuse, lobes…] among the enabled non-delta components, and which are sampled."""
            _, has_glossy, has_diffuse = self._enabled(ctx)
            on = [has_diffuse and self.q_py[0] > 0] + [has_glossy and x > 0 for x in self.q_py[1:]]
            total = sum(x for x, o in zip(self.q_py, on) if o)
            if total <= 0:
                return [0.0] * len(on), on
            if all(on) or total == 1.0:
                return [q if o else 0.0 for q, o in zip(self.q, on)], on
            return [q / total if o else 0.0 for q, o in zip(self.q, on)], on

        def _eval_pdf(self, ctx, si, wo, active):
            """(f cosθo, non-delta pdf) for directions wo (local frame)."""
            _, has_glossy, has_diffuse = self._enabled(ctx)
            p = self.params
            n = p["coat_index"]
            ci, co = m.Frame3f.cos_theta(si.wi), m.Frame3f.cos_theta(wo)
            active = active & (ci > 0.0) & (co > 0.0)
            wi_c, wo_c = _into_coat(dr, m, si.wi, n), _into_coat(dr, m, wo, n)
            lobes = self._lobes()
            terms, g, ch, ih = _base_terms(dr, m, wi_c, wo_c, lobes)
            r_i, r_o = _fresnel_air(dr, ci, n), _fresnel_air(dr, co, n)
            f_base = m.Float(0.0)
            if has_glossy:
                spec = m.Float(0.0)
                for (s, _, _), (d, f) in zip(lobes, terms):
                    spec = spec + s * d * f
                f_base = spec * g / (4.0 * dr.maximum(wi_c.z * wo_c.z, 1e-12))  # guarded: a scalar variant divides in Python
            if has_diffuse:
                f_base = f_base + p["diffuse"] / math.pi
            if self.table != (0, 0):
                f_base = f_base * self._color(wi_c, wo_c)
            value = (1.0 - r_i) * (1.0 - r_o) / (n * n) * f_base * co
            q, on = self._non_delta_q(ctx)
            p_coat = m.Float(0.0)
            if on[0]:
                p_coat = q[0] * wo_c.z / math.pi
            for k, (d, _) in enumerate(terms):
                if on[k + 1]:
                    p_coat = p_coat + q[k + 1] * d * ch / (4.0 * ih)
            pdf = (1.0 - self._delta_probability(ctx, r_i)) * p_coat * co / (n * n * dr.maximum(wo_c.z, 1e-12))
            return dr.select(active, value, 0.0), dr.select(active, pdf, 0.0)

        # ---- the Mitsuba interface ------------------------------------------------------------------
        def eval(self, ctx, si, wo, active=True):
            value, _ = self._eval_pdf(ctx, si, wo, active)
            return m.Spectrum(value)

        def pdf(self, ctx, si, wo, active=True):
            return self._eval_pdf(ctx, si, wo, active)[1]

        def eval_pdf(self, ctx, si, wo, active=True):
            value, pdf = self._eval_pdf(ctx, si, wo, active)
            return m.Spectrum(value), pdf

        def sample(self, ctx, si, sample1, sample2, active=True):
            has_delta, has_glossy, has_diffuse = self._enabled(ctx)
            n = self.params["coat_index"]
            ci = m.Frame3f.cos_theta(si.wi)
            active = active & (ci > 0.0) & (has_delta or has_glossy or has_diffuse)
            r_i = _fresnel_air(dr, ci, n)
            p_delta = self._delta_probability(ctx, r_i)
            pick_delta = sample1 < p_delta
            u = dr.clip((sample1 - p_delta) / dr.maximum(1.0 - p_delta, 1e-12), 0.0, 0.99999994)

            # A direction inside the coat from each sampled non-delta component; u picks one.
            wi_c = _into_coat(dr, m, si.wi, n)
            q, on = self._non_delta_q(ctx)
            wo_c = m.warp.square_to_cosine_hemisphere(sample2)
            is_diffuse = u < 2.0  # True, as a mask of the right type
            edge = q[0]
            for k, (_, alpha, _) in enumerate(self._lobes()):
                if not on[k + 1]:
                    continue
                tan2 = -alpha * alpha * dr.log(1.0 - sample2.x)
                cos_h = dr.rsqrt(1.0 + tan2)
                sin_h = dr.safe_sqrt(1.0 - cos_h * cos_h)
                s_phi, c_phi = dr.sincos(2.0 * math.pi * sample2.y)
                h = m.Vector3f(sin_h * c_phi, sin_h * s_phi, cos_h)
                pick = u >= edge  # the last component whose share starts below u (edge 0 for the first)
                wo_c = dr.select(pick, 2.0 * dr.dot(wi_c, h) * h - wi_c, wo_c)
                is_diffuse = is_diffuse & (u < edge)
                edge = edge + q[k + 1]

            # Out of the coat (total internal reflection: no sample), or the coat's mirror reflection.
            sin2 = n * n * (wo_c.x * wo_c.x + wo_c.y * wo_c.y)
            escapes = (wo_c.z > 0.0) & (sin2 < 1.0)
            wo = m.Vector3f(wo_c.x * n, wo_c.y * n, dr.safe_sqrt(1.0 - sin2))
            wo = dr.select(pick_delta, m.Vector3f(-si.wi.x, -si.wi.y, si.wi.z), wo)
            value, pdf = self._eval_pdf(ctx, si, wo, active & (sample1 >= p_delta) & escapes)

            bs = dr.zeros(m.BSDFSample3f) if not jit else dr.zeros(m.BSDFSample3f, dr.width(sample1))
            bs.wo = wo
            bs.eta = 1.0
            bs.pdf = dr.select(active, dr.select(pick_delta, p_delta, pdf), 0.0)
            bs.sampled_component = dr.select(pick_delta, m.UInt32(0), dr.select(is_diffuse, m.UInt32(2), m.UInt32(1)))
            bs.sampled_type = dr.select(pick_delta, m.UInt32(+Flags.DeltaReflection),
                                        dr.select(is_diffuse, m.UInt32(+Flags.DiffuseReflection), m.UInt32(+Flags.GlossyReflection)))
            weight = dr.select(pick_delta, r_i / dr.maximum(p_delta, 1e-12), value / dr.select(pdf > 0.0, pdf, 1.0))
            weight = dr.select(active & (pick_delta | (escapes & (pdf > 0.0))), weight, 0.0)
            return bs, m.Spectrum(weight)

        def traverse(self, cb):
            for key, value in self.params.items():
                cb.put(key, value, mi.ParamFlags.Differentiable)

        def parameters_changed(self, keys=None):
            for key, value in self.params.items():
                self.values[key] = float(value[0]) if jit else float(value)
            self._check()
            self._update()

        def to_string(self):
            return f"PaintjaxCarPaintBSDF[{', '.join(f'{k}={v:g}' for k, v in self.values.items())}]"

    return PaintjaxCarPaintBSDF
