"""Progress lines with a time estimate on stderr, for the long host loops (tracer rounds, wave profiles).

A loop owns a `Heartbeat` and calls it with the fraction of its work done; the heartbeat passes
`(fraction, seconds since the loop began)` on to its report at most every `HEARTBEAT_SECONDS`
(the first after that long, so a run shorter than that prints nothing). `print_progress` is the
report the CLI uses: one line on stderr, e.g. "  lobe: 40 % of 2000 profiles solved, 12 s, about 18 s left".
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable

#: Seconds between progress lines (read when a `Heartbeat` is made).
HEARTBEAT_SECONDS = 5.0


def progress_line(label: str, fraction: float, seconds: float, done: str = "done", left: str = "left") -> str:
    """One progress line: percentage done, seconds so far and, once something is done, the estimated time left.

    Arguments:
        label: what runs; fraction: share of the work done in [0, 1]; seconds: time since the work began.
        done, left: the words after the percentage and after the time left.

    Returns:
        The line (indented by two spaces, no newline).
    """
    eta = f", about {seconds * (1.0 / fraction - 1.0):.0f} s {left}" if fraction > 0 else ""
    return f"  {label}: {100 * fraction:.0f} % {done}, {seconds:.0f} s{eta}"


def print_progress(label: str, done: str = "done", left: str = "left") -> Callable[[float, float], None]:
    """A report `(fraction, seconds)` that prints `progress_line` to stderr (flushed)."""

    def report(fraction: float, seconds: float) -> None:
        print(progress_line(label, fraction, seconds, done, left), file=sys.stderr, flush=True)

    return report


class Heartbeat:
    """Calls `report(fraction, seconds)` at most every `interval` seconds (default `HEARTBEAT_SECONDS`).

    Arguments:
        report: called with the fraction passed in and the seconds since the heartbeat was made.
        interval: least seconds between reports, and before the first.
    """

    def __init__(self, report: Callable[[float, float], None], interval: float | None = None):
        self.report = report
        self.interval = HEARTBEAT_SECONDS if interval is None else float(interval)
        self.start = self.last = time.perf_counter()

    def due(self) -> bool:
        """Whether a report is due (for loops where reading the fraction itself costs time)."""
        return time.perf_counter() - self.last >= self.interval

    def __call__(self, fraction: float) -> None:
        """Report `fraction` if a report is due."""
        if self.due():
            self.last = time.perf_counter()
            self.report(float(fraction), self.last - self.start)
