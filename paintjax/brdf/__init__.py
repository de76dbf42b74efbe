"""Platelet BRDFs: what one aluminium platelet face does with the light that reaches it.

In: in-plane lobes from `paintjax.wave` (or the Kirchhoff closed form). Out: 3-D platelet BRDFs in
the platelet's frame that the tracer evaluates and samples: mirror and Lambertian references,
the analytic Kirchhoff/Beckmann and He–Torrance BRDFs, and the wave-based `TabulatedBRDF` built
from the lobes (cached on disk), on its own or interpolated over a (σ, τ) grid.
"""

from ._analytic import AbstractGaussianMetalBRDF, AbstractLobeBRDF, BeckmannBRDF, coherent_lobe_width, hemisphere_directions
from ._grid import BRDFTableGrid, platelet_brdf_grid
from ._he_torrance import HeTorranceBRDF
from ._in_plane import DEFAULT_INCIDENCE_DEG, DEFAULT_NUM_PROFILES, InPlaneLobes, kirchhoff_lobes, leontovich_reflectance
from ._platelet import AbstractPlateletBRDF, LambertianBRDF, MirrorBRDF, reflect
from ._table import TABLE_VERSION, TabulatedBRDF, platelet_brdf_table, platelet_table_arrays, table_from_lobes

__all__ = [
    "AbstractGaussianMetalBRDF",
    "AbstractLobeBRDF",
    "BeckmannBRDF",
    "coherent_lobe_width",
    "hemisphere_directions",
    "BRDFTableGrid",
    "platelet_brdf_grid",
    "HeTorranceBRDF",
    "DEFAULT_INCIDENCE_DEG",
    "DEFAULT_NUM_PROFILES",
    "InPlaneLobes",
    "kirchhoff_lobes",
    "leontovich_reflectance",
    "AbstractPlateletBRDF",
    "LambertianBRDF",
    "MirrorBRDF",
    "reflect",
    "TABLE_VERSION",
    "TabulatedBRDF",
    "platelet_brdf_table",
    "platelet_table_arrays",
    "table_from_lobes",
]
