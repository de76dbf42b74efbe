"""paintjax: a hybrid ray-wave appearance model of metallic paint, in JAX.

Float64 is *not* enabled on import. The CLI, the experiments and the tests enable it
(`jax.config.update("jax_enable_x64", True)`); library users who need it do the same.
"""

from ._aluminium import RAKIC1995_550NM, aluminium_index, aluminium_permittivity, aluminium_reflectance
from ._brdf import AbstractPlateletBRDF, LambertianBRDF, MirrorBRDF, reflect
from ._beckmann import AbstractGaussianMetalBRDF, AbstractLobeBRDF, BeckmannBRDF
from ._brdf_table import (
    BRDFTableGrid,
    InPlaneLobes,
    TabulatedBRDF,
    kirchhoff_lobes,
    platelet_brdf_grid,
    platelet_brdf_table,
    platelet_table_arrays,
    table_from_lobes,
)
from ._cache import cache_key, cached_arrays, default_cache_dir
from ._he_torrance import HeTorranceBRDF
from ._instrument import (
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
from ._hot_spot import HotSpot
from ._microfacet import microfacet_lightness, microfacet_reflectance_factor, single_scatter_brdf
from ._grid import UniformGrid, build_grid, candidate_pairs, check_grid_matches
from ._microstructure import (
    GenerationLog,
    PlateletArray,
    array_statistics,
    boolean_platelet_array,
    cross_section,
    generate_platelet_array,
    overlapping_pairs,
    platelet_array_for_sample,
    tilt_ks,
)
from ._optics import coat_internal_diffuse_reflectance, fresnel_conductor, fresnel_dielectric, snell_cos
from ._overlap import midplane_overlap, obb_overlap, periodic_overlap, tri_tri_intersect
from ._samples import Measured, Sample, load_sample, sample_names
from ._sizes import LogNormalSizes, PolynomialCDFSizes, SizeDistribution, TabulatedCDFSizes, default_sizes
from ._tilt import GammaTilt
from ._tracer import LEDGER_KEYS, MAX_CREATED_ENERGY, EnergyCreationError, TraceResult, TracerOptions, lightness_with_se, trace
from ._spectral import SPECTRAL_NODES_NM, combine_spectral, lab_from_xyz, spectral_node_weights

from ._hankel import hankel0, hankel01, hankel1
from ._profiles import (
    LineScan,
    Profiles,
    load_line_scan,
    process_line_scan,
    profile_statistics,
    profiles_from_heights,
    synthesize_profiles,
)
from ._wave import WaveLobes, flat_profiles, max_incidence_deg, profile_averaged_lobes, solve_profiles
from ._wave_approx import kirchhoff_coherent_fraction, kirchhoff_sigma, spm_sigma, spm_sigma_realisation

from ._design import DesignResult, design_to_target
from ._fit import FitResult, fit_least_squares
from ._forward import (
    AnalyticForward,
    CallableForward,
    Emulator,
    ForwardModel,
    build_emulator,
    emulator_check,
    make_forward,
    register_forward,
)
from ._parameters import PARAMETERS, Parameter, ParameterSpec, make_spec
from ._posterior import LogPosterior, PosteriorResult, corner_plot, sample_posterior, save_netcdf
from ._tracer_forward import TRACER_BOX, TracerLStar, TracerSettings, tracer_emulator
from ._tracer_forward import register as _register_tracer_forward

_register_tracer_forward()  # makes --forward tracer-emulator available

__version__ = "0.1.0"
