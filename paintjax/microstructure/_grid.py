"""A uniform grid over the basecoat (jax-md cell-list pattern), periodic in x and y.

The grid covers [0, Lx) × [0, Ly) × [0, h_b] with nx × ny × nz equal cells. Cell
(ix, iy, iz) has index (ix·ny + iy)·nz + iz and spans [ix·dx, (ix+1)·dx] × … . A platelet is
listed in every cell that its box, or one of its lateral periodic images, intersects (exact
separating-axis test against the cell inflated by `pad`, 1 nm by default, so rays on a cell
face never miss a platelet). Lists have a fixed capacity and are padded with −1; `overflow`
is set when some cell held more platelets than the capacity (the excess is dropped, as in
jax-md: rebuild with a larger capacity). By default the capacity is the largest occupancy, so
the default build never overflows.

Periodic images: the grid stores platelet *indices*. A user testing platelet j near a point p
takes the image of its centre closest to p (`PlateletArray.nearest_image_centers`); the tile is
at least √2·w_max + t wide, so that image is unique.

The grid is built once per array in NumPy (irregular work) and is a JAX pytree; lookups
(`cell_of`, `candidates`, `cell_bounds`) are jittable and vectorised.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from ._overlap import aabb_half_extents, obb_overlap

#: Default cell edge as a fraction of the median platelet width.
DEFAULT_CELL_FRACTION = 0.5


class UniformGrid(eqx.Module):
    """Cell lists of the platelets over [0, Lx) × [0, Ly) × [0, h_b], periodic in x and y.

    Fields:
        cell_platelets: (nx·ny·nz, capacity) int32 platelet indices, padded with −1.
        cell_counts: (nx·ny·nz,) int32 true occupancy (may exceed capacity when overflowing).
        overflow: bool scalar, True when any cell held more than `capacity` platelets.
        shape: static (nx, ny, nz).
        cell_size: static (dx, dy, dz) [µm] = (Lx/nx, Ly/ny, h_b/nz).
        tile: static (Lx, Ly) [µm]; basecoat_thickness: static h_b [µm].
    """

    cell_platelets: Int[Array, "cells capacity"]
    cell_counts: Int[Array, " cells"]
    overflow: Bool[Array, ""]
    shape: tuple[int, int, int] = eqx.field(static=True)
    cell_size: tuple[float, float, float] = eqx.field(static=True)
    tile: tuple[float, float] = eqx.field(static=True)
    basecoat_thickness: float = eqx.field(static=True)

    @staticmethod
    def build(array, cell_size=None, capacity: int | None = None, pad: float = 1e-3) -> "UniformGrid":
        """Same as `build_grid`."""
        return build_grid(array, cell_size, capacity, pad)

    @property
    def num_cells(self) -> int:
        return self.shape[0] * self.shape[1] * self.shape[2]

    @property
    def capacity(self) -> int:
        return int(self.cell_platelets.shape[1])

    def cell_index(self, ix: ArrayLike, iy: ArrayLike, iz: ArrayLike) -> Int[Array, "..."]:
        """Flat cell index of integer cell coordinates; ix, iy wrap periodically, iz must be in [0, nz)."""
        nx, ny, nz = self.shape
        return ((jnp.asarray(ix) % nx) * ny + (jnp.asarray(iy) % ny)) * nz + jnp.asarray(iz)

    @eqx.filter_jit
    def cell_coords(self, points: Float[ArrayLike, "... 3"]) -> Int[Array, "... 3"]:
        """Integer cell coordinates (ix, iy, iz) of points; x, y wrap, z = h_b falls in the top cell.

        iz is −1 for points outside [0, h_b] in z (no clamping).
        """
        p = jnp.asarray(points)
        nx, ny, nz = self.shape
        dx, dy, dz = self.cell_size
        ix = jnp.floor(p[..., 0] / dx).astype(jnp.int32) % nx
        iy = jnp.floor(p[..., 1] / dy).astype(jnp.int32) % ny
        z = p[..., 2]
        iz = jnp.minimum(jnp.floor(z / dz).astype(jnp.int32), nz - 1)
        iz = jnp.where((z >= 0) & (z <= self.basecoat_thickness), iz, -1)
        return jnp.stack([ix, iy, iz], axis=-1)

    @eqx.filter_jit
    def cell_of(self, points: Float[ArrayLike, "... 3"]) -> Int[Array, "..."]:
        """Flat cell index of points, −1 for points outside the basecoat in z."""
        c = self.cell_coords(points)
        return jnp.where(c[..., 2] >= 0, self.cell_index(c[..., 0], c[..., 1], c[..., 2]), -1)

    @eqx.filter_jit
    def candidates(self, cell: ArrayLike) -> Int[Array, "... capacity"]:
        """Platelet indices listed in `cell` (padded with −1); cell −1 gives all −1."""
        cell = jnp.asarray(cell)
        rows = self.cell_platelets[jnp.clip(cell, 0, self.num_cells - 1)]
        return jnp.where((cell >= 0)[..., None], rows, -1)

    @eqx.filter_jit
    def cell_bounds(self, cell: ArrayLike) -> tuple[Float[Array, "... 3"], Float[Array, "... 3"]]:
        """Lower and upper corners of cells (in the primary tile)."""
        cell = jnp.asarray(cell)
        nx, ny, nz = self.shape
        iz = cell % nz
        iy = (cell // nz) % ny
        ix = cell // (ny * nz)
        lo = jnp.stack([ix, iy, iz], axis=-1) * jnp.asarray(self.cell_size)
        return lo, lo + jnp.asarray(self.cell_size)


def platelet_boxes(array) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """NumPy float64 boxes of a platelet array: centres (N, 3), axes rows (u, v, n) (N, 3, 3), half extents (N, 3)."""
    c = np.asarray(array.centers, dtype=float)
    n = np.asarray(array.normals, dtype=float)
    u = np.asarray(array.axes_u, dtype=float)
    w = np.asarray(array.widths, dtype=float)
    R = np.stack([u, np.cross(n, u), n], axis=1)
    e = np.stack([0.5 * w, 0.5 * w, np.full_like(w, 0.5 * float(array.thickness))], axis=1)
    return c, R, e


def _grid_shape(tile, h_b, cell_size) -> tuple[int, int, int]:
    cs = np.broadcast_to(np.asarray(cell_size, dtype=float), (3,))
    if np.any(~np.isfinite(cs)) or np.any(cs <= 0):
        raise ValueError(f"cell_size must be positive [µm] (a number or (dx, dy, dz)), got {cell_size!r}")
    extent = np.array([tile[0], tile[1], h_b], dtype=float)
    n = np.maximum(1, np.round(extent / cs)).astype(int)
    if np.prod(n) > 50_000_000:
        raise ValueError(f"cell_size {cell_size!r} gives {np.prod(n)} cells; choose larger cells")
    return int(n[0]), int(n[1]), int(n[2])


def default_cell_size(array) -> float:
    """Default cell edge [µm]: half the median platelet width (cells then list a few platelets)."""
    return DEFAULT_CELL_FRACTION * float(np.median(np.asarray(array.widths)))


def _enumerate_ranges(lo: np.ndarray, span: np.ndarray):
    """For ranges lo[i] + [0, span[i]) (span ≥ 1 per axis, (N, 3)), list (owner, ix, iy, iz)."""
    n_per = np.prod(span, axis=1)
    owner = np.repeat(np.arange(lo.shape[0]), n_per)
    start = np.cumsum(n_per) - n_per
    local = np.arange(int(n_per.sum())) - np.repeat(start, n_per)
    sy, sz = span[owner, 1], span[owner, 2]
    iz = local % sz
    iy = (local // sz) % sy
    ix = local // (sz * sy)
    return owner, lo[owner, 0] + ix, lo[owner, 1] + iy, lo[owner, 2] + iz


def check_grid_matches(array, grid) -> None:
    """Raise unless `grid` is a cell list of `array`: same tile and basecoat (where the grid records
    them), indices inside the array, and every platelet listed in the cell of its centre.

    Catches a grid built for another array (another seed, size or tile), which would otherwise
    trace the wrong platelets or read past the platelet table. O(platelets × capacity)."""
    cells = np.asarray(grid.cell_platelets)
    shape = tuple(int(v) for v in grid.shape)
    n = int(np.asarray(array.widths).reshape(-1).shape[0])
    if cells.ndim != 2 or cells.shape[0] != int(np.prod(shape)):
        raise ValueError(f"grid.cell_platelets must have shape (nx*ny*nz, capacity), got {cells.shape} for shape {shape}")
    tile = tuple(float(v) for v in array.tile)
    h_b = float(array.basecoat_thickness)
    if getattr(grid, "tile", None) is not None and not np.allclose(grid.tile, tile, rtol=1e-9, atol=0.0):
        raise ValueError(f"grid was built for a {tuple(grid.tile)} µm tile, but the array's tile is {tile} µm: rebuild the grid")
    if getattr(grid, "basecoat_thickness", None) is not None and not np.isclose(grid.basecoat_thickness, h_b, rtol=1e-9, atol=0.0):
        raise ValueError(f"grid was built for a basecoat of {grid.basecoat_thickness:g} µm, but the array's is {h_b:g} µm: rebuild the grid")
    if cells.size and int(cells.max()) >= n:
        raise ValueError(f"grid lists platelet {int(cells.max())}, but the array has {n} platelets: rebuild the grid")
    if n == 0:
        return
    c = np.asarray(array.centers, float).reshape(-1, 3)
    d = np.array([tile[0] / shape[0], tile[1] / shape[1], h_b / shape[2]])
    ix = np.floor(np.mod(c[:, 0], tile[0]) / d[0]).astype(np.int64) % shape[0]
    iy = np.floor(np.mod(c[:, 1], tile[1]) / d[1]).astype(np.int64) % shape[1]
    iz = np.clip(np.floor(c[:, 2] / d[2]).astype(np.int64), 0, shape[2] - 1)
    listed = np.any(cells[(ix * shape[1] + iy) * shape[2] + iz] == np.arange(n)[:, None], axis=1)
    if not np.all(listed):
        raise ValueError(f"grid does not list {int(np.sum(~listed))} of the array's {n} platelets in the cells of their "
                         "centres: it was built for another array (or overflowed); rebuild it with build_grid(array)")


def build_grid(array, cell_size=None, capacity: int | None = None, pad: float = 1e-3) -> UniformGrid:
    """Build the uniform grid of a `PlateletArray` (NumPy, exact box–cell tests).

    Arguments:
        array: the platelets; every box must lie inside [0, h_b] in z.
        cell_size: target cell edge [µm], a number or (dx, dy, dz); default half the median
            width. The actual cells divide the tile and the basecoat exactly (nearest count).
        capacity: platelets per cell; default the largest occupancy (never overflows). A smaller
            value drops the excess and sets `overflow`.
        pad: cells are inflated by this much [µm] for the listing test (≥ 0).

    Returns:
        UniformGrid.
    """
    Lx, Ly = (float(v) for v in array.tile)
    h_b = float(array.basecoat_thickness)
    cell_size = default_cell_size(array) if cell_size is None else cell_size
    shape = _grid_shape((Lx, Ly), h_b, cell_size)
    d = np.array([Lx / shape[0], Ly / shape[1], h_b / shape[2]])
    if not (np.isfinite(pad) and pad >= 0):
        raise ValueError(f"pad must be a non-negative length [µm], got {pad!r}")
    if capacity is not None and (int(capacity) != capacity or capacity < 1):
        raise ValueError(f"capacity must be a positive integer, got {capacity!r}")

    c, R, e = platelet_boxes(array)
    n = c.shape[0]
    h = aabb_half_extents(R, e)
    # tolerance: rounding of float32 leaves (x64 off) plus a hair
    tol = 1e-9 + 8 * float(jnp.finfo(jnp.asarray(array.centers).dtype).eps) * max(h_b, 1.0)
    if n and (np.any(c[:, 2] - h[:, 2] < -tol) or np.any(c[:, 2] + h[:, 2] > h_b + tol)):
        raise ValueError("array: every platelet box must lie inside the basecoat [0, h_b] in z for the grid")
    ncell = int(np.prod(shape))
    if n:
        lo = np.floor((c - h - pad) / d).astype(np.int64)
        hi = np.floor((c + h + pad) / d).astype(np.int64)
        lo[:, 2] = np.clip(lo[:, 2], 0, shape[2] - 1)
        hi[:, 2] = np.clip(hi[:, 2], 0, shape[2] - 1)
        owner, ix, iy, iz = _enumerate_ranges(lo, hi - lo + 1)
        cell_lo = np.stack([ix, iy, iz], axis=1) * d
        centre = cell_lo + 0.5 * d
        hit = obb_overlap(c[owner], R[owner], e[owner], centre, np.eye(3), 0.5 * d + pad)
        owner, ix, iy, iz = owner[hit], ix[hit] % shape[0], iy[hit] % shape[1], iz[hit]
        cell = (ix * shape[1] + iy) * shape[2] + iz
        key = np.unique(cell * n + owner)  # sorted by cell, then platelet; duplicates removed
        cell, owner = key // n, key % n
    else:
        cell = owner = np.zeros(0, dtype=np.int64)
    counts = np.bincount(cell, minlength=ncell)
    cap = max(int(counts.max(initial=0)), 1) if capacity is None else int(capacity)
    start = np.cumsum(counts) - counts
    slot = np.arange(cell.size) - start[cell]
    keep = slot < cap
    table = np.full((ncell, cap), -1, dtype=np.int32)
    table[cell[keep], slot[keep]] = owner[keep]
    return UniformGrid(
        cell_platelets=jnp.asarray(table),
        cell_counts=jnp.asarray(counts.astype(np.int32)),
        overflow=jnp.asarray(bool(np.any(counts > cap))),
        shape=shape,
        cell_size=(float(d[0]), float(d[1]), float(d[2])),
        tile=(Lx, Ly),
        basecoat_thickness=h_b,
    )


def candidate_pairs(grid: UniformGrid) -> np.ndarray:
    """(P, 2) int64 pairs i < j of platelets sharing at least one cell (neighbour search).

    Every pair of overlapping platelets shares a cell, so overlap counts need only these.

    Raises:
        ValueError: if the grid overflowed (its lists are incomplete).
    """
    if bool(grid.overflow):
        raise ValueError("grid: the cell lists overflowed; rebuild with a larger capacity")
    table = np.asarray(grid.cell_platelets)
    counts = np.minimum(np.asarray(grid.cell_counts), table.shape[1])
    valid = table >= 0
    entries = table[valid].astype(np.int64)  # row-major: grouped by cell
    cell = np.nonzero(valid)[0]
    start = (np.cumsum(counts) - counts)[cell]
    pos = np.arange(entries.size) - start
    partners = counts[cell] - 1 - pos  # later entries in the same cell
    owner = np.repeat(np.arange(entries.size), partners)
    first = np.cumsum(partners) - partners
    other = owner + 1 + (np.arange(owner.size) - np.repeat(first, partners))
    a, b = entries[owner], entries[other]
    i, j = np.minimum(a, b), np.maximum(a, b)
    n = int(entries.max(initial=0)) + 1
    key = np.unique(i * n + j)
    return np.stack([key // n, key % n], axis=1)


class _ColumnCells:
    """Incremental neighbour search for overlap removal (NumPy, periodic in x and y).

    A multi-level column hash: a platelet of lateral bounding half-extent h is stored once, at
    the level ℓ with reach r_ℓ = r_0·2^ℓ ≥ h, in the column (side ≥ r_ℓ/2) holding its centre.
    `query` returns, for candidate centres sharing one bounding box (half extents hx, hy),
    every (candidate, platelet) pair whose lateral bounding boxes can touch, each pair once
    (possibly plus some that cannot).
    """

    def __init__(self, tile, lateral_half_extents):
        self.L = np.asarray(tile, dtype=float)
        h = np.asarray(lateral_half_extents, dtype=float)
        self.r0 = max(float(np.median(h)), 1e-6)
        n_levels = 1 + max(0, int(np.ceil(np.log2(max(float(h.max()), self.r0) / self.r0))))
        self.levels = []
        rows = 0
        for lev in range(n_levels):
            reach = self.r0 * 2.0**lev
            n = np.minimum(np.maximum(1, np.floor(2 * self.L / reach)), 4096).astype(int)
            self.levels.append(dict(reach=reach, n=n, d=self.L / n, offset=rows, used=0))
            rows += int(n[0] * n[1])
        # one table for all levels (rows = columns), so a query is a single gather
        self.data = np.full((rows, 2), -1, dtype=np.int64)
        self.count = np.zeros(rows, dtype=np.int64)

    def insert(self, j: int, x: float, y: float, hx: float, hy: float) -> None:
        h = max(hx, hy, self.r0)
        lv = self.levels[min(int(np.ceil(np.log2(h / self.r0) - 1e-12)), len(self.levels) - 1)]
        n, d = lv["n"], lv["d"]
        row = lv["offset"] + (int(np.floor(x / d[0])) % n[0]) * n[1] + int(np.floor(y / d[1])) % n[1]
        if self.count[row] >= self.data.shape[1]:
            self.data = np.concatenate([self.data, np.full_like(self.data, -1)], axis=1)
        self.data[row, self.count[row]] = j
        self.count[row] += 1
        lv["used"] += 1

    @staticmethod
    def _axis(lv, x, h, a):
        r = h + lv["reach"]
        n, d = lv["n"][a], lv["d"][a]
        s = int(2 * r / d) + 2
        if s >= n:  # the whole period: every column once
            return np.broadcast_to(np.arange(n), (len(x), n))
        i0 = np.floor((np.asarray(x) - r) / d).astype(np.int64)
        return (i0[:, None] + np.arange(s)[None, :]) % n

    def query(self, x, y, hx: float, hy: float) -> tuple[np.ndarray, np.ndarray]:
        rows = []
        for lv in self.levels:
            if lv["used"]:
                ix, iy = self._axis(lv, x, hx, 0), self._axis(lv, y, hy, 1)
                rows.append((lv["offset"] + ix[:, :, None] * lv["n"][1] + iy[:, None, :]).reshape(len(ix), -1))
        if not rows:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        rows = np.concatenate(rows, axis=1) if len(rows) > 1 else rows[0]
        ent = self.data[rows].reshape(rows.shape[0], -1)
        k, s = np.nonzero(ent >= 0)
        return k, ent[k, s]
