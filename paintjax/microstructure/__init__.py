"""Platelet microstructure: size and tilt laws, non-overlapping platelet arrays, the uniform grid.

In: a sample's statistics (PVC, size law, gamma tilt law, film thickness) and a seed. Out: a
`PlateletArray` of square aluminium prisms in a laterally periodic basecoat tile, its statistics
(overlaps, realised tilt law) and the fixed-capacity `UniformGrid` the tracer walks.
"""

from ._array import (
    MAX_PVC,
    GenerationLog,
    PlateletArray,
    PlateletFitError,
    boolean_platelet_array,
    generate_platelet_array,
    platelet_array_for_sample,
)
from ._grid import UniformGrid, build_grid, candidate_pairs, check_grid_matches
from ._overlap import midplane_overlap, obb_overlap, periodic_overlap, tri_tri_intersect
from ._plots import plot_cross_section, plot_tilt_histogram
from ._sizes import LogNormalSizes, PolynomialCDFSizes, SizeDistribution, TabulatedCDFSizes, default_sizes
from ._statistics import array_statistics, cross_section, overlapping_pairs, tilt_ks
from ._tilt import GammaTilt

__all__ = [
    "PlateletFitError",
    "MAX_PVC",
    "GenerationLog",
    "PlateletArray",
    "boolean_platelet_array",
    "generate_platelet_array",
    "platelet_array_for_sample",
    "UniformGrid",
    "build_grid",
    "candidate_pairs",
    "check_grid_matches",
    "midplane_overlap",
    "obb_overlap",
    "periodic_overlap",
    "tri_tri_intersect",
    "plot_cross_section",
    "plot_tilt_histogram",
    "LogNormalSizes",
    "PolynomialCDFSizes",
    "SizeDistribution",
    "TabulatedCDFSizes",
    "default_sizes",
    "array_statistics",
    "cross_section",
    "overlapping_pairs",
    "tilt_ks",
    "GammaTilt",
]
