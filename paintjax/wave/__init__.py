"""Full-wave scattering by rough platelet profiles: the scalar-wave boundary-integral solver.

In: rough 1-D profiles (synthesised Gaussian or exponential ones, or a measured line scan),
wavelength, the binder and metal indices. Out: in-plane scattering lobes σ(θ_i, θ_s) per
polarisation, with the incoherent part's control-variate estimate, the unbiased coherent part
(`_coherent.py`) and their standard errors; closed forms (perturbation theory, Kirchhoff) to
check them against. The solver's kernels (`channels`, `layer_operators`, `solve_batch`, …) are
public for benchmarks and independent checks.
"""

from ._beam import incident_field, incident_power, max_incidence_deg
from ._closed_forms import kirchhoff_coherent_fraction, kirchhoff_sigma, spm_sigma, spm_sigma_realisation
from ._coherent import coherent_estimate, control_variate_mean, expected_control_amplitude, expected_control_power
from ._hankel import hankel0, hankel01, hankel1
from ._profiles import (
    CORRELATIONS,
    LineScan,
    Profiles,
    grid,
    load_line_scan,
    process_line_scan,
    profile_statistics,
    profiles_from_heights,
    synthesize_profiles,
)
from ._solver import (
    WaveLobes,
    band_width,
    channels,
    default_spacing,
    flat_profiles,
    layer_operators,
    profile_averaged_lobes,
    quadrature_points,
    scattering_amplitudes,
    solve_batch,
    solve_profiles,
    surface_fields,
)

__all__ = [
    "kirchhoff_coherent_fraction",
    "kirchhoff_sigma",
    "spm_sigma",
    "spm_sigma_realisation",
    "coherent_estimate",
    "control_variate_mean",
    "expected_control_amplitude",
    "expected_control_power",
    "hankel0",
    "hankel01",
    "hankel1",
    "CORRELATIONS",
    "grid",
    "LineScan",
    "Profiles",
    "load_line_scan",
    "process_line_scan",
    "profile_statistics",
    "profiles_from_heights",
    "synthesize_profiles",
    "WaveLobes",
    "band_width",
    "channels",
    "incident_field",
    "incident_power",
    "layer_operators",
    "quadrature_points",
    "solve_batch",
    "default_spacing",
    "flat_profiles",
    "max_incidence_deg",
    "profile_averaged_lobes",
    "scattering_amplitudes",
    "solve_profiles",
    "surface_fields",
]
