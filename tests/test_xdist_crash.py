"""The suite's xdist scheduler (`tests/_xdist_crash.py`): a worker that dies mid-file costs at most the
test it died on, not the run. Checked on a throw-away suite in which one test kills its worker once
and another every time."""

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

pytest.importorskip("xdist")


def _suite(folder: Path) -> None:
    (folder / "test_1_crash.py").write_text(textwrap.dedent("""
        import os, signal
        from pathlib import Path
        def test_before(): pass
        def test_dies_once():
            mark = Path(__file__).with_name("died")
            if not mark.exists():
                mark.touch()
                os.kill(os.getpid(), signal.SIGSEGV)
        def test_dies_always(): os.kill(os.getpid(), signal.SIGSEGV)
        def test_after(): pass
    """))
    for name in ("test_2_plain.py", "test_3_plain.py"):
        (folder / name).write_text("def test_one(): pass\ndef test_two(): pass\n")


def _run(folder: Path, workers: int, timeout: float):
    env = {"PYTHONPATH": str(Path(__file__).parent), "PATH": "/usr/bin:/bin"}
    return subprocess.run([sys.executable, "-m", "pytest", "-n", str(workers), "--dist", "loadfile", "-p", "_xdist_crash",
                           "-p", "no:cacheprovider", "-q", "-o", "faulthandler_timeout=0", str(folder)],
                          cwd=folder, env=env, capture_output=True, text=True, timeout=timeout)


@pytest.mark.parametrize("workers", [1, 2])
def test_a_test_whose_worker_dies_runs_once_more_and_the_rest_still_run(tmp_path, workers):
    """The test that killed its worker once passes on the second run; the one that kills it every time fails
    after two; the summary names both deaths; every other test runs once."""
    _suite(tmp_path)
    done = _run(tmp_path, workers, timeout=180)
    out = done.stdout + done.stderr
    assert "1 failed, 7 passed" in out, out
    assert "crashed while running 'test_1_crash.py::test_dies_always'" in out, out
    died = [line.split()[-1] for line in out.splitlines() if line.startswith("a worker died running")]
    assert died == ["test_1_crash.py::test_dies_once", "test_1_crash.py::test_dies_always", "test_1_crash.py::test_dies_always"], out
    assert done.returncode == 1

