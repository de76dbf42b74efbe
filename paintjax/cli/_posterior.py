"""`paintjax posterior`: `paintjax fit --posterior` under its own name — least squares, then the emcee
posterior with its predictive check, for one panel (`--sample`, `--measured`) or many (`--data`)."""

from __future__ import annotations

from ._fit import API_FLAGS, RANGES, add_fit_arguments, run  # noqa: F401  (API_FLAGS, RANGES: the validation layer's names and ranges)


def register(sub) -> None:
    p = sub.add_parser(
        "posterior",
        help="posterior of tilt and roughness from measured L* (the same as fit --posterior)",
        description="Least squares, then an emcee posterior (progress bar, HDF5 chain that resumes) with a "
        "posterior-predictive check; every option of `paintjax fit` applies.",
    )
    add_fit_arguments(p)
    p.set_defaults(func=run, posterior=True)
