"""paintjax: a hybrid ray-wave appearance model of metallic paint, in JAX.

The subpackages follow the light: `optics` → `wave` → `brdf` → `microstructure` → `instrument` →
`tracer` → `appearance` (→ `render`, the optional Mitsuba 3 extra) and `inverse`; `simulate`
assembles a paint from them, and `cli` is the console script.
This namespace re-exports each stage's main names; the subpackages hold the rest of their public
API.

Float64 is *not* enabled on import. The CLI, the experiments and the tests enable it
(`jax.config.update("jax_enable_x64", True)`); library users who need it do the same.
"""

from . import appearance, brdf, instrument, inverse, microstructure, optics, tracer, wave
from ._cache import cache_key, cached_arrays, cached_json, default_cache_dir, enable_compilation_cache
from ._io import atomic_savefig, atomic_savez, atomic_write_json, to_jsonable

# the forward pipeline: a paint's inputs → five-angle L*
from ._pipeline import array_overrides, platelet_brdf, sample_array, simulate

# published reference samples
from ._samples import Measured, Sample, load_sample, sample_names

# the paint's gonio BRDF and the car-paint model renderers use (`paintjax.render` draws it in Mitsuba 3)
from .appearance import CarPaintBRDF, CarPaintFit, GonioTable, car_paint_for_sample, fit_car_paint, gonio_table, load_car_paint

# platelet BRDFs
from .brdf import (
    AbstractGaussianMetalBRDF,
    AbstractLobeBRDF,
    AbstractPlateletBRDF,
    BeckmannBRDF,
    BRDFTableGrid,
    HeTorranceBRDF,
    InPlaneLobes,
    LambertianBRDF,
    MirrorBRDF,
    TabulatedBRDF,
    kirchhoff_lobes,
    platelet_brdf_grid,
    platelet_brdf_table,
    platelet_table_arrays,
    reflect,
    table_from_lobes,
)

# instrument, lightness and the analytic single-scatter model
from .instrument import (
    ASPECULAR_15,
    ASPECULAR_45,
    STANDARD_ASPECULAR,
    Geometry,
    HotSpot,
    custom_geometry,
    flop_index,
    hemisphere_quadrature,
    lightness,
    lightness_np,
    lightness_to_reflectance_factor,
    ma98_geometry,
    microfacet_lightness,
    microfacet_reflectance_factor,
    mirror_tilt_deg,
    reflectance_factor_to_lightness,
    refract_into_coat,
    single_scatter_brdf,
    spectral_lightness,
    spectral_to_xyz,
    spectral_weights,
)

# inverse layer: forward maps, fits, posteriors, designs
from .inverse import (
    PARAMETERS,
    TRACER_BOX,
    AnalyticForward,
    CallableForward,
    DesignResult,
    Emulator,
    FitResult,
    ForwardModel,
    LogPosterior,
    Parameter,
    ParameterSpec,
    PosteriorResult,
    TracerLStar,
    TracerSettings,
    build_emulator,
    corner_plot,
    design_to_target,
    emulator_check,
    fit_least_squares,
    make_forward,
    make_spec,
    predictive_plot,
    register_forward,
    sample_posterior,
    save_netcdf,
    tracer_emulator,
)
from .inverse._tracer_forward import register as _register_tracer_forward

# platelet microstructure
from .microstructure import (
    GammaTilt,
    GenerationLog,
    LogNormalSizes,
    PlateletArray,
    PolynomialCDFSizes,
    SizeDistribution,
    TabulatedCDFSizes,
    UniformGrid,
    array_statistics,
    boolean_platelet_array,
    build_grid,
    candidate_pairs,
    check_grid_matches,
    cross_section,
    default_sizes,
    generate_platelet_array,
    midplane_overlap,
    obb_overlap,
    overlapping_pairs,
    periodic_overlap,
    platelet_array_for_sample,
    tilt_ks,
    tri_tri_intersect,
)

# optics
from .optics import (
    RAKIC1995_550NM,
    aluminium_index,
    aluminium_permittivity,
    aluminium_reflectance,
    coat_internal_diffuse_reflectance,
    fresnel_conductor,
    fresnel_dielectric,
    snell_cos,
)

# the ray tracer
from .tracer import (
    LEDGER_KEYS,
    MAX_CREATED_ENERGY,
    SPECTRAL_NODES_NM,
    EnergyCreationError,
    TraceResult,
    TracerOptions,
    combine_spectral,
    lab_from_xyz,
    lightness_with_se,
    spectral_node_weights,
    trace,
)

# full-wave scattering by rough profiles
from .wave import (
    LineScan,
    Profiles,
    WaveLobes,
    flat_profiles,
    hankel0,
    hankel01,
    hankel1,
    kirchhoff_coherent_fraction,
    kirchhoff_sigma,
    load_line_scan,
    max_incidence_deg,
    process_line_scan,
    profile_averaged_lobes,
    profile_statistics,
    profiles_from_heights,
    solve_profiles,
    spm_sigma,
    spm_sigma_realisation,
    synthesize_profiles,
)

_register_tracer_forward()  # makes --forward tracer-emulator available

__version__ = "0.1.0"
