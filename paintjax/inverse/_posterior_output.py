"""Outputs of a posterior: ArviZ InferenceData as NetCDF, a corner plot and the posterior-predictive L* against the measurement."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path

from .._io import atomic_path, atomic_savefig
from ._posterior import PosteriorResult


def save_netcdf(idata, path: str | os.PathLike) -> Path:
    """Write ArviZ InferenceData to NetCDF atomically (temporary file in the same folder + rename)."""
    with atomic_path(path) as tmp:
        idata.to_netcdf(str(tmp))
    return Path(path)


def corner_plot(result: PosteriorResult, *, names: Sequence[str] | None = None, reference: Mapping[str, float] | None = None,
                path: str | os.PathLike | None = None, title: str | None = None):
    """Corner plot (the `corner` package): marginal histograms with their 5 / 50 / 95 % quantiles on the
    diagonal, 2-D histograms with 1σ/2σ contours below.

    Arguments:
        result: a `PosteriorResult`.
        names: parameters to show (default: all sampled, plus ``mean_tilt``).
        reference: optional values to mark (e.g. independently measured ones), by name.
        path: if given, the PNG is written there atomically.
        title: figure title.

    Returns:
        The matplotlib figure.
    """
    import corner
    import numpy as np

    names = list(names or (list(result.names) + (["mean_tilt"] if "shape" in result.names and "scale" in result.names else [])))
    data = np.column_stack([result.draws(n) for n in names])
    reference = dict(reference or {})
    truths = [reference.get(n) for n in names] if any(n in reference for n in names) else None
    fig = corner.corner(data, labels=names, quantiles=[0.05, 0.5, 0.95], show_titles=True, title_fmt=".3g", truths=truths,
                        truth_color="C3", levels=(1 - np.exp(-0.5), 1 - np.exp(-2.0)), plot_datapoints=False)
    if title:
        fig.suptitle(title, y=1.02)
    if path is not None:
        atomic_savefig(fig, path)
    return fig


def predictive_plot(angles: Sequence[float], measured: Sequence[float], *, measured_sd: Sequence[float] | None = None,
                    model_angles: Sequence[float] | None = None, fit: Sequence[float] | None = None,
                    band: tuple[Sequence[float], Sequence[float]] | None = None, path: str | os.PathLike | None = None,
                    title: str | None = None):
    """Measured L* against the model, per aspecular angle: the measurement (± 2 SD where given), the
    least-squares curve and the 90 % posterior-predictive band (replicated data).

    Arguments:
        angles, measured: the measured points (aspecular angles [deg], L*).
        measured_sd: the measurement's SD per angle, drawn as ± 2 SD bars (None: no bars).
        model_angles: the angles of `fit` and `band` (default: `angles`).
        fit: the least-squares L* (None: not drawn).
        band: (5 %, 95 %) posterior-predictive quantiles (None: not drawn).
        path: if given, the PNG is written there atomically.
        title: figure title.

    Returns:
        The matplotlib figure.
    """
    import matplotlib.pyplot as plt
    import numpy as np

    a = np.asarray(angles, float)
    m = a if model_angles is None else np.asarray(model_angles, float)
    fig, ax = plt.subplots(figsize=(4.6, 3.4))
    if band is not None:
        ax.fill_between(m, band[0], band[1], color="C0", alpha=0.25, label="posterior predictive 90 %")
    if fit is not None:
        ax.plot(m, fit, "-", color="C0", label="least squares")
    yerr = None if measured_sd is None else 2 * np.asarray(measured_sd, float)
    ax.errorbar(a, np.asarray(measured, float), yerr=yerr, fmt="o", color="k", ms=4, capsize=2,
                label="measured" + ("" if yerr is None else " ± 2 SD"))
    ax.set_xlabel("aspecular angle [°]")
    ax.set_ylabel("L*")
    if title:
        ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    if path is not None:
        atomic_savefig(fig, path)
    return fig
