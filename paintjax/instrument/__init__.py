"""The virtual multi-angle spectrophotometer and the analytic single-scatter model.

In: illumination and aspecular angles, reflectance factors or spectra. Out: MA98-style
`Geometry` objects (directions in air and refracted into the coat), CIE 1976 L*, the flop index,
and the analytic single-scatter ("specular microfacet") model of a hiding platelet layer with its
hot spot, which the tracer is checked against and the inverse layer uses as a fast forward map.
"""

from ._geometry import (
    ASPECULAR_15,
    ASPECULAR_45,
    STANDARD_ASPECULAR,
    Geometry,
    custom_geometry,
    hemisphere_quadrature,
    ma98_geometry,
    mirror_tilt_deg,
    refract_into_coat,
)
from ._hot_spot import HotSpot, boolean_escape_monte_carlo
from ._lightness import (
    flop_index,
    lightness,
    lightness_np,
    lightness_to_reflectance_factor,
    reflectance_factor_to_lightness,
    spectral_lightness,
    spectral_to_xyz,
    spectral_weights,
)
from ._single_scatter import microfacet_lightness, microfacet_reflectance_factor, single_scatter_brdf

__all__ = [
    "ASPECULAR_15",
    "ASPECULAR_45",
    "STANDARD_ASPECULAR",
    "Geometry",
    "custom_geometry",
    "hemisphere_quadrature",
    "ma98_geometry",
    "mirror_tilt_deg",
    "refract_into_coat",
    "HotSpot",
    "boolean_escape_monte_carlo",
    "flop_index",
    "lightness",
    "lightness_np",
    "lightness_to_reflectance_factor",
    "reflectance_factor_to_lightness",
    "spectral_lightness",
    "spectral_to_xyz",
    "spectral_weights",
    "microfacet_lightness",
    "microfacet_reflectance_factor",
    "single_scatter_brdf",
]
