"""The inverse layer: from measured five-angle L* to microstructure parameters, and to designs.

In: measured L* (with the instrument's uncertainty), a forward map θ → L* (the analytic model, the
tracer, or a Gaussian-process emulator of the tracer), a prior box. Out: least-squares fits
(Optimistix), emcee posteriors with diagnostics, and designs that reach a target curve; and
measurement models of the inputs themselves (a virtual profilometer for σ, τ and a virtual
orientation measurement for the tilt law), which say what the published inputs imply.
"""

from ._analytic import AnalyticForward
from ._chain import MAX_RHAT, MAX_STEPS, check_chain
from ._design import DesignResult, design_to_target
from ._emulator import Emulator, build_emulator, emulator_check, fit_emulator
from ._error_model import EmulatorError, RunToRun, fit_emulator_error, fit_run_to_run
from ._fit import FitResult, fit_least_squares
from ._forward import CallableForward, ForwardModel
from ._measured_inputs import MeasuredInputs, posterior_predictive_check
from ._panels import fit_panel, fit_panels, read_panels, read_results
from ._parameters import PARAMETERS, Parameter, ParameterSpec, make_spec
from ._posterior import LogPosterior, PosteriorResult, sample_posterior
from ._posterior_output import corner_plot, predictive_plot, save_netcdf
from ._profilometer import (
    SIGMA_DEFINITIONS,
    Profilometer,
    ReadingModel,
    build_reading_model,
    profile_roughness,
    smoothed_gaussian_statistics,
)
from ._registry import make_forward, register_forward
from ._tilt_measurement import apparent_tilt_deg, fit_gamma, gamma_fit_moments, gamma_fit_sd, platelets_for_sd, tilt_fit_distribution
from ._tracer_emulator import (
    WIDE_TRACER_BOX,
    WIDE_TRACER_SETTINGS,
    direct_tracer,
    independent_check_design,
    tracer_emulator,
    tracer_info,
    wide_tracer_emulator,
)
from ._tracer_forward import TRACER_BOX, TRACER_PARAMETERS, TracerLStar, TracerSettings, independent_runs
from ._verdict import DISAGREE_P, panel_posteriors

__all__ = [
    "WIDE_TRACER_BOX",
    "WIDE_TRACER_SETTINGS",
    "wide_tracer_emulator",
    "MeasuredInputs",
    "posterior_predictive_check",
    "predictive_plot",
    "SIGMA_DEFINITIONS",
    "Profilometer",
    "ReadingModel",
    "build_reading_model",
    "profile_roughness",
    "smoothed_gaussian_statistics",
    "apparent_tilt_deg",
    "fit_gamma",
    "gamma_fit_moments",
    "gamma_fit_sd",
    "platelets_for_sd",
    "tilt_fit_distribution",
    "AnalyticForward",
    "DesignResult",
    "design_to_target",
    "Emulator",
    "EmulatorError",
    "fit_emulator_error",
    "RunToRun",
    "fit_run_to_run",
    "build_emulator",
    "emulator_check",
    "fit_emulator",
    "FitResult",
    "fit_least_squares",
    "CallableForward",
    "ForwardModel",
    "PARAMETERS",
    "Parameter",
    "ParameterSpec",
    "make_spec",
    "LogPosterior",
    "PosteriorResult",
    "corner_plot",
    "sample_posterior",
    "check_chain",
    "MAX_RHAT",
    "MAX_STEPS",
    "save_netcdf",
    "make_forward",
    "fit_panels",
    "fit_panel",
    "read_panels",
    "read_results",
    "panel_posteriors",
    "DISAGREE_P",
    "register_forward",
    "TRACER_BOX",
    "TRACER_PARAMETERS",
    "TracerLStar",
    "TracerSettings",
    "direct_tracer",
    "independent_check_design",
    "independent_runs",
    "tracer_emulator",
    "tracer_info",
]
