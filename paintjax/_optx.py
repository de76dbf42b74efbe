"""Short messages for Optimistix result codes (shared by the inverse fits and the car-paint fit)."""

from __future__ import annotations

import optimistix as optx

_SHORT = {1: "max_steps reached", 7: "max_steps reached", 8: "diverged", 9: "non-finite values"}


def result_message(code: int) -> str:
    """One line for an Optimistix `RESULTS` code (0: "successful")."""
    if code == 0:
        return "successful"
    if code in _SHORT:
        return _SHORT[code]
    try:
        return str(optx.RESULTS._index_to_message[code]).split("\n")[0] or f"failed (code {code})"
    except Exception:  # pragma: no cover - message lookup is cosmetic
        return f"failed (code {code})"
