"""Uniform grid: complete and sound cell lists, periodic lookups, overflow flag, neighbour pairs."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from paintjax import PlateletArray, UniformGrid, build_grid, candidate_pairs, check_grid_matches, generate_platelet_array, periodic_overlap
from paintjax.microstructure._grid import platelet_boxes


@pytest.fixture(scope="module")
def array():
    return generate_platelet_array(3, pvc=0.2, tilt=(2.29, 2.18), tile=150.0)


@pytest.fixture(scope="module")
def grid(array):
    return build_grid(array)


def points_in_platelets(array, per_platelet, rng):
    """Random points inside every platelet box, wrapped into the primary tile."""
    c, R, e = platelet_boxes(array)
    s = rng.uniform(-1, 1, (c.shape[0], per_platelet, 3)) * e[:, None, :]
    p = c[:, None, :] + np.einsum("npk,nkx->npx", s, R)
    p[..., 0] %= array.tile[0]
    p[..., 1] %= array.tile[1]
    return p


def test_grid_shape_and_contract(array, grid):
    assert isinstance(grid, UniformGrid)
    nx, ny, nz = grid.shape
    assert grid.cell_platelets.shape == (nx * ny * nz, grid.capacity)
    assert grid.cell_platelets.dtype == jnp.int32
    np.testing.assert_allclose(np.array(grid.cell_size) * grid.shape, [*array.tile, array.basecoat_thickness])
    # default cell ≈ half the median width
    med = float(np.median(np.asarray(array.widths)))
    assert 0.3 * med < grid.cell_size[0] < 0.7 * med
    assert not bool(grid.overflow)
    assert int(np.max(np.asarray(grid.cell_counts))) == grid.capacity  # default capacity = max occupancy
    # each row: valid indices first, then −1 padding
    table = np.asarray(grid.cell_platelets)
    counts = np.asarray(grid.cell_counts)
    assert np.all((table >= 0).sum(axis=1) == counts)
    assert table.max() < array.count


def test_every_point_of_every_platelet_is_listed_in_its_cell(array, grid):
    """What the tracer relies on: a ray point inside platelet j lies in a cell that lists j."""
    rng = np.random.default_rng(0)
    p = points_in_platelets(array, 40, rng)
    cells = np.asarray(grid.cell_of(jnp.asarray(p.reshape(-1, 3)))).reshape(p.shape[:2])
    assert np.all(cells >= 0)
    cand = np.asarray(grid.candidates(jnp.asarray(cells)))  # (N, P, capacity)
    listed = np.any(cand == np.arange(array.count)[:, None, None], axis=-1)
    assert listed.all()
    # corners and face centres too (boundary points)
    c, R, e = platelet_boxes(array)
    signs = np.array([[a, b, d] for a in (-1, 1) for b in (-1, 1) for d in (-1, 1)], float)
    corners = c[:, None, :] + np.einsum("sk,nk,nkx->nsx", signs, e, R)
    corners[..., 0] %= array.tile[0]
    corners[..., 1] %= array.tile[1]
    cells = np.asarray(grid.cell_of(jnp.asarray(corners)))
    cand = np.asarray(grid.candidates(jnp.asarray(cells)))
    assert np.any(cand == np.arange(array.count)[:, None, None], axis=-1).all()


def test_listed_platelets_really_touch_their_cells(array, grid):
    c, R, e = platelet_boxes(array)
    table = np.asarray(grid.cell_platelets)
    cell, slot = np.nonzero(table >= 0)
    j = table[cell, slot]
    lo, hi = (np.asarray(x) for x in grid.cell_bounds(jnp.asarray(cell)))
    centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo) + 2e-3
    hit = periodic_overlap(centre, np.eye(3), half, c[j], R[j], e[j], array.tile)
    assert hit.all()


def test_cell_lookup_is_periodic_and_bounded_in_z(grid, array):
    Lx, Ly = array.tile
    h_b = array.basecoat_thickness
    p = jnp.asarray([[1.0, 2.0, 3.0], [1.0 + Lx, 2.0 - Ly, 3.0], [1.0 - 3 * Lx, 2.0, 3.0]])
    c = np.asarray(grid.cell_of(p))
    assert c[0] == c[1] == c[2] >= 0
    top = np.asarray(grid.cell_coords(jnp.asarray([5.0, 5.0, h_b])))
    assert top[2] == grid.shape[2] - 1
    assert np.asarray(grid.cell_of(jnp.asarray([[5.0, 5.0, -1e-9], [5.0, 5.0, h_b + 1e-9]]))).tolist() == [-1, -1]
    assert np.all(np.asarray(grid.candidates(-1)) == -1)
    lo, hi = grid.cell_bounds(jnp.asarray(c[0]))
    assert np.all(np.asarray(lo) <= [1.0, 2.0, 3.0]) and np.all(np.asarray(hi) >= [1.0, 2.0, 3.0])
    # cell_index round trip
    ix, iy, iz = (int(v) for v in np.asarray(grid.cell_coords(p[0])))
    assert int(grid.cell_index(ix, iy, iz)) == c[0]


def test_grid_lookups_jit_and_vmap(grid):
    pts = jnp.asarray(np.random.default_rng(1).uniform(0, 20, (7, 3)))
    f = jax.jit(lambda g, p: g.candidates(g.cell_of(p)))
    out = f(grid, pts)
    assert out.shape == (7, grid.capacity)
    np.testing.assert_array_equal(np.asarray(out), np.asarray(grid.candidates(grid.cell_of(pts))))
    leaves = jax.tree_util.tree_leaves(grid)
    assert len(leaves) == 3  # cell_platelets, cell_counts, overflow


def test_overflow_flag_and_capacity(array, grid):
    small = build_grid(array, capacity=1)
    assert bool(small.overflow)
    assert small.capacity == 1
    np.testing.assert_array_equal(np.asarray(small.cell_counts), np.asarray(grid.cell_counts))
    with pytest.raises(ValueError, match="overflow"):
        candidate_pairs(small)
    big = build_grid(array, capacity=grid.capacity + 5)
    assert not bool(big.overflow) and big.capacity == grid.capacity + 5
    with pytest.raises(ValueError, match="capacity"):
        build_grid(array, capacity=0)


def test_a_grid_only_fits_its_own_array(array, grid):
    """The tracer checks the grid against the array: another seed, a bigger array or another tile is refused."""
    check_grid_matches(array, grid)
    moved = PlateletArray(centers=array.centers.at[:, 0].add(0.5 * array.tile[0]), normals=array.normals, axes_u=array.axes_u,
                          widths=array.widths, thickness=array.thickness, tile=array.tile, basecoat_thickness=array.basecoat_thickness)
    with pytest.raises(ValueError, match="built for another array"):  # same tile, count and sizes, other places
        check_grid_matches(moved, grid)
    check_grid_matches(moved, build_grid(moved))
    bigger = generate_platelet_array(3, pvc=0.2, tilt=(2.29, 2.18), tile=200.0)
    fewer = PlateletArray(centers=array.centers[:10], normals=array.normals[:10], axes_u=array.axes_u[:10], widths=array.widths[:10],
                          thickness=array.thickness, tile=array.tile, basecoat_thickness=array.basecoat_thickness)
    with pytest.raises(ValueError, match="but the array has 10 platelets"):
        check_grid_matches(fewer, grid)
    with pytest.raises(ValueError, match="tile"):
        check_grid_matches(array, build_grid(bigger))


def test_cell_size_override(array):
    g = build_grid(array, cell_size=25.0)
    assert g.shape == (6, 6, 1)
    g = build_grid(array, cell_size=(30.0, 15.0, 5.0))
    assert g.shape == (5, 10, 4)
    with pytest.raises(ValueError, match="cell_size"):
        build_grid(array, cell_size=-1.0)


def test_candidate_pairs_contain_every_overlapping_pair():
    arr = generate_platelet_array(4, pvc=0.2, tilt=(2.29, 2.18), tile=120.0, overlap_test="none")
    g = build_grid(arr)
    pairs = {tuple(p) for p in candidate_pairs(g).tolist()}
    c, R, e = platelet_boxes(arr)
    i, j = np.triu_indices(arr.count, 1)
    hit = periodic_overlap(c[i], R[i], e[i], c[j], R[j], e[j], arr.tile)
    overlapping = set(zip(i[hit].tolist(), j[hit].tolist()))
    assert len(overlapping) > 50  # the unprocessed array overlaps a lot
    assert overlapping <= pairs
    assert all(a < b for a, b in pairs)


def test_grid_rejects_platelets_outside_the_basecoat(array):
    c = np.asarray(array.centers).copy()
    c[0, 2] = array.basecoat_thickness  # half the box above h_b
    bad = PlateletArray(
        centers=jnp.asarray(c),
        normals=array.normals,
        axes_u=array.axes_u,
        widths=array.widths,
        thickness=array.thickness,
        tile=array.tile,
        basecoat_thickness=array.basecoat_thickness,
    )
    with pytest.raises(ValueError, match="array"):
        build_grid(bad)


def test_single_flat_platelet_across_the_periodic_corner():
    one = PlateletArray(
        centers=jnp.asarray([[0.5, 0.5, 10.0]]),
        normals=jnp.asarray([[0.0, 0.0, 1.0]]),
        axes_u=jnp.asarray([[1.0, 0.0, 0.0]]),
        widths=jnp.asarray([8.0]),
        thickness=1.0,
        tile=(40.0, 40.0),
        basecoat_thickness=20.0,
    )
    g = build_grid(one, cell_size=4.0, pad=0.0)
    assert g.shape == (10, 10, 5)
    listed = np.flatnonzero(np.asarray(g.cell_counts))
    coords = np.stack([listed // 50, (listed // 5) % 10, listed % 5], 1)
    # x, y ∈ [-3.5, 4.5] wraps to cells {9, 0, 1}; z ∈ [9.5, 10.5] → cells {2}
    assert sorted(set(coords[:, 0])) == [0, 1, 9]
    assert sorted(set(coords[:, 1])) == [0, 1, 9]
    assert set(coords[:, 2]) == {2}
    assert listed.size == 9


def test_incremental_column_hash_finds_every_laterally_touching_platelet():
    """The neighbour search of overlap removal: a superset of the laterally touching pairs."""
    from paintjax.microstructure._grid import _ColumnCells

    rng = np.random.default_rng(7)
    L = np.array([100.0, 80.0])
    n = 400
    h = rng.lognormal(np.log(6.0), 0.6, (n, 2))  # lateral half extents 1…40
    xy = rng.uniform(0, 1, (n, 2)) * L
    cells = _ColumnCells(L, h.max(axis=1))
    for j in range(n):
        cells.insert(j, xy[j, 0], xy[j, 1], h[j, 0], h[j, 1])
    for hx, hy in ((0.5, 0.5), (5.0, 12.0), (30.0, 3.0)):
        q = rng.uniform(0, 1, (25, 2)) * L
        k, j = cells.query(q[:, 0], q[:, 1], hx, hy)
        found = set(zip(k.tolist(), j.tolist()))
        assert len(found) == len(k)  # each pair once
        d = xy[None, :, :] - q[:, None, :]
        d -= L * np.round(d / L)
        touch = np.all(np.abs(d) < np.array([hx, hy]) + h[None, :, :], axis=-1)
        want = set(zip(*np.nonzero(touch)))
        assert want <= found
        assert len(want) > 0
