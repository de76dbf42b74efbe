"""The observations a fit or posterior takes: L* per angle (which angles hold data), the instrument's
SD per angle, and known inputs (value ± SD of a parameter); each checked, with errors that name them."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np


def check_measured(measured, m: int, name: str = "measured", angles=None) -> np.ndarray:
    """Concrete L* vector of length m with finite values in [−5, 250] (ValueError otherwise).

    Slightly negative values are accepted: Gaussian noise on a dark angle produces them. With
    `angles` (m booleans: which angles hold data) only those are checked; the others come back NaN.
    """
    try:
        y = np.asarray(measured, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be {m} numbers (L* per angle), got {measured!r}") from None
    if y.size != m:
        raise ValueError(f"{name} must have {m} values (one L* per angle), got {y.size}")
    have = check_angles(angles, m)
    if np.any(~np.isfinite(y[have])) or np.any(y[have] < -5) or np.any(y[have] > 250):
        raise ValueError(f"{name} L* values must be finite and lie in [-5, 250], got {y.tolist()}")
    return np.where(have, y, np.nan)


def check_angles(angles, m: int) -> np.ndarray:
    """Which of the m angles hold data: None → all; else m booleans, at least one True (ValueError otherwise)."""
    if angles is None:
        return np.ones(m, bool)
    a = np.asarray(angles)
    if a.shape != (m,) or a.dtype != bool or not a.any():
        raise ValueError(f"angles must be {m} booleans (which angles hold data), at least one True, got {angles!r}")
    return a


def prior_arrays(names: Sequence[str], priors: Mapping[str, tuple[float, float]] | None) -> tuple[np.ndarray, np.ndarray]:
    """(values, 1/sd) per name of the known inputs `priors` ({name: (value, sd)}); 0 weight where none."""
    pv, pw = np.zeros(len(names)), np.zeros(len(names))
    for name, v, sd in known_inputs(priors or {}):
        if name not in names:
            raise ValueError(f"known input {name!r} is not a free parameter of the fit (free: {', '.join(names)})")
        i = list(names).index(name)
        pv[i], pw[i] = v, 1.0 / sd
    return pv, pw


def known_inputs(values: Mapping[str, tuple[float, float]]) -> tuple[tuple[str, float, float], ...]:
    """Known inputs {name: (value, sd)} as sorted (name, value, sd), each a finite value with an sd > 0 (ValueError)."""
    items = []
    for name, vs in dict(values).items():
        try:
            v, sd = (float(t) for t in vs)
        except (TypeError, ValueError):
            raise ValueError(f"known input {name} must be (value, sd), got {vs!r}") from None
        if not (np.isfinite(v) and np.isfinite(sd) and sd > 0):
            raise ValueError(f"known input {name} needs a finite value and an sd > 0, got value {v!r}, sd {sd!r}")
        items.append((str(name), v, sd))
    return tuple(sorted(items))


def check_instrument_sd(instrument_sd, m: int | None = None) -> None:
    """The instrument repeatability: a finite number > 0 [L*], or one per angle (m of them)."""
    try:
        a = np.asarray(instrument_sd, dtype=float)
    except (TypeError, ValueError):
        a = np.asarray(np.nan)
    if a.ndim > 1 or (a.ndim == 1 and m is not None and a.shape != (m,)) or not np.all((a > 0) & np.isfinite(a)) or a.size == 0:
        raise ValueError(f"instrument_sd must be a finite number > 0 [L*], or one per angle, got {instrument_sd!r}")
