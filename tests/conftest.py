"""Test configuration: the suite runs in float64 on the CPU (documented place that enables x64),
with its own temporary on-disk cache so that it neither reads nor fills the user's cache.

The pytest-xdist workers of one run share that cache (keyed by the run's id): a wave table, platelet
array or XLA compilation that one worker made is read by the other instead of being made twice. Every
test that checks a cache miss uses its own folder (`tmp_path`), and the cache's writes are atomic.
"""

import os
import tempfile
from pathlib import Path

os.environ.setdefault("JAX_PLATFORMS", "cpu")
_RUN = os.environ.get("PYTEST_XDIST_TESTRUNUID")
if _RUN:
    _CACHE = Path(tempfile.gettempdir()) / f"paintjax-test-cache-{_RUN}"
    _CACHE.mkdir(exist_ok=True)
    os.environ["PAINTJAX_CACHE"] = str(_CACHE)
else:
    os.environ["PAINTJAX_CACHE"] = tempfile.mkdtemp(prefix="paintjax-test-cache-")

# every process of the run (tests that give a subprocess its own PAINTJAX_CACHE too) shares one XLA cache
os.environ["JAX_COMPILATION_CACHE_DIR"] = str(Path(os.environ["PAINTJAX_CACHE"]) / "jax")

import jax  # noqa: E402

from paintjax import enable_compilation_cache  # noqa: E402

jax.config.update("jax_enable_x64", True)
enable_compilation_cache()  # compilations persist in the shared test cache

#: The test modules that take minutes on the 2-core CPU, longest first (measured in `make test` on
#: 2026-12-02: about 490, 240 and 160 s of a 1600 s total). They are collected first and the Makefile
#: runs `-n 2 --dist loadfile --no-loadscope-reorder`, so each worker starts on a long module and the
#: short ones fill in behind (longest-processing-time-first). xdist's default order (modules by
#: number of tests) moves with every test added: 854, 925 and 928 s on three runs of nearly the same
#: suite that day, 853 and 885 s this way. test_platelet_brdf_truth.py (2026-12-03) takes about 4 min,
#: test_appearance.py (2026-12-04, a traced gonio table) about 2.5 min.
LONG_MODULES_FIRST = ("test_tracer.py", "test_tracer_single_scatter.py", "test_commands.py", "test_platelet_brdf_truth.py", "test_panels.py",
                      "test_appearance.py")


def pytest_collection_modifyitems(session, config, items):
    rank = {name: k for k, name in enumerate(LONG_MODULES_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable: the rest keep their order


# xdist's scheduler for `--dist loadfile`, made safe against a worker that dies, and the summary line for each
# death (`tests/_xdist_crash.py`); without xdist the suite runs in one process and needs neither
try:
    from _xdist_crash import pytest_terminal_summary, pytest_xdist_make_scheduler  # noqa: F401
except ImportError:
    pass
