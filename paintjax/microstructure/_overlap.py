"""Overlap tests between platelets (square rectangular prisms), vectorised in NumPy.

Two tests, both over any leading (broadcast) dimensions of pairs:

* **exact** (`obb_overlap`): separating-axis test (SAT) of two oriented boxes over the 15
  candidate axes (3 + 3 face normals, 9 edge cross products; cross products of parallel
  edges are skipped, the face axes cover them). Boxes are closed sets and *overlap* means
  their interiors intersect: boxes that only touch (a shared face, edge or corner) do not
  overlap.
* **mid-plane** (`midplane_overlap`): the original study's test. Each platelet is reduced to
  its mid-plane square, split into two triangles, and the four triangle pairs are tested with
  Möller's (1997) interval test (`tri_tri_intersect`, touching counts as intersecting).
  Mid-plane intersection implies box overlap, so this test misses overlaps (e.g. two
  near-parallel platelets less than one thickness apart) but never invents them.

Periodic images (lateral tile Lx × Ly) are handled by `periodic_overlap`: the minimum-image
separation is tested, plus the neighbouring images whenever the axis-aligned bounding boxes
allow a second image to touch (only possible for tiles under twice the platelet extent).

Box convention: centre c (…, 3), axes (…, 3, 3) whose *rows* are the unit axes (u, v, n), half
extents (…, 3). A platelet of width w and thickness t has half extents (w/2, w/2, t/2).
NumPy rather than JAX: overlap removal is irregular, sequential work on small batches, where
NumPy's per-call cost is far below JAX dispatch.
"""

from __future__ import annotations

import numpy as np

#: Cross-product axes with |A_i × B_j| below this are skipped (parallel edges).
_PARALLEL_EPS = 1e-9


_I = np.repeat(np.arange(3), 3)
_J = np.tile(np.arange(3), 3)
_I1, _I2, _J1, _J2 = (_I + 1) % 3, (_I + 2) % 3, (_J + 1) % 3, (_J + 2) % 3


def obb_overlap(ca, Ra, ea, cb, Rb, eb) -> np.ndarray:
    """Exact separating-axis overlap test of oriented boxes (interiors intersect).

    Arguments:
        ca, cb: (..., 3) box centres.
        Ra, Rb: (..., 3, 3) unit axes as rows.
        ea, eb: (..., 3) half extents along those axes (≥ 0).

    Returns:
        (...) bool, True where the interiors of the two boxes intersect.
    """
    ca, cb, ea, eb = (np.asarray(x, dtype=float) for x in (ca, cb, ea, eb))
    Ra, Rb = np.asarray(Ra, dtype=float), np.asarray(Rb, dtype=float)
    d = cb - ca
    C = Ra @ np.swapaxes(Rb, -1, -2)  # C_ij = A_i · B_j
    aC = np.abs(C)
    t = (Ra @ d[..., :, None])[..., 0]  # separation in A's frame
    # Face axes of A: |t_i| ≥ e_a,i + Σ_j e_b,j |C_ij| separates; of B: |Σ_i C_ij t_i| ≥ Σ_i e_a,i |C_ij| + e_b,j.
    sep = np.any(np.abs(t) >= ea + (aC @ eb[..., :, None])[..., 0], axis=-1)
    tb = (t[..., None, :] @ C)[..., 0, :]
    sep |= np.any(np.abs(tb) >= (ea[..., None, :] @ aC)[..., 0, :] + eb, axis=-1)
    # Edge–edge axes A_i × B_j (unnormalised; the comparison is scale-free). Parallel edges give a
    # null axis, skipped: the face axes cover that case.
    Cij = C[..., _I, _J]
    dist = np.abs(t[..., _I2] * C[..., _I1, _J] - t[..., _I1] * C[..., _I2, _J])
    ra = ea[..., _I1] * aC[..., _I2, _J] + ea[..., _I2] * aC[..., _I1, _J]
    rb = eb[..., _J1] * aC[..., _I, _J2] + eb[..., _J2] * aC[..., _I, _J1]
    sep |= np.any((dist >= ra + rb) & (1.0 - Cij**2 > _PARALLEL_EPS**2), axis=-1)
    return ~sep


def aabb_half_extents(R, e) -> np.ndarray:
    """(..., 3) half extents of the axis-aligned bounding box of oriented boxes (R rows, e)."""
    return np.einsum("...k,...kx->...x", np.asarray(e, dtype=float), np.abs(np.asarray(R, dtype=float)))


def minimum_image(d, tile) -> np.ndarray:
    """Lateral minimum-image convention: shift d[..., 0:2] by multiples of the tile into [-L/2, L/2]."""
    d = np.array(d, dtype=float, copy=True)
    L = np.asarray(tile, dtype=float)
    d[..., :2] -= L * np.round(d[..., :2] / L)
    return d


def _square_triangles(c, R, half_width) -> np.ndarray:
    """(..., 2, 3, 3): the mid-plane square c ± a u ± a v as two triangles (vertex rows)."""
    a = np.asarray(half_width, dtype=float)[..., None]
    u, v = R[..., 0, :] * a, R[..., 1, :] * a
    p00, p10, p11, p01 = c - u - v, c + u - v, c + u + v, c - u + v
    t1 = np.stack([p00, p10, p11], axis=-2)
    t2 = np.stack([p00, p11, p01], axis=-2)
    return np.stack([t1, t2], axis=-3)


def midplane_overlap(ca, Ra, wa, cb, Rb, wb) -> np.ndarray:
    """The original study's test: do the mid-plane squares (two triangles each) intersect?

    Arguments:
        ca, cb: (..., 3) centres; Ra, Rb: (..., 3, 3) axes as rows (u, v, n); wa, wb: (...) widths.

    Returns:
        (...) bool, True where any of the 2 × 2 triangle pairs intersect (Möller's test).
    """
    Ta = _square_triangles(np.asarray(ca, float), np.asarray(Ra, float), 0.5 * np.asarray(wa, float))
    Tb = _square_triangles(np.asarray(cb, float), np.asarray(Rb, float), 0.5 * np.asarray(wb, float))
    hit = np.zeros(np.broadcast_shapes(Ta.shape[:-3], Tb.shape[:-3]), dtype=bool)
    for i in range(2):
        for j in range(2):
            hit |= tri_tri_intersect(Ta[..., i, :, :], Tb[..., j, :, :])
    return hit


def _cross(a, b):
    return np.stack(
        [
            a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
            a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
            a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0],
        ],
        axis=-1,
    )


def _dot(a, b):
    return np.sum(a * b, axis=-1)


def _plane_distances(T, P):
    """Signed distances (scaled by |N|) of the vertices of P from the plane of triangle T."""
    N = _cross(T[..., 1, :] - T[..., 0, :], T[..., 2, :] - T[..., 0, :])
    d = _dot(N[..., None, :], P) - _dot(N, T[..., 0, :])[..., None]
    scale = np.sqrt(_dot(N, N)) * np.max(np.abs(P - T[..., 0:1, :]), axis=(-2, -1))
    d = np.where(np.abs(d) <= 1e-12 * scale[..., None], 0.0, d)
    return N, d


def _intervals(p, dd):
    """Möller's compute_intervals: the segment of the triangle on the line, in projection p."""
    d0, d1, d2 = dd[..., 0], dd[..., 1], dd[..., 2]
    # index of the vertex alone on its side of the other plane (Möller's branch order)
    k = np.where(
        d0 * d1 > 0, 2, np.where(d0 * d2 > 0, 1, np.where((d1 * d2 > 0) | (d0 != 0), 0, np.where(d1 != 0, 1, 2)))
    )
    i = np.where(k == 0, 1, 0)
    j = np.where(k == 2, 1, 2)
    take = lambda a, idx: np.take_along_axis(a, idx[..., None], axis=-1)[..., 0]  # noqa: E731
    pk, pi, pj = take(p, k), take(p, i), take(p, j)
    dk, di, dj = take(dd, k), take(dd, i), take(dd, j)
    den_i = np.where(dk - di == 0, 1.0, dk - di)
    den_j = np.where(dk - dj == 0, 1.0, dk - dj)
    a = pk + (pi - pk) * dk / den_i
    b = pk + (pj - pk) * dk / den_j
    return np.minimum(a, b), np.maximum(a, b)


def _orient2(a, b, c):
    return (b[..., 0] - a[..., 0]) * (c[..., 1] - a[..., 1]) - (b[..., 1] - a[..., 1]) * (c[..., 0] - a[..., 0])


def _segments_intersect_2d(p1, p2, q1, q2):
    o1, o2 = _orient2(p1, p2, q1), _orient2(p1, p2, q2)
    o3, o4 = _orient2(q1, q2, p1), _orient2(q1, q2, p2)
    proper = (o1 * o2 <= 0) & (o3 * o4 <= 0)
    # collinear segments: need overlapping bounding boxes as well
    collinear = (o1 == 0) & (o2 == 0)
    lo_p, hi_p = np.minimum(p1, p2), np.maximum(p1, p2)
    lo_q, hi_q = np.minimum(q1, q2), np.maximum(q1, q2)
    boxes = np.all((lo_p <= hi_q) & (lo_q <= hi_p), axis=-1)
    return np.where(collinear, boxes, proper)


def _point_in_tri_2d(p, T):
    o0 = _orient2(T[..., 0, :], T[..., 1, :], p)
    o1 = _orient2(T[..., 1, :], T[..., 2, :], p)
    o2 = _orient2(T[..., 2, :], T[..., 0, :], p)
    return ((o0 >= 0) & (o1 >= 0) & (o2 >= 0)) | ((o0 <= 0) & (o1 <= 0) & (o2 <= 0))


def _coplanar_tri_tri(N, V, U):
    ax = np.argmax(np.abs(N), axis=-1)
    keep = np.stack([np.where(ax == 0, 1, 0), np.where(ax == 2, 1, 2)], axis=-1)  # drop the dominant axis
    idx = np.broadcast_to(keep[..., None, :], V.shape[:-1] + (2,))
    V2 = np.take_along_axis(V, idx, axis=-1)
    U2 = np.take_along_axis(U, np.broadcast_to(keep[..., None, :], U.shape[:-1] + (2,)), axis=-1)
    hit = _point_in_tri_2d(V2[..., 0, :], U2) | _point_in_tri_2d(U2[..., 0, :], V2)
    for a in range(3):
        for b in range(3):
            hit |= _segments_intersect_2d(V2[..., a, :], V2[..., (a + 1) % 3, :], U2[..., b, :], U2[..., (b + 1) % 3, :])
    return hit


def tri_tri_intersect(V, U) -> np.ndarray:
    """Möller's triangle–triangle intersection test (touching counts as intersecting).

    Arguments:
        V, U: (..., 3, 3) triangles, vertices as rows (broadcast against each other).

    Returns:
        (...) bool.
    """
    V, U = np.broadcast_arrays(np.asarray(V, dtype=float), np.asarray(U, dtype=float))
    N1, du = _plane_distances(V, U)
    N2, dv = _plane_distances(U, V)
    sep = ((du[..., 0] * du[..., 1] > 0) & (du[..., 0] * du[..., 2] > 0)) | (
        (dv[..., 0] * dv[..., 1] > 0) & (dv[..., 0] * dv[..., 2] > 0)
    )
    coplanar = np.all(du == 0, axis=-1) | np.all(dv == 0, axis=-1)
    D = _cross(N1, N2)
    ax = np.argmax(np.abs(D), axis=-1)[..., None]
    vp = np.take_along_axis(V, np.broadcast_to(ax[..., None], V.shape[:-1] + (1,)), axis=-1)[..., 0]
    up = np.take_along_axis(U, np.broadcast_to(ax[..., None], U.shape[:-1] + (1,)), axis=-1)[..., 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        a0, a1 = _intervals(vp, dv)
        b0, b1 = _intervals(up, du)
    general = ~((a1 < b0) | (b1 < a0))
    out = np.where(coplanar, False, general) & ~sep
    if np.any(coplanar & ~sep):
        out = out | (coplanar & ~sep & _coplanar_tri_tri(N1, V, U))
    return out


def periodic_overlap(ca, Ra, ea, cb, Rb, eb, tile, test: str = "sat") -> np.ndarray:
    """Overlap of box pairs in a laterally periodic tile, all relevant images included.

    Arguments:
        ca, Ra, ea, cb, Rb, eb: boxes as in `obb_overlap` (broadcast to a common (P,) shape).
        tile: (Lx, Ly) lateral period [µm].
        test: "sat" (exact boxes) or "midplane" (Möller on the mid-plane squares; the widths
            are 2·e[..., 0]).

    Returns:
        (P,) bool.
    """
    if test not in ("sat", "midplane"):
        raise ValueError(f"test must be 'sat' or 'midplane', got {test!r}")
    ca, Ra, ea, cb, Rb, eb = (np.asarray(x, dtype=float) for x in (ca, Ra, ea, cb, Rb, eb))
    lead = np.broadcast_shapes(ca.shape[:-1], Ra.shape[:-2], ea.shape[:-1], cb.shape[:-1], Rb.shape[:-2], eb.shape[:-1])
    if lead == ():
        one = [x[None] for x in (ca, Ra, ea, cb, Rb, eb)]
        return periodic_overlap(*one, tile, test)[0]
    ca, ea, cb, eb = (np.broadcast_to(x, lead + (3,)).reshape(-1, 3) for x in (ca, ea, cb, eb))
    Ra, Rb = (np.broadcast_to(x, lead + (3, 3)).reshape(-1, 3, 3) for x in (Ra, Rb))
    if len(lead) != 1:
        return periodic_overlap(ca, Ra, ea, cb, Rb, eb, tile, test).reshape(lead)
    if test == "midplane":  # boxes of zero thickness bound the mid-plane squares
        ea = np.array(ea)
        eb = np.array(eb)
        ea[..., 2] = 0.0
        eb[..., 2] = 0.0
    L = np.asarray(tile, dtype=float)
    d0 = minimum_image(cb - ca, L)
    reach = aabb_half_extents(Ra, ea) + aabb_half_extents(Rb, eb)
    out = np.zeros(ca.shape[:-1], dtype=bool)
    # Images other than the minimum one can touch only where the reach exceeds half the tile.
    kxs = (0,) if np.all(reach[..., 0] <= 0.5 * L[0]) else (0, -1, 1)
    kys = (0,) if np.all(reach[..., 1] <= 0.5 * L[1]) else (0, -1, 1)
    for kx in kxs:
        for ky in kys:
            d = d0 + np.array([kx * L[0], ky * L[1], 0.0])
            cand = np.all(np.abs(d) <= reach, axis=-1) & ~out  # ≤: touching counts (coplanar mid-planes: reach_z = 0)
            if not np.any(cand):
                continue
            idx = np.flatnonzero(cand)
            if test == "sat":
                hit = obb_overlap(0.0 * d[idx], Ra[idx], ea[idx], d[idx], Rb[idx], eb[idx])
            else:
                hit = midplane_overlap(0.0 * d[idx], Ra[idx], 2 * ea[idx, 0], d[idx], Rb[idx], 2 * eb[idx, 0])
            out[idx[hit]] = True
    return out
