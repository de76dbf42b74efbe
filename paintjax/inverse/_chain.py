"""The emcee chain: its size limits, its HDF5 storage (what may be resumed) and its convergence diagnostics."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .._io import nearest_existing


def burn_thin(tau, it: int) -> tuple[int, int]:
    """Burn-in (2 max τ, at most half the chain) and thinning (τ_min / 2) of a chain of `it` steps."""
    finite = bool(np.all(np.isfinite(tau)))
    tmax = float(np.max(tau)) if finite else float(it)
    return min(int(2 * tmax), it // 2), (max(1, int(0.5 * np.min(tau))) if finite else 1)


def chain_diagnostics(chain) -> tuple[np.ndarray, np.ndarray]:
    """ArviZ rank-normalised split R-hat and bulk ESS per parameter of an emcee chain, walkers as chains.

    Arguments:
        chain: (steps, walkers, p) draws (after burn-in and thinning).

    Returns:
        (rhat, ess_bulk), each of shape (p,); NaN where a parameter has too few draws.
    """
    import arviz as az

    chain = np.asarray(chain, float)
    if chain.ndim != 3 or chain.shape[0] < 4:
        return np.full(chain.shape[-1], np.nan), np.full(chain.shape[-1], np.nan)
    per = np.moveaxis(chain, 2, 0).swapaxes(1, 2)  # (p, walkers, steps)
    return (np.array([float(az.rhat(x)) for x in per]), np.array([float(az.ess(x, method="bulk")) for x in per]))


#: The stopping rule's defaults: the largest split R-hat of any parameter (walkers as chains) and the most steps.
MAX_RHAT = 1.01
MAX_STEPS = 60000

#: Most emcee walkers (memory: the chain holds walkers × steps × parameters; the default is 32).
MAX_WALKERS = 4096


def check_walkers(walkers: int, parameters: int) -> None:
    """An emcee ensemble needs an even number of walkers, at least 2 per sampled parameter, at most `MAX_WALKERS` (ValueError)."""
    if walkers < 2 * parameters or walkers % 2 or walkers > MAX_WALKERS:
        raise ValueError(f"walkers must be even, >= 2 × {parameters} sampled parameters = {2 * parameters} and <= {MAX_WALKERS}, got {walkers}")


def check_chain(backend_path, meta: str, *, resume: bool = True, overwrite: bool = False) -> bool:
    """Whether the chain file `backend_path` will be resumed; a stored chain is never silently replaced.

    Arguments:
        backend_path: the HDF5 chain file (absent: a new chain).
        meta: the run's description (`LogPosterior.description`).
        resume: continue a stored chain of the same description.
        overwrite: allow replacing a stored chain that is not resumed.

    Returns:
        True when the stored chain continues, False when a new one starts.

    Raises:
        ValueError: the path is a folder, unwritable or not an emcee chain, or it holds steps of a
            chain that is not resumed (another run, or resume=False) and overwrite is False.
    """
    import emcee

    path = Path(backend_path)
    if not path.exists():
        probe = nearest_existing(path.parent)
        if not probe.is_dir() or not os.access(probe, os.W_OK | os.X_OK):
            raise ValueError(f"backend_path {str(path)!r} cannot be written: {str(probe)!r} is not a writable folder")
        return False
    if path.is_dir():
        raise ValueError(f"backend_path must be a file for the chain, but {str(path)!r} is a folder")
    try:
        stored = emcee.backends.HDFBackend(str(path), read_only=True).iteration
    except (OSError, KeyError, AttributeError, ValueError) as err:
        raise ValueError(f"backend_path {str(path)!r} is not a readable emcee chain ({type(err).__name__}); it is left as it is: "
                         "move or delete it, or give a new path") from None
    if stored == 0:
        return False
    same = read_meta(path) == meta
    if same and resume:
        return True
    if overwrite:
        return False
    why = "was sampled for other data, model, parameters, priors or walkers" if not same else "is not resumed (resume=False)"
    raise ValueError(f"backend_path {str(path)!r} holds {stored} steps of a chain that {why}; it is kept. Give a new path, "
                     "or overwrite=True to replace it")


def write_meta(path: Path, meta: str) -> None:
    import h5py

    with h5py.File(path, "a") as f:
        f["mcmc"].attrs["paintjax_meta"] = meta


def read_meta(path: Path):
    import h5py

    try:
        with h5py.File(path, "r") as f:
            return f["mcmc"].attrs.get("paintjax_meta")
    except (OSError, KeyError):
        return None
