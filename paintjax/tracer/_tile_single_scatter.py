"""Single scattering by the mirror platelets of one given tile: a deterministic reference for the tracer.

The analytic single-scatter model (`paintjax.instrument._single_scatter`) is the ensemble of Boolean tiles. For mirror
platelets one tile departs from it by far more than the tracer's standard error: a detector
sees only the platelets whose normals bisect the illumination and its aperture, few of them in
the tail of the tilt law (tile-to-tile SD of R 3 / 6 / 29 % at 15 / 25 / 45° for the tracer tests'
thin-platelet tile). This module computes what the tracer must give on *that* tile.

With the instrument rotated by a uniform azimuth φ (the tracer's `randomize_azimuth`) and a flat
coat, a ray of the collimated beam that meets the top face of platelet j, normal m (facing the
source), at a point x leaves along the mirror direction ω_o = 2(ω_i·m)m − ω_i, and the reflectance
factor averaged over a detector cone of solid angle Ω is

    R = Σ_j (1/2π) ∫ dφ  [ω_o leaves into the cone] π T_i T_o R_Al(ω_i·m) (ω_i·m) w_j² / (μ_i L_x L_y Ω cos θ_air)
        × (1/w_j²) ∫_face V(x, φ) dA  =  Z · V̄,

V = 1 when the beam reaches x from the top of the basecoat (walked downward, as the tracer's
rays go, so a face point inside an overlapping box is shadowed by it) and the exit path from x
up along ω_o meets no box (side walls only block: the tracer's `edges="absorb"`, under which a
ray that first meets a side wall is absorbed). Z (the tile's own tilts, no occlusion) is a
midpoint rule over φ for every platelet; V̄ is the mean visibility of face points drawn from Z's
integrand times a depth proxy (importance sampling), walked with `_tracer._traverse`, which
`tests/test_tracer.py` checks against a brute-force search over all periodic images. So R
carries a Monte Carlo error from V̄ alone, stated as its standard error.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..brdf._platelet import MirrorBRDF
from ..instrument._geometry import Geometry, refract_into_coat
from ..instrument._single_scatter import check_coat_index, check_platelet_medium
from ..optics._fresnel import fresnel_dielectric
from ._scene import _rotz, _traverse, build_scene  # the tracer's rotation and its validated grid walk


def _mirror_paths(m, c, s, wi, n):
    """Mirror paths of tile-frame normals m (..., 3) with the instrument rotated by φ (cos c, sin s).

    Returns, in the instrument frame: the face met (+1: along m, −1: the other), cos of
    incidence on it, the internal exit direction ω_o and its direction in air (z = 0 where the
    ray goes down or is totally reflected).
    """
    m_inst = _rotz(m, c, -s)
    cos_i = m_inst @ wi
    face = jnp.where(cos_i >= 0.0, 1.0, -1.0)
    cos_i = jnp.abs(cos_i)
    wo = 2.0 * (cos_i * face)[..., None] * m_inst - wi
    xy = n * wo[..., :2]
    s2 = jnp.sum(xy * xy, -1)
    leaves = (wo[..., 2] > 0.0) & (s2 < 1.0)
    air = jnp.concatenate([xy, jnp.where(leaves, jnp.sqrt(jnp.clip(1.0 - s2, 0.0, 1.0)), 0.0)[..., None]], -1)
    return face, cos_i, wo, air


@eqx.filter_jit
def _weights(normals, widths, depth, c_phi, s_phi, wi, det_air, cos_alpha, n, scale, free_depth, mirror):
    """Z's integrand per detector, platelet and azimuth node (m, N, Φ), and the sampling proxy √τ̂ (N, Φ)."""
    _, cos_i, wo, air = _mirror_paths(normals[:, None, :], c_phi[None, :], s_phi[None, :], wi, n)
    T_o = 1.0 - fresnel_dielectric(air[..., 2], 1.0, n)[2]
    base = scale * T_o * mirror.albedo(cos_i) * cos_i * widths[:, None] ** 2 / jnp.maximum(air[..., 2], 1e-300)
    inside = (air[..., 2] > 0.0) & (jnp.einsum("npc,mc->mnp", air, det_air) >= cos_alpha)
    weight = jnp.where(inside, base[None], 0.0)
    # √ of a proxy of the entry and exit transmission at the platelet's depth (horizontal
    # platelets' mean free depth): any positive proxy keeps the estimate unbiased, and √ of the
    # true transmission minimises the variance of the binary visibility
    proxy = jnp.sqrt(jnp.exp(-depth[:, None] * (1.0 / wi[2] + 1.0 / jnp.maximum(wo[..., 2], 1e-3)) / free_depth))
    return weight, proxy


def tile_mirror_single_scatter(array, geometry: Geometry, mirror: MirrorBRDF, grid, *, n: float, samples: int = 20_000,
                               seed: int = 0, azimuth_nodes: int = 2048, max_cells: int = 32):
    """Single-scatter reflectance factor of one tile's mirror platelets into each finite detector aperture.

    What `trace(..., single_scatter=True, options=TracerOptions(edges="absorb"))` estimates on the
    same tile under a flat coat (with its default random instrument azimuth).

    Arguments:
        array: the `PlateletArray` (its own tilts, positions, widths and boxes).
        geometry: instrument geometry with a finite `detector_aperture_deg` and a collimated
            illumination (`illumination_aperture_deg` = 0).
        mirror: the platelets' mirror BRDF (its Fresnel reflectance in the binder).
        grid: the array's uniform grid (for the visibility walk).
        n: coat (and binder) index; the coat is flat.
        samples: visibility points per detector.
        seed: NumPy seed of the visibility points.
        azimuth_nodes: midpoint nodes of the instrument azimuth for Z.
        max_cells: cells per round of the visibility walk, ≥ 2 (undecided rays resume).

    Returns:
        dict of per-detector arrays: `reflectance_factor` Z·V̄, `se` (from V̄), `unoccluded` Z and
        `visibility` V̄. A detector no mirror path reaches has Z = 0 and returns zeros (R = 0 is
        then exact); float64 must be enabled.
    """
    if geometry.illumination_aperture_deg != 0.0:
        raise ValueError("tile_mirror_single_scatter needs a collimated illumination (illumination_aperture_deg = 0)")
    alpha = float(geometry.detector_aperture_deg)
    if not alpha > 0.0:
        raise ValueError(f"geometry.detector_aperture_deg must be > 0 for mirror platelets, got {alpha!r}")
    for name, value, low in (("samples", samples, 2), ("azimuth_nodes", azimuth_nodes, 8), ("max_cells", max_cells, 2)):
        if not (isinstance(value, (int, np.integer)) and value >= low):
            raise ValueError(f"{name} must be an integer ≥ {low}, got {value!r}")
    check_coat_index(n)
    check_platelet_medium(mirror, n)
    if jnp.asarray(0.0).dtype != jnp.float64:  # the face offsets and walk decisions need it
        raise RuntimeError("tile_mirror_single_scatter needs float64: call jax.config.update('jax_enable_x64', True) first")
    Lx, Ly = (float(x) for x in array.tile)
    h_b, t = float(array.basecoat_thickness), float(array.thickness)
    centres = np.asarray(array.centers, float).reshape(-1, 3)
    normals = np.asarray(array.normals, float).reshape(-1, 3)
    axes_u = np.asarray(array.axes_u, float).reshape(-1, 3)
    axes_v = np.cross(normals, axes_u)
    widths = np.asarray(array.widths, float).reshape(-1)

    wi_air = np.asarray(geometry.illumination_air(), float)
    det_air = np.asarray(geometry.detectors_air(), float)
    wi = np.asarray(refract_into_coat(jnp.asarray(wi_air), n))
    T_i = 1.0 - float(fresnel_dielectric(wi_air[2], 1.0, n)[2])
    cos_alpha = np.cos(np.deg2rad(alpha))
    omega = 2.0 * np.pi * (1.0 - cos_alpha)
    phi = (np.arange(azimuth_nodes) + 0.5) * (2.0 * np.pi / azimuth_nodes)
    c_phi, s_phi = np.cos(phi), np.sin(phi)

    depth = h_b - centres[:, 2]
    free_depth = Lx * Ly * h_b / max(float(np.sum(widths**2)), 1e-300)  # of horizontal platelets
    scale = np.pi * T_i / (wi[2] * Lx * Ly * omega * azimuth_nodes)
    weight, proxy = (np.asarray(a) for a in _weights(*(jnp.asarray(v) for v in (normals, widths, depth, c_phi, s_phi, wi, det_air)),
                                                      cos_alpha, n, scale, free_depth, mirror))

    sc = build_scene(array, geometry, mirror, grid, n=n, clearcoat_thickness=0.0, primer_albedo=0.0, dtype=jnp.float64)
    walk = jax.jit(jax.vmap(lambda p, d, tl: _traverse(sc, p, d, tl, True, max_cells)))
    rng = np.random.default_rng(seed)
    eps = float(sc.eps)
    out = {k: np.zeros(len(det_air)) for k in ("reflectance_factor", "se", "unoccluded", "visibility")}
    for k, axis in enumerate(det_air):
        w_k = weight[k]
        out["unoccluded"][k] = Z = float(w_k.sum())
        if Z == 0.0:
            continue
        q = w_k * proxy
        Q = float(q.sum())
        pick = rng.choice(q.size, size=int(samples), p=(q / Q).ravel())
        j, l = np.unravel_index(pick, q.shape)
        st = rng.uniform(-0.5, 0.5, (int(samples), 2)) * widths[j, None]
        face, _, wo, _ = (np.asarray(a) for a in _mirror_paths(jnp.asarray(normals[j]), jnp.asarray(c_phi[l]), jnp.asarray(s_phi[l]),
                                                                 jnp.asarray(wi), n))
        m_face = face[:, None] * normals[j]
        x = centres[j] + (0.5 * t + eps) * m_face + st[:, :1] * axes_u[j] + st[:, 1:] * axes_v[j]
        # entry: down from the top of the basecoat to x, as the beam goes (a face point inside an
        # overlapping box is then shadowed by that box); exit: up from x
        d_in = np.asarray(_rotz(jnp.asarray(wi), jnp.asarray(c_phi[l]), jnp.asarray(s_phi[l])))
        d_out = np.asarray(_rotz(jnp.asarray(wo), jnp.asarray(c_phi[l]), jnp.asarray(s_phi[l])))
        t_in = (h_b - x[:, 2]) / d_in[:, 2]
        visible = _path_clear(walk, x + t_in[:, None] * d_in, -d_in, t_in, eps)
        visible &= _path_clear(walk, x, d_out, (h_b - x[:, 2]) / d_out[:, 2], eps)
        v = visible / proxy[j, l]  # V / √τ̂ under the sampling density ∝ W √τ̂
        out["reflectance_factor"][k] = Q * v.mean()
        out["se"][k] = Q * v.std(ddof=1) / np.sqrt(v.size)
        out["visibility"][k] = out["reflectance_factor"][k] / Z
    return out


def _path_clear(walk, p, d, limit, eps):
    """Whether each ray from p along d meets no box within distance `limit`.

    `walk` covers a fixed number of cells per round; undecided rays resume `eps` past the point
    reached (as the tracer does, so a ray on a cell boundary cannot stall), compacted into
    power-of-two batches (few compilations).
    """
    p, d, limit = np.array(p, float), np.asarray(d, float), np.array(limit, float)
    clear = np.zeros(len(p), bool)
    todo = np.arange(len(p))
    for _ in range(4096):
        if todo.size == 0:
            return clear
        size = max(1024, 1 << int(np.ceil(np.log2(todo.size))))
        idx = np.concatenate([todo, np.full(size - todo.size, todo[0])])
        tb, _, _, reach, done = (np.asarray(a) for a in walk(jnp.asarray(p[idx]), jnp.asarray(d[idx]), jnp.asarray(limit[idx])))
        tb, reach, done = tb[: todo.size], reach[: todo.size], done[: todo.size]
        hit = tb < limit[todo]
        clear[todo[done & ~hit]] = True
        go = ~done & ~hit
        nxt = todo[go]
        p[nxt] += (reach[go, None] + eps) * d[nxt]
        limit[nxt] -= reach[go] + eps
        todo = nxt
    raise RuntimeError("visibility walk did not finish")
