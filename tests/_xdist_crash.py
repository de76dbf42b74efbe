"""A file-grouped xdist scheduler that survives a worker that dies.

pytest-xdist 3.8's `LoadFileScheduling` (what `make test` runs, `--dist loadfile`) mishandles a worker
that dies mid-file (a native crash in a compiled library, the OOM killer):

- it puts every file the dead worker had ever been given back on the queue, finished ones included,
  so a replacement worker may be sent a unit with nothing left to run and waits for it forever;
- it leaves the test the worker died on pending, so the replacement runs it again (and dies again
  when the crash is deterministic);
- a replacement handed the last unit is never told that no more work will come, so it waits for a
  second test before it runs the first (pytest-xdist issues 784, 1323 and 1327).

The whole run then hangs until something outside kills it, and the report never names the test.
`CrashSafeLoadFileScheduling` gives a dead worker's unfinished tests back to the queue and shuts a
worker down once the queue is empty. The test a worker died on runs once more, on a fresh worker
(the death may come from what earlier tests left in that process): if its worker dies again it is
reported failed ("worker crashed while running ..."); either way it is listed in `CRASHED` and the run's
summary names it. Every other test still runs. This module is a pytest plugin (its two hooks below):
`tests/conftest.py` takes them in, and any other suite can load it with `-p _xdist_crash`.
"""

from __future__ import annotations

import pytest
from xdist.scheduler import LoadFileScheduling

#: The tests whose worker died while running them, in order (a test twice when it died twice).
CRASHED: list[str] = []


def fits_this_xdist() -> bool:
    """Whether the installed xdist's file scheduler has the internals this one builds on (xdist 3.5–3.8)."""
    return all(hasattr(LoadFileScheduling, name) for name in ("_pending_of", "_reschedule", "_assign_work_unit", "remove_node"))


class CrashSafeLoadFileScheduling(LoadFileScheduling):
    """`--dist loadfile` whose recovery from a dead worker does not hang and runs the fatal test at most twice."""

    def remove_node(self, node) -> str | None:
        """Forget `node`; when it died with tests pending, requeue those of its files that are unfinished
        (first in line) and return the id of the test it died on when that test has now died twice."""
        workload = self.assigned_work.pop(node)
        if not self._pending_of(workload):
            return None
        crashitem = next(nodeid for unit in workload.values() for nodeid, done in unit.items() if not done)
        again = crashitem not in CRASHED
        CRASHED.append(crashitem)
        for scope, unit in workload.items():
            if crashitem in unit and not again:
                unit[crashitem] = True
            if not all(unit.values()):
                self.workqueue[scope] = unit
                self.workqueue.move_to_end(scope, last=False)
        for other in self.assigned_work:
            self._reschedule(other)
        return None if again else crashitem

    def _reschedule(self, node) -> None:
        """As xdist's, and a worker that has just been given the last unit is told to finish."""
        super()._reschedule(node)
        if not self.workqueue and not node.shutting_down:
            node.shutdown()


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """This scheduler for `--dist loadfile` (None, xdist's own, otherwise or when the installed xdist lacks the
    internals it builds on; tests/test_xdist_crash.py then fails)."""
    if config.getvalue("dist") != "loadfile" or not fits_this_xdist():
        return None
    return CrashSafeLoadFileScheduling(config, log)


def pytest_terminal_summary(terminalreporter) -> None:
    """A line per test whose worker died."""
    if CRASHED:
        terminalreporter.section("workers that died")
        for nodeid in CRASHED:
            terminalreporter.line(f"a worker died running {nodeid}")
