"""paintjax: a hybrid ray-wave appearance model of metallic paint, in JAX.

Float64 is *not* enabled on import. The CLI, the experiments and the tests enable it
(`jax.config.update("jax_enable_x64", True)`); library users who need it do the same.
"""

from ._aluminium import RAKIC1995_550NM, aluminium_index, aluminium_permittivity, aluminium_reflectance
from ._brdf import AbstractPlateletBRDF, MirrorBRDF, reflect
from ._instrument import (
    ASPECULAR_15,
    ASPECULAR_45,
    STANDARD_ASPECULAR,
    Geometry,
    custom_geometry,
    ma98_geometry,
    mirror_tilt_deg,
    refract_into_coat,
)
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
from ._microfacet import microfacet_lightness, microfacet_reflectance_factor, single_scatter_brdf
from ._optics import coat_internal_diffuse_reflectance, fresnel_conductor, fresnel_dielectric, snell_cos
from ._samples import Measured, Sample, load_sample, sample_names
from ._tilt import GammaTilt

__version__ = "0.1.0"
