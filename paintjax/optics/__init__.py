"""Optics of flat interfaces and materials: aluminium's index, Fresnel reflectance, the clearcoat.

In: wavelengths, indices, cosines. Out: complex indices, power reflectances and transmittances,
and the clearcoat–air interface (flat or wavy) that the tracer and the analytic model cross.
"""

from ._aluminium import RAKIC1995_550NM, VISIBLE_RANGE_UM, aluminium_index, aluminium_permittivity, aluminium_reflectance
from ._fresnel import coat_internal_diffuse_reflectance, fresnel_conductor, fresnel_dielectric, snell_cos
from ._interface import MAX_WAVINESS_DEG, check_waviness, smith_masking

__all__ = [
    "RAKIC1995_550NM",
    "VISIBLE_RANGE_UM",
    "aluminium_index",
    "aluminium_permittivity",
    "aluminium_reflectance",
    "coat_internal_diffuse_reflectance",
    "fresnel_conductor",
    "fresnel_dielectric",
    "snell_cos",
    "MAX_WAVINESS_DEG",
    "check_waviness",
    "smith_masking",
]
