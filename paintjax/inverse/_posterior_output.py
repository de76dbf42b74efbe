"""Outputs of a posterior: ArviZ InferenceData as NetCDF, and a corner plot."""

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
