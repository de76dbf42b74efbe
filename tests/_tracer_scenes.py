"""Shared pieces of the tracer tests: tolerance, coat index, tilt law, coat transmittance, an empty
array and a brute-force reference grid (and the Lambertian BRDF's test name).

The grid follows the UniformGrid contract of ARCHITECTURE.md so the tracer can be validated
independently of the grid module; the arrays are Boolean-model arrays (`boolean_platelet_array`),
not the generator's hard-core arrays.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from paintjax import fresnel_dielectric
from paintjax.brdf._platelet import LambertianBRDF
from paintjax.microstructure._array import boolean_platelet_array

#: Tolerance of every statistical check, in Monte Carlo standard errors (batch means over 32 lane
#: groups): K = 4 gives a false-alarm rate below 1e-4 per comparison.
K = 4.0
N_COAT = 1.5
SILVER1_TILT = (2.29, 2.18)


def coat_transmittance(theta_deg):
    """Unpolarised Fresnel transmittance of the air–coat interface at polar angle θ in air [deg]."""
    return 1.0 - np.asarray(fresnel_dielectric(np.cos(np.deg2rad(theta_deg)), 1.0, N_COAT)[2])


def empty_array(tile=(40.0, 40.0), h_b=20.0, thickness=1.0):
    return boolean_platelet_array(0, 0, tile=tile, basecoat_thickness=h_b, width=1.0, thickness=thickness, margin=0.0)


class HandGrid(eqx.Module):
    cell_platelets: jnp.ndarray
    overflow: jnp.ndarray
    shape: tuple = eqx.field(static=True)
    cell_size: tuple = eqx.field(static=True)


def reference_grid(array, shape, capacity=None) -> HandGrid:
    """Brute-force periodic cell list: every cell that a platelet's bounding box overlaps."""
    nx, ny, nz = shape
    Lx, Ly = array.tile
    h_b = array.basecoat_thickness
    cs = np.array([Lx / nx, Ly / ny, h_b / nz])
    c = np.asarray(array.centers).reshape(-1, 3)
    nrm = np.asarray(array.normals).reshape(-1, 3)
    u = np.asarray(array.axes_u).reshape(-1, 3)
    v = np.cross(nrm, u)
    w = np.asarray(array.widths).reshape(-1)
    ext = np.abs(u) * (w / 2)[:, None] + np.abs(v) * (w / 2)[:, None] + np.abs(nrm) * array.thickness / 2
    lists = [[] for _ in range(nx * ny * nz)]
    for j in range(len(c)):
        lo = np.floor((c[j] - ext[j]) / cs).astype(int)
        hi = np.floor((c[j] + ext[j]) / cs).astype(int)
        for ix in range(lo[0], hi[0] + 1):
            for iy in range(lo[1], hi[1] + 1):
                for iz in range(max(lo[2], 0), min(hi[2], nz - 1) + 1):
                    lists[((ix % nx) * ny + (iy % ny)) * nz + iz].append(j)
    cap = max(1, max(len(x) for x in lists)) if capacity is None else capacity
    table = -np.ones((len(lists), cap), dtype=np.int32)
    for k, x in enumerate(lists):
        x = sorted(set(x))[:cap]
        table[k, : len(x)] = x
    overflow = any(len(set(x)) > cap for x in lists)
    return HandGrid(cell_platelets=jnp.asarray(table), overflow=jnp.asarray(overflow), shape=(nx, ny, nz), cell_size=tuple(float(x) for x in cs))


LambertPlateletBRDF = LambertianBRDF  # the tests' name for the library's reference BRDF
