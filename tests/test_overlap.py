"""Overlap tests: exact box SAT against independent references, Möller's triangle test, images."""

import numpy as np
import pytest
from scipy.optimize import linprog
from scipy.spatial.transform import Rotation

from paintjax import midplane_overlap, obb_overlap, periodic_overlap, tri_tri_intersect


def random_boxes(rng, n, spread=3.0):
    R = Rotation.random(n, random_state=rng).as_matrix().transpose(0, 2, 1)  # rows = axes
    e = rng.uniform(0.2, 2.0, (n, 3))
    c = rng.uniform(-spread, spread, (n, 3))
    return c, R, e


def chebyshev_margin(ca, Ra, ea, cb, Rb, eb) -> float:
    """Largest s with a point at depth ≥ s inside both boxes (LP); > 0 iff the interiors meet."""
    A, b = [], []
    for c, R, e in ((ca, Ra, ea), (cb, Rb, eb)):
        for k in range(3):
            for sgn in (1.0, -1.0):
                A.append(np.r_[sgn * R[k], 1.0])
                b.append(e[k] + sgn * R[k] @ c)
    res = linprog(c=[0, 0, 0, -1.0], A_ub=np.array(A), b_ub=np.array(b), bounds=[(None, None)] * 3 + [(None, 10.0)])
    assert res.status == 0
    return -res.fun


def inside(p, c, R, e, strict=True):
    local = np.abs((p - c) @ R.T)
    return np.all(local < e, axis=-1) if strict else np.all(local <= e, axis=-1)


def grid_sampling_overlap(ca, Ra, ea, cb, Rb, eb, spacing=0.05):
    """Brute force: any point of a regular lattice inside both boxes?"""
    ha = np.abs(Ra).T @ ea
    hb = np.abs(Rb).T @ eb
    lo = np.maximum(ca - ha, cb - hb)
    hi = np.minimum(ca + ha, cb + hb)
    if np.any(hi <= lo):
        return False
    axes = [np.arange(lo[k], hi[k] + spacing, spacing) for k in range(3)]
    P = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    return bool(np.any(inside(P, ca, Ra, ea) & inside(P, cb, Rb, eb)))


def test_sat_agrees_with_lp_and_point_sampling_on_random_pairs():
    rng = np.random.default_rng(1)
    n = 300
    ca, Ra, ea = random_boxes(rng, n)
    cb, Rb, eb = random_boxes(rng, n)
    sat = obb_overlap(ca, Ra, ea, cb, Rb, eb)
    margins = np.array([chebyshev_margin(ca[k], Ra[k], ea[k], cb[k], Rb[k], eb[k]) for k in range(n)])
    clear = np.abs(margins) > 1e-7
    assert clear.sum() > 0.95 * n
    np.testing.assert_array_equal(sat[clear], margins[clear] > 0)
    assert 0.2 * n < sat.sum() < 0.8 * n  # both classes well represented
    # point sampling on a lattice of spacing h finds every overlap deeper than h·√3/2
    robust = np.flatnonzero(np.abs(margins) > 0.05)
    assert robust.size > 0.8 * n
    brute = np.array([grid_sampling_overlap(ca[k], Ra[k], ea[k], cb[k], Rb[k], eb[k]) for k in robust])
    np.testing.assert_array_equal(sat[robust], brute)


def test_sat_broadcasts_and_is_symmetric():
    rng = np.random.default_rng(2)
    ca, Ra, ea = random_boxes(rng, 50)
    cb, Rb, eb = random_boxes(rng, 50)
    ab = obb_overlap(ca, Ra, ea, cb, Rb, eb)
    ba = obb_overlap(cb, Rb, eb, ca, Ra, ea)
    np.testing.assert_array_equal(ab, ba)
    one = obb_overlap(ca[0], Ra[0], ea[0], cb, Rb, eb)  # one box against many
    assert one.shape == (50,)
    assert obb_overlap(ca[0], Ra[0], ea[0], cb[0], Rb[0], eb[0]).shape == ()


def test_touching_faces_do_not_overlap_and_a_hair_more_does():
    I = np.eye(3)
    e = np.array([1.0, 0.5, 0.25])
    ca = np.zeros(3)
    cb = np.array([2.0, 0.25, 0.0])  # shares the face x = 1 exactly
    assert not obb_overlap(ca, I, e, cb, I, e)
    assert obb_overlap(ca, I, e, cb - [1e-9, 0, 0], I, e)
    assert not obb_overlap(ca, I, e, cb + [1e-9, 0, 0], I, e)
    # corner contact
    assert not obb_overlap(ca, I, e, 2 * e, I, e)
    assert obb_overlap(ca, I, e, 2 * e - 1e-9, I, e)
    # same face contact after a common rigid rotation (inexact arithmetic: ±1e-9 gaps)
    Q = Rotation.from_euler("zyx", [31.0, -17.0, 8.0], degrees=True).as_matrix()
    for gap, expected in ((1e-9, False), (-1e-9, True)):
        cbq = Q @ (cb + [gap, 0, 0])
        assert obb_overlap(ca, I @ Q.T, e, cbq, I @ Q.T, e) == expected


def test_crossed_edges_separated_only_by_an_edge_cross_axis():
    # A: cube rotated 45° about x (top edge along x at z = √2); B: cube rotated 45° about y
    # (bottom edge along y). Touching at one point when B's centre is at z = 2√2.
    A = Rotation.from_euler("x", 45, degrees=True).as_matrix().T
    B = Rotation.from_euler("y", 45, degrees=True).as_matrix().T
    e = np.ones(3)
    z0 = 2 * np.sqrt(2.0)
    assert obb_overlap(np.zeros(3), A, e, [0, 0, z0 - 1e-9], B, e)
    assert not obb_overlap(np.zeros(3), A, e, [0, 0, z0 + 1e-9], B, e)
    # the face axes alone do not separate the boxes at z0 + 0.01: the cross axis must
    d = np.array([0, 0, z0 + 0.01])
    for axis in list(A) + list(B):
        assert abs(d @ axis) < np.abs(A @ axis) @ e + np.abs(B @ axis) @ e


def test_parallel_boxes_use_face_axes():
    I = np.eye(3)
    e = np.array([1.0, 1.0, 0.5])
    assert obb_overlap(np.zeros(3), I, e, [0.5, 0.5, 0.9], I, e)
    assert not obb_overlap(np.zeros(3), I, e, [0.5, 0.5, 1.1], I, e)


def test_periodic_images():
    tile = (10.0, 10.0)
    I = np.eye(3)
    e = np.array([1.0, 1.0, 0.5])
    # only through the lateral image across x = 0 / x = 10
    ca, cb = np.array([0.5, 5.0, 1.0]), np.array([9.0, 5.0, 1.0])
    assert not obb_overlap(ca, I, e, cb, I, e)
    assert periodic_overlap(ca, I, e, cb, I, e, tile)
    assert periodic_overlap(ca, I, e, cb + [0.4, 0, 0], I, e, tile)  # centres 1.1 apart through the image
    assert not periodic_overlap(ca, I, e, cb - [0.6, 0, 0], I, e, tile)  # 2.1 apart through the image
    # corner image (both x and y wrap)
    assert periodic_overlap([0.2, 0.2, 1.0], I, e, [9.5, 9.5, 1.0], I, e, tile)
    # touching through the image does not overlap
    assert not periodic_overlap([0.5, 5.0, 1.0], I, e, [8.5, 5.0, 1.0], I, e, tile)


def test_periodic_second_image_found_when_the_tile_is_small():
    # Slanted plates (30° about y): the minimum image is clear, the next image overlaps.
    L = 10.0
    R = Rotation.from_euler("y", -30, degrees=True).as_matrix().T  # u = (cos30, 0, sin30)
    e = np.array([4.0, 1.0, 0.5])
    ca = np.array([0.0, 0.0, 0.0])
    cb = np.array([5.5, 0.0, 5.5 * np.tan(np.deg2rad(30))])  # on A's u axis, 5.5 away in x
    min_image = cb - [L, 0, 0]  # |dx| = 4.5 < 5.5
    assert not obb_overlap(ca, R, e, min_image, R, e)
    assert obb_overlap(ca, R, e, cb, R, e)
    assert periodic_overlap(ca, R, e, cb, R, e, (L, 40.0))
    # brute force over images: lattice points inside A and inside some image of B
    P = np.stack(np.meshgrid(*[np.linspace(-6, 6, 61)] * 3, indexing="ij"), -1).reshape(-1, 3)
    hits = [np.any(inside(P, ca, R, e) & inside(P, cb + [k * L, 0, 0], R, e)) for k in (-1, 0, 1)]
    assert hits == [False, True, False]  # k = −1 is the minimum image: clear; k = 0 (dx = 5.5) overlaps


def test_periodic_overlap_matches_brute_force_images_on_random_pairs():
    rng = np.random.default_rng(5)
    n = 200
    tile = (6.0, 7.0)
    ca, Ra, ea = random_boxes(rng, n)
    cb, Rb, eb = random_boxes(rng, n)
    ca[:, :2] = rng.uniform(0, 1, (n, 2)) * tile
    cb[:, :2] = rng.uniform(0, 1, (n, 2)) * tile
    ca[:, 2] = cb[:, 2] = 0.0
    got = periodic_overlap(ca, Ra, ea, cb, Rb, eb, tile)
    want = np.zeros(n, dtype=bool)
    for kx in range(-2, 3):
        for ky in range(-2, 3):
            want |= obb_overlap(ca, Ra, ea, cb + [kx * tile[0], ky * tile[1], 0.0], Rb, eb)
    np.testing.assert_array_equal(got, want)
    assert want.sum() > 20


def segment_hits_triangle(p, q, T, eps=1e-12):
    """Möller–Trumbore for the segment p→q against triangle T (independent reference)."""
    d = q - p
    e1, e2 = T[1] - T[0], T[2] - T[0]
    h = np.cross(d, e2)
    a = e1 @ h
    if abs(a) < eps:
        return False
    f = 1.0 / a
    s = p - T[0]
    u = f * (s @ h)
    if u < 0 or u > 1:
        return False
    qv = np.cross(s, e1)
    v = f * (d @ qv)
    if v < 0 or u + v > 1:
        return False
    t = f * (e2 @ qv)
    return 0 <= t <= 1


def reference_tri_tri(V, U):
    return any(segment_hits_triangle(V[a], V[(a + 1) % 3], U) for a in range(3)) or any(
        segment_hits_triangle(U[a], U[(a + 1) % 3], V) for a in range(3)
    )


def test_moller_agrees_with_edge_piercing_reference():
    rng = np.random.default_rng(3)
    n = 2000
    V = rng.uniform(-1, 1, (n, 3, 3))
    U = rng.uniform(-1, 1, (n, 3, 3)) + rng.uniform(-0.6, 0.6, (n, 1, 3))
    got = tri_tri_intersect(V, U)
    want = np.array([reference_tri_tri(V[k], U[k]) for k in range(n)])
    np.testing.assert_array_equal(got, want)
    assert 0.1 * n < got.sum() < 0.9 * n


def test_moller_coplanar_and_touching_cases():
    T = np.array([[0, 0, 0], [2, 0, 0], [0, 2, 0]], float)
    assert tri_tri_intersect(T, T + [0.5, 0.5, 0])  # coplanar, overlapping
    assert not tri_tri_intersect(T, T + [3, 0, 0])  # coplanar, apart
    assert tri_tri_intersect(T, T + [2, 0, 0])  # coplanar, sharing a vertex
    small = np.array([[0.2, 0.2, 0], [0.5, 0.2, 0], [0.2, 0.5, 0]], float)
    assert tri_tri_intersect(T, small) and tri_tri_intersect(small, T)  # contained
    # crossing at right angles / just missing
    S = np.array([[0.5, 0.5, -1], [0.5, 0.5, 1], [0.5, 3, 0]], float)
    assert tri_tri_intersect(T, S)
    assert not tri_tri_intersect(T, S + [2.0, 0, 0])
    # a vertex touching the plane inside the triangle
    P = np.array([[0.5, 0.5, 0], [0.5, 0.5, 1], [1, 0.5, 1]], float)
    assert tri_tri_intersect(T, P)
    assert not tri_tri_intersect(T, P + [0, 0, 1e-6])


def test_midplane_test_implies_box_overlap_and_misses_some():
    rng = np.random.default_rng(4)
    n = 4000
    R = Rotation.random(n, random_state=rng).as_matrix().transpose(0, 2, 1)
    R2 = Rotation.random(n, random_state=rng).as_matrix().transpose(0, 2, 1)
    w1, w2 = rng.uniform(2, 6, n), rng.uniform(2, 6, n)
    c2 = rng.uniform(-4, 4, (n, 3))
    t = 1.0
    mid = midplane_overlap(np.zeros(3), R, w1, c2, R2, w2)
    box = obb_overlap(np.zeros(3), R, np.stack([w1 / 2, w1 / 2, np.full(n, t / 2)], 1), c2, R2, np.stack([w2 / 2, w2 / 2, np.full(n, t / 2)], 1))
    assert mid.sum() > 100
    assert not np.any(mid & ~box)
    assert np.any(box & ~mid)
    # two parallel platelets 0.5 µm apart (thickness 1): boxes overlap, mid-planes never meet
    I = np.eye(3)
    assert obb_overlap(np.zeros(3), I, [5, 5, 0.5], [1, 1, 0.5], I, [5, 5, 0.5])
    assert not midplane_overlap(np.zeros(3), I, 10.0, [1, 1, 0.5], I, 10.0)
    assert periodic_overlap(np.zeros(3), I, [5, 5, 0.5], [1, 1, 0.5], I, [5, 5, 0.5], (100.0, 100.0), test="sat")
    assert not periodic_overlap(np.zeros(3), I, [5, 5, 0.5], [1, 1, 0.5], I, [5, 5, 0.5], (100.0, 100.0), test="midplane")


def test_periodic_overlap_rejects_unknown_test():
    I = np.eye(3)
    with pytest.raises(ValueError, match="test"):
        periodic_overlap(np.zeros(3), I, np.ones(3), np.ones(3), I, np.ones(3), (10.0, 10.0), test="aabb")
