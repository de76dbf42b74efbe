"""The inverse layer: from measured five-angle L* to microstructure parameters, and to designs.

In: measured L* (with the instrument's uncertainty), a forward map θ → L* (the analytic model, the
tracer, or a Gaussian-process emulator of the tracer), a prior box. Out: least-squares fits
(Optimistix), emcee posteriors with diagnostics, and designs that reach a target curve.
"""

from ._analytic import AnalyticForward
from ._design import DesignResult, design_to_target
from ._emulator import Emulator, build_emulator, emulator_check, fit_emulator
from ._fit import FitResult, fit_least_squares
from ._forward import CallableForward, ForwardModel
from ._parameters import PARAMETERS, Parameter, ParameterSpec, make_spec
from ._posterior import LogPosterior, PosteriorResult, corner_plot, sample_posterior, save_netcdf
from ._registry import make_forward, register_forward
from ._tracer_forward import TRACER_BOX, TRACER_PARAMETERS, TracerLStar, TracerSettings, direct_tracer, tracer_emulator, tracer_info

__all__ = [
    "AnalyticForward",
    "DesignResult",
    "design_to_target",
    "Emulator",
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
    "save_netcdf",
    "make_forward",
    "register_forward",
    "TRACER_BOX",
    "TRACER_PARAMETERS",
    "TracerLStar",
    "TracerSettings",
    "direct_tracer",
    "tracer_emulator",
    "tracer_info",
]
