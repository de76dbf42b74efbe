"""One validation layer: each parameter's valid range declared once, checked before any work.

A library module declares its entry points' ranges as `Range`s keyed by the API argument
(`paintjax.wave._checks.LOBE_RANGES`); the entry point checks its arguments with `check_args` first,
and a CLI sub-command checks the same ranges under its flags (`paintjax.cli._common.check_flags`),
so a message reads "--wavelength must lie in [0.2, 12] µm, got 15" from the shell and
"wavelength_um must lie in [0.2, 12] µm, got 15" from Python.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Mapping


@dataclasses.dataclass(frozen=True)
class Range:
    """A closed, open or half-open interval of valid values (None: unbounded on that side).

    Attributes:
        lo, hi: the ends; lo_open, hi_open: whether an end is excluded.
        unit: printed after the interval (e.g. "µm"); integer: whole numbers only.
        why: printed after the unit in parentheses (e.g. "Lorentz–Drude validity").
    """

    lo: float | None = None
    hi: float | None = None
    unit: str = ""
    lo_open: bool = False
    hi_open: bool = False
    integer: bool = False
    why: str = ""

    def describe(self) -> str:
        """The interval as text: "[0.2, 12] µm", "(0, 10] µm", "> 0", "an integer ≥ 1"."""
        if self.lo is not None and self.hi is not None:
            text = f"{'(' if self.lo_open else '['}{self.lo}, {self.hi}{')' if self.hi_open else ']'}"
            text = f"{'an integer' if self.integer else 'lie'} in {text}"
        elif self.lo is not None:
            text = f"{'an integer' if self.integer else 'a number'} {'>' if self.lo_open else '≥'} {self.lo}"
        elif self.hi is not None:
            text = f"{'an integer' if self.integer else 'a number'} {'<' if self.hi_open else '≤'} {self.hi}"
        else:
            text = "an integer" if self.integer else "a finite number"
        return text + (f" {self.unit}" if self.unit else "") + (f" ({self.why})" if self.why else "")

    def contains(self, v: float) -> bool:
        lo_ok = self.lo is None or (v > self.lo if self.lo_open else v >= self.lo)
        hi_ok = self.hi is None or (v < self.hi if self.hi_open else v <= self.hi)
        return math.isfinite(v) and lo_ok and hi_ok

    def check(self, name: str, value):
        """`value` as a float (an int if `integer`), or a ValueError "NAME must lie in [a, b] unit, got X"."""
        text = self.describe()
        verb = "must " if text.startswith("lie") else "must be "
        if isinstance(value, bool) or (self.integer and not _is_integral(value)):
            raise ValueError(f"{name} {verb}{text}, got {value!r}")
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"{name} {verb}{text}, got {value!r}") from None
        if not self.contains(v):
            raise ValueError(f"{name} {verb}{text}, got {value!r}")
        return int(v) if self.integer else v


#: A random seed: a whole number ≥ 0 (the ranges of every entry point that takes one).
SEED = Range(0, None, integer=True)


def _is_integral(value) -> bool:
    return isinstance(value, numbers.Integral) or (isinstance(value, float) and value.is_integer())


def check_args(values: Mapping[str, object], ranges: Mapping[str, Range], names: Mapping[str, str] | None = None,
               optional=None) -> dict:
    """Check every value against its range, in the order of `ranges`; None is left to its default (all names, or those in `optional`).

    Arguments:
        values: argument name → value. ranges: argument name → `Range` (names without a value are skipped).
        names: argument name → the name a message uses (e.g. the CLI flag); default the argument's name.
        optional: the names that may be None (default: all, as for CLI options left out).

    Returns:
        argument name → the checked value (float, or int for integer ranges), for those given.
    """
    names = names or {}
    out = {}
    for k, r in ranges.items():
        v = values.get(k)
        if v is None and optional is not None and k not in optional:
            r.check(names.get(k, k), v)  # required: a ValueError naming it
        if v is not None:  # a list (e.g. of angles) is checked value by value
            out[k] = [r.check(names.get(k, k), x) for x in v] if isinstance(v, (list, tuple)) else r.check(names.get(k, k), v)
    return out
