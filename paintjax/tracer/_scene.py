"""The tracer's device scene and its geometry kernels: packed platelets, the uniform-grid traversal, box hits.

`build_scene` packs a `PlateletArray`, its `UniformGrid`, the platelet BRDF and the instrument into
a `_Scene` pytree; `_traverse` walks a ray through the periodic grid cell by cell (jax-md cell-list
pattern, fixed capacity) and returns the nearest platelet hit (or any hit, for shadow rays).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from ..brdf._platelet import AbstractPlateletBRDF
from ..instrument._geometry import Geometry, refract_into_coat
from ..instrument._single_scatter import _orthonormal_basis
from ..microstructure._grid import check_grid_matches
from ..optics._interface import slope_sd
from ._options import _BIG, detector_reverse_shares

# ----------------------------------------------------------------------------------------------
# Scene


class _Scene(eqx.Module):
    cols: tuple  # (cx, cy, cz, ux, uy, uz, nx, ny, nz, w/2), each padded (N_pad,); padding = dummy
    cells: Int[Array, "ncell_pad C_pad"]  # platelet indices, −1 mapped to a dummy entry
    grid_n: Int[Array, "3"]
    cell_size: Float[Array, "3"]
    tile: Float[Array, "2"]
    half_t: Float[Array, ""]
    h_b: Float[Array, ""]
    h_c: Float[Array, ""]
    n: Float[Array, ""]
    albedo: Float[Array, ""]
    eps: Float[Array, ""]
    illum_air: Float[Array, "P 3"]  # P sources; ray r comes from source wheel[r mod len(wheel)] (the reverse pool: one per detector)
    illum_cos_alpha: Float[Array, ""]
    det_air: Float[Array, "m 3"]
    det_cos_alpha: Float[Array, ""]
    brdf: AbstractPlateletBRDF
    slope_sd: Float[Array, ""]  # per-component slope sd of a wavy clearcoat (0 = flat)
    log_reverse_share: Float[Array, "P m"]  # bidirectional MIS: log(reverse rays / forward rays) per source and detector (−inf: off)
    illum_in_z: Float[Array, " P"]  # |z| of the refracted source directions (projected-area factor of the beam)
    wheel: Int[Array, " W"]  # the cycle of sources the rays are dealt over (one entry per share)
    max_cells: int = eqx.field(static=True)  # budget of a ray's step
    shadow_cells: int = eqx.field(static=True)  # cells a shadow ray crosses at most to the top within the flat coat's critical angle
    wavy: bool = eqx.field(static=True, default=False)  # draw facet normals at the clearcoat surface
    mis: bool = eqx.field(static=True, default=False)  # NEE + BRDF-sampled exits, balance heuristic
    bidir: bool = eqx.field(static=True, default=False)  # NEE weighted against the reverse (detector-side) tracer


def _bucket(x: int, q: int) -> int:
    return max(q, -(-int(x) // q) * q)


def _pack_platelets(array, dtype, n_pad: int) -> tuple:
    c = np.asarray(array.centers, dtype=float).reshape(-1, 3)
    nrm = np.asarray(array.normals, dtype=float).reshape(-1, 3)
    u = np.asarray(array.axes_u, dtype=float).reshape(-1, 3)
    w = np.asarray(array.widths, dtype=float).reshape(-1)
    packed = np.concatenate([c, u, nrm, w[:, None] / 2], axis=-1)
    dummy = np.array([0.0, 0.0, -1e6, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0])  # far below, zero size: never hit
    packed = np.concatenate([packed, np.broadcast_to(dummy, (n_pad - len(c), 10))], axis=0)
    return tuple(jnp.asarray(packed[:, k], dtype) for k in range(packed.shape[1]))


#: Steepest internal direction of a wavy coat's next-event estimate, as tan θ_in. A facet refracts an air
#: direction to at most the critical angle from its normal, so only steep facets reach beyond the flat
#: coat's tan θ_c = 0.894, at vanishing visible weight: at the largest waviness (15°) no weight lay
#: beyond tan 2.84 for a detector at 85°, nor beyond 3.34 at 89.9° (2·10⁷ facets each). Directions
#: beyond are not scored, which bounds a shadow ray's travel and so its resumptions (`_shadows`).
_WAVY_MAX_TAN_IN = 3.5
_WAVY_MIN_COS_IN = float(1.0 / np.sqrt(1.0 + _WAVY_MAX_TAN_IN**2))


def _shadow_cell_bound(shape, cell, h_b, n) -> int:
    """Cells a ray toward any detector through a flat coat crosses at most from inside the basecoat to its top.

    Any air direction refracts to within the critical angle (sin θ_in ≤ 1/n); fixed by that bound, not
    by the geometry, so geometries share a compilation. A wavy coat's steeper directions resume (`_shadows`).
    """
    nz = shape[2]
    sin_in = 1.0 / n
    lateral = h_b * sin_in / np.sqrt(1.0 - sin_in**2)
    return int(nz + int(np.ceil(lateral / cell[0])) + int(np.ceil(lateral / cell[1])) + 1)


# ----------------------------------------------------------------------------------------------
# Geometry helpers (single ray; vmapped by the callers)


def _rotz(v, c, s):
    """Rotate vectors v (..., 3) about z by the angle with cosine c and sine s (c, s broadcast against v[..., 0])."""
    z = jnp.broadcast_to(v[..., 2], jnp.broadcast_shapes(jnp.shape(c), v.shape[:-1]))
    return jnp.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1], z], axis=-1)


def _cone(axis, cos_alpha, u1, u2):
    """Uniform direction in the cap of half-angle α around `axis` (u1, u2 uniform); α = 0 gives axis."""
    c = 1.0 - u1 * (1.0 - cos_alpha)
    s = jnp.sqrt(jnp.clip(1.0 - c * c, 0.0, 1.0))
    phi = 2.0 * jnp.pi * u2
    t1, t2 = _orthonormal_basis(axis)
    return (s * jnp.cos(phi))[..., None] * t1 + (s * jnp.sin(phi))[..., None] * t2 + c[..., None] * axis


def _refract_in(w_air, n):
    t = w_air[..., :2] / n
    return jnp.concatenate([t, jnp.sqrt(jnp.clip(1.0 - jnp.sum(t * t, -1, keepdims=True), 0.0, 1.0))], axis=-1)


def _to_local(w, t1, t2, nrm):
    return jnp.stack([jnp.sum(w * t1, -1), jnp.sum(w * t2, -1), jnp.sum(w * nrm, -1)], axis=-1)


def _slab(q, ox, oy, oz, dx, dy, dz, half_t):
    """Slab test of rays o + t d (o relative to the box centres) against boxes with columns q.

    Written component by component (no reductions over length-3 axes, per-column gathers):
    this is the hot loop. Returns (t_in, t_out, (tn_u, tn_v, tn_n), (d_u, d_v, d_n)).
    """
    ux, uy, uz, nx, ny, nz, hw = q
    vx, vy, vz = ny * uz - nz * uy, nz * ux - nx * uz, nx * uy - ny * ux
    tns, tfs, das = [], [], []
    for ax, ay, az, h in ((ux, uy, uz, hw), (vx, vy, vz, hw), (nx, ny, nz, half_t)):
        oa = ox * ax + oy * ay + oz * az
        da = dx * ax + dy * ay + dz * az
        da = jnp.where(jnp.abs(da) < 1e-15, jnp.where(da >= 0, 1e-15, -1e-15), da)
        inv = 1.0 / da
        t1 = (-h - oa) * inv
        t2 = (h - oa) * inv
        tns.append(jnp.minimum(t1, t2))
        tfs.append(jnp.maximum(t1, t2))
        das.append(da)
    t_in = jnp.maximum(jnp.maximum(tns[0], tns[1]), tns[2])
    t_out = jnp.minimum(jnp.minimum(tfs[0], tfs[1]), tfs[2])
    return t_in, t_out, tns, das


def _gather(sc: _Scene, j):
    return tuple(col.at[j].get(mode="promise_in_bounds") for col in sc.cols)


def _traverse(sc: _Scene, p, d, t_limit, any_hit: bool, max_cells: int):
    """3-D DDA through at most `max_cells` periodic cells from p along d, up to distance t_limit.

    Single ray (vmapped by the callers); `any_hit` stops at the first occluder
    (shadow rays). p may lie in any periodic image of the tile (a hit point, a shadow ray's
    origin): the walk starts from its image in the tile, and the returned shift is relative to p.
    Returns (t_best, index_best, image shift (2,), t_reached, finished). A hit exists when
    t_best < t_limit; `finished` is False when the cell budget ran out before a decision, and the
    ray must resume at p + t_reached d.
    """
    dtype = p.dtype
    gn = sc.grid_n
    nx, ny, nz = gn[0], gn[1], gn[2]
    cs = sc.cell_size
    Lx, Ly = sc.tile[0], sc.tile[1]
    image_x, image_y = Lx * jnp.floor(p[0] / Lx), Ly * jnp.floor(p[1] / Ly)
    px, py, pz = p[0] - image_x, p[1] - image_y, p[2]
    dx, dy, dz = d[0], d[1], d[2]

    def axis_init(pc, dc, c, n):
        small = jnp.abs(dc) < 1e-15
        i = jnp.clip(jnp.floor(pc / c).astype(jnp.int32), 0, n - 1)
        pos_dir = dc >= 0
        step = jnp.where(pos_dir, 1, -1).astype(jnp.int32)
        bnd = (i + pos_dir.astype(jnp.int32)).astype(dtype) * c
        safe = jnp.where(small, 1.0, dc)
        tmax = jnp.where(small, _BIG, (bnd - pc) / safe)
        tdel = jnp.where(small, _BIG, c / jnp.abs(safe))
        return i, step, tmax.astype(dtype), tdel.astype(dtype)

    ix, sx_, tmx, tdx = axis_init(px, dx, cs[0], nx)
    iy, sy_, tmy, tdy = axis_init(py, dy, cs[1], ny)
    iz, sz_, tmz, tdz = axis_init(pz, dz, cs[2], nz)
    dummy = sc.cols[0].shape[0] - 1

    def body(_, carry):
        ix, iy, iz, tmx, tmy, tmz, tb, jb, bsx, bsy, treach, done = carry
        t_exit = jnp.minimum(jnp.minimum(tmx, tmy), tmz)
        flat = (jnp.mod(ix, nx) * ny + jnp.mod(iy, ny)) * nz + jnp.clip(iz, 0, nz - 1)
        cand = sc.cells.at[flat].get(mode="promise_in_bounds")
        qx, qy, qz, *q = _gather(sc, cand)
        shx = Lx * jnp.round(((ix.astype(dtype) + 0.5) * cs[0] - qx) / Lx)
        shy = Ly * jnp.round(((iy.astype(dtype) + 0.5) * cs[1] - qy) / Ly)
        t_in, t_out, _, _ = _slab(q, px - qx - shx, py - qy - shy, pz - qz, dx, dy, dz, sc.half_t)
        ok = (t_in <= t_out) & (t_in > 0.0) & (t_in < tb)
        tt = jnp.where(ok, t_in, _BIG)
        k = jnp.argmin(tt)
        tk = tt[k]
        better = (tk < _BIG) & ~done
        tb = jnp.where(better, tk, tb)
        jb = jnp.where(better, cand[k], jb)
        bsx = jnp.where(better, shx[k], bsx)
        bsy = jnp.where(better, shy[k], bsy)
        finish = done | (t_exit >= t_limit) | (tb <= t_exit)
        if any_hit:
            finish = finish | (tb < t_limit)
        treach = jnp.where(done, treach, jnp.minimum(t_exit, t_limit))
        mx = (tmx <= tmy) & (tmx <= tmz)
        my = ~mx & (tmy <= tmz)
        mz = ~mx & ~my
        go = ~finish
        ix = jnp.where(go & mx, ix + sx_, ix)
        iy = jnp.where(go & my, iy + sy_, iy)
        iz = jnp.where(go & mz, iz + sz_, iz)
        tmx = jnp.where(go & mx, tmx + tdx, tmx)
        tmy = jnp.where(go & my, tmy + tdy, tmy)
        tmz = jnp.where(go & mz, tmz + tdz, tmz)
        finish = finish | (iz < 0) | (iz >= nz)
        return ix, iy, iz, tmx, tmy, tmz, tb, jb, bsx, bsy, treach, finish

    zero = jnp.zeros((), dtype)
    init = (ix, iy, iz, tmx, tmy, tmz, jnp.asarray(t_limit, dtype), jnp.asarray(dummy, jnp.int32), zero, zero, zero, jnp.asarray(False))
    out = jax.lax.fori_loop(0, max_cells, body, init)
    _, _, _, _, _, _, tb, jb, bsx, bsy, treach, done = out
    return tb, jb, jnp.stack([bsx + image_x, bsy + image_y]), treach, done


def _face_normal(sc: _Scene, j, shift, x_hit, d):
    """Outward normal of the face of box j (image `shift`) through which direction d entered."""
    qx, qy, qz, *q = _gather(sc, j)
    o = x_hit - d
    _, _, tns, das = _slab(q, o[0] - qx - shift[0], o[1] - qy - shift[1], o[2] - qz, d[0], d[1], d[2], sc.half_t)
    ux, uy, uz, nx, ny, nz, _ = q
    u = jnp.stack([ux, uy, uz])
    n = jnp.stack([nx, ny, nz])
    v = jnp.cross(n, u)
    is_u = (tns[0] >= tns[1]) & (tns[0] >= tns[2])
    is_v = ~is_u & (tns[1] >= tns[2])
    axis = jnp.where(is_u, u, jnp.where(is_v, v, n))
    da = jnp.where(is_u, das[0], jnp.where(is_v, das[1], das[2]))
    return -jnp.sign(da) * axis, is_u | is_v


def _in_dtype(brdf: AbstractPlateletBRDF, dtype) -> AbstractPlateletBRDF:
    """The BRDF with its floating-point arrays in the tracer's dtype (its evaluations then run in it)."""
    cast = lambda x: x.astype(dtype) if isinstance(x, jax.Array) and jnp.issubdtype(x.dtype, jnp.floating) else x  # noqa: E731
    return jax.tree_util.tree_map(cast, brdf)


# ----------------------------------------------------------------------------------------------
def build_scene(array, geometry: Geometry, brdf: AbstractPlateletBRDF, grid, *, n: float, clearcoat_thickness: float,
                primer_albedo: float, waviness_deg: float = 0.0, dtype=jnp.float32, min_cells: int = 2, mis: bool = True,
                reverse_share=None, reverse: bool = False) -> _Scene:
    """Pack an array, its grid, the BRDF and the instrument into the tracer's device scene.

    `reverse`: the reverse pool of bidirectional MIS, by reciprocity: one source per detector (at
    the detector's direction) and one detector at the illumination direction. `reverse_share`: the
    reverse rays per forward ray, a number for every detector or one per detector (rounded as
    `detector_reverse_shares` rounds them), for both scenes; the reverse pool deals its rays to the
    detectors with a share, in proportion to it.

    Platelet and cell tables are padded to bucketed sizes and the grid dimensions are traced
    values, so arrays of similar size (e.g. the two reference samples) share one compilation.
    """
    Lx, Ly = (float(x) for x in array.tile)
    h_b = float(array.basecoat_thickness)
    shape = tuple(int(s) for s in grid.shape)
    cell = np.array([Lx / shape[0], Ly / shape[1], h_b / shape[2]])
    check_grid_matches(array, grid)
    cells = np.asarray(grid.cell_platelets)
    n_pl = int(np.asarray(array.widths).reshape(-1).shape[0])
    ncell = shape[0] * shape[1] * shape[2]
    n_pad = _bucket(n_pl + 1, 512)
    table = np.full((_bucket(ncell, 1024), _bucket(cells.shape[1], 4)), n_pad - 1, dtype=np.int32)
    table[:ncell, : cells.shape[1]] = np.where(cells < 0, n_pad - 1, cells)
    eps = max(1e-9, 64.0 * float(jnp.finfo(dtype).eps)) * max(Lx, Ly, h_b)
    arr = lambda x: jnp.asarray(np.asarray(x, dtype=float), dtype)  # noqa: E731
    sources = np.asarray(geometry.illumination_air(), dtype=float)[None]
    detectors = np.asarray(geometry.detectors_air(), dtype=float)
    illum_alpha, det_alpha = geometry.illumination_aperture_deg, geometry.detector_aperture_deg
    if reverse:
        sources, detectors, illum_alpha, det_alpha = detectors, sources, det_alpha, illum_alpha
    shares, wheel = detector_reverse_shares(0.0 if reverse_share is None else reverse_share, detectors.shape[0] if not reverse else sources.shape[0])
    # log(rays of the other pass / this pass's rays), per detector (forward: one source) or per source (reverse: one detector)
    log_share = np.where(shares > 0, np.log(np.where(shares > 0, shares, 1.0)), -1e30)
    log_share = (-log_share)[:, None] if reverse else log_share[None, :]
    wheel = wheel if reverse else np.zeros(1, np.int64)
    src_in = np.asarray(refract_into_coat(jnp.asarray(sources), float(n)))
    return _Scene(
        cols=_pack_platelets(array, dtype, n_pad),
        cells=jnp.asarray(table),
        grid_n=jnp.asarray(shape, jnp.int32),
        cell_size=arr(cell),
        tile=arr([Lx, Ly]),
        half_t=arr(0.5 * float(array.thickness)),
        h_b=arr(h_b),
        h_c=arr(float(clearcoat_thickness)),
        n=arr(float(n)),
        albedo=arr(float(primer_albedo)),
        eps=arr(eps),
        illum_air=arr(sources),
        illum_cos_alpha=arr(np.cos(np.deg2rad(illum_alpha))),
        det_air=arr(detectors),
        det_cos_alpha=arr(np.cos(np.deg2rad(det_alpha))),
        brdf=_in_dtype(brdf, dtype),
        slope_sd=arr(slope_sd(waviness_deg)),
        log_reverse_share=arr(log_share),
        illum_in_z=arr(np.abs(src_in[:, 2])),
        wheel=jnp.asarray(wheel, jnp.int32),
        max_cells=int(min_cells),
        shadow_cells=_shadow_cell_bound(shape, cell, h_b, float(n)),
        wavy=waviness_deg > 0.0,
        mis=bool(mis) and det_alpha > 0.0 and not waviness_deg > 0.0,
        bidir=bool(np.any(shares > 0)),
    )
