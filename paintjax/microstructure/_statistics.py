"""Statistics of a platelet array: residual overlaps, the realised tilt law (KS), PVC, and cross-sections."""

from __future__ import annotations

import numpy as np

from ._array import PlateletArray, _as_tilt, _tilt_cdf_np
from ._grid import UniformGrid, build_grid, candidate_pairs, platelet_boxes
from ._overlap import periodic_overlap


def overlapping_pairs(array: PlateletArray, test: str = "sat", grid: UniformGrid | None = None) -> np.ndarray:
    """(P, 2) pairs i < j of overlapping platelets (periodic images included), via the grid.

    Arguments:
        array: the platelets.
        test: "sat" (exact boxes) or "midplane" (the original study's Möller test).
        grid: a non-overflowing `UniformGrid` of the array; built if None.
    """
    if test not in ("sat", "midplane"):
        raise ValueError(f"test must be 'sat' or 'midplane', got {test!r}")
    grid = build_grid(array) if grid is None else grid
    pairs = candidate_pairs(grid)
    if pairs.size == 0:
        return pairs
    c, R, e = platelet_boxes(array)
    i, j = pairs[:, 0], pairs[:, 1]
    hit = periodic_overlap(c[i], R[i], e[i], c[j], R[j], e[j], array.tile, test)
    return pairs[hit]


def _tilt_deg_np(array: PlateletArray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(np.asarray(array.normals, dtype=float)[:, 2], -1.0, 1.0)))


def tilt_ks(array: PlateletArray, tilt) -> tuple[float, float]:
    """Kolmogorov–Smirnov statistic and p-value of the array's tilts against the gamma law."""
    from scipy import stats

    tilt = _as_tilt(tilt)
    td = _tilt_deg_np(array)
    res = stats.kstest(td, lambda x: _tilt_cdf_np(tilt, x))
    return float(res.statistic), float(res.pvalue)


def array_statistics(array: PlateletArray, tilt=None, grid: UniformGrid | None = None) -> dict:
    """Statistics of an array: count, achieved PVC, residual overlaps (both tests), tilt KS.

    Arguments:
        array: the platelets.
        tilt: the gamma law the tilts should follow (for the KS statistic); None skips it.
        grid: a non-overflowing grid of the array (built if None).

    Returns:
        dict with count, pvc, overlaps_exact, overlaps_midplane, tilt_ks, tilt_ks_pvalue,
        tilt_mean_deg, width_d10/d50/d90, tile, basecoat_thickness.
    """
    grid = build_grid(array) if grid is None else grid
    w = np.asarray(array.widths, dtype=float)
    td = _tilt_deg_np(array)
    out = {
        "count": array.count,
        "pvc": float(np.sum(w**2) * array.thickness / array.tile_volume()),
        "overlaps_exact": int(overlapping_pairs(array, "sat", grid).shape[0]),
        "overlaps_midplane": int(overlapping_pairs(array, "midplane", grid).shape[0]),
        "tilt_ks": None,
        "tilt_ks_pvalue": None,
        "tilt_mean_deg": float(td.mean()) if td.size else float("nan"),
        "width_d10": float(np.quantile(w, 0.1)),
        "width_d50": float(np.quantile(w, 0.5)),
        "width_d90": float(np.quantile(w, 0.9)),
        "tile": list(array.tile),
        "basecoat_thickness": array.basecoat_thickness,
    }
    if tilt is not None:
        out["tilt_ks"], out["tilt_ks_pvalue"] = tilt_ks(array, tilt)
    return out


def cross_section(array: PlateletArray, y: float) -> list[np.ndarray]:
    """Polygons (M_k, 2) in (x, z) where the plane y = const cuts the platelet boxes.

    Each platelet's periodic image nearest to the plane is cut; x may fall outside [0, Lx)
    (draw with shifts of ±Lx to wrap). Platelets the plane misses give no polygon.
    """
    c, R, e = platelet_boxes(array)
    Ly = array.tile[1]
    cy = c[:, 1] - Ly * np.round((c[:, 1] - y) / Ly)
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
    corners = c[:, None, :] + np.einsum("ck,nk,nkx->ncx", signs, e, R)
    corners[:, :, 1] += (cy - c[:, 1])[:, None]
    edges = [(a, b) for a in range(8) for b in range(a + 1, 8) if np.sum(signs[a] != signs[b]) == 1]
    polys = []
    for k in np.flatnonzero(np.abs(cy - y) < np.sum(e * np.abs(R[:, :, 1]), axis=1)):
        pts = []
        for a, b in edges:
            pa, pb = corners[k, a], corners[k, b]
            da, db = pa[1] - y, pb[1] - y
            if da * db < 0:
                s = da / (da - db)
                pts.append(pa + s * (pb - pa))
        if len(pts) >= 3:
            p = np.asarray(pts)[:, [0, 2]]
            m = p.mean(axis=0)
            ang = np.arctan2((p[:, 1] - m[1]), (p[:, 0] - m[0]))
            polys.append(p[np.argsort(ang)])
    return polys
