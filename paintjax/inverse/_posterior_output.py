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
    """Corner plot (matplotlib only): 1-D histograms on the diagonal, 2-D histograms below.

    Arguments:
        result: a `PosteriorResult`.
        names: parameters to show (default: all sampled, plus ``mean_tilt``).
        reference: optional values to mark (e.g. independently measured ones), by name.
        path: if given, the PNG is written there atomically.
        title: figure title.

    Returns:
        The matplotlib figure.
    """
    import matplotlib.pyplot as plt

    names = list(names or (list(result.names) + (["mean_tilt"] if "shape" in result.names and "scale" in result.names else [])))
    k = len(names)
    fig, axes = plt.subplots(k, k, figsize=(1.9 * k + 1, 1.9 * k + 1), squeeze=False)
    data = {n: result.draws(n) for n in names}
    reference = dict(reference or {})
    for i, ni in enumerate(names):
        for j, nj in enumerate(names):
            ax = axes[i, j]
            if j > i:
                ax.axis("off")
                continue
            if i == j:
                ax.hist(data[ni], bins=40, color="0.4", histtype="stepfilled", alpha=0.7)
                for qv in (result.q05.get(ni), result.q95.get(ni)):
                    if qv is not None:
                        ax.axvline(qv, color="k", ls=":", lw=0.8)
                if ni in reference:
                    ax.axvline(reference[ni], color="C3", lw=1.2)
                ax.set_yticks([])
            else:
                ax.hist2d(data[nj], data[ni], bins=35, cmap="Greys")
                if nj in reference and ni in reference:
                    ax.plot(reference[nj], reference[ni], "o", color="C3", ms=4)
            if i == k - 1:
                ax.set_xlabel(nj)
            else:
                ax.set_xticklabels([])
            if j == 0 and i > 0:
                ax.set_ylabel(ni)
            elif j > 0:
                ax.set_yticklabels([])
    if title:
        fig.suptitle(title)
    if path is not None:
        atomic_savefig(fig, path)
    return fig
