"""Many panels from a CSV file on Dask: bad rows reported per row, the same numbers as the serial path,
nothing lost when a worker dies, nothing recomputed on a rerun. A real LocalCluster with 2 worker
processes, not a mock."""

from __future__ import annotations

import os
import signal

import numpy as np
import pytest

from paintjax.inverse import fit_panel, fit_panels, read_panels, read_results

CSV = """id,L15,L25,L45,L75,L110,sd45
a,143.3,107.2,58.6,37.2,32.1,
b,129.0,106.1,67.7,43.7,36.2,0.5
c,147,122,74,37,34,
d,150,120,,38,33,
bad-text,140,abc,60,35,30,
bad-range,140,110,600,35,30,
"""
SETTINGS = dict(forward="tracer-emulator-wide", free=("shape", "scale", "sigma", "tau"), n_starts=2, seed=3)


@pytest.fixture(scope="module")
def client():
    distributed = pytest.importorskip("distributed")
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)
    c = distributed.Client(cluster)
    yield c
    c.close()
    cluster.close()


def test_bad_rows_are_reported_per_row(tmp_path):
    path = tmp_path / "p.csv"
    path.write_text("id,L15,L25,L45,L75,L110,sd15\nx,1,2,3,4,5,\nx,1,2,3,4,5,\n,1,2,3,4,5,\ny,1,nan,3,4,5,\nz,1,2,,,,\nw,1,2,3,4,5,0\n")
    panels, bad = read_panels(path)
    assert [p["id"] for p in panels] == ["x"]
    errors = {b["row"]: b["error"] for b in bad}
    assert "duplicate id 'x'" in errors[2] and errors[3] == "no id" and "L25 must be finite" in errors[4]
    assert "needs L* at 3 or more" in errors[5] and "sd15 must be > 0" in errors[6]
    (tmp_path / "q.csv").write_text("id,L-15,L15\na,1,2\n")
    with pytest.raises(ValueError, match=r"\['L-15'\] are not modelled"):
        read_panels(tmp_path / "q.csv")
    with pytest.raises(ValueError, match="is a folder"):
        read_panels(tmp_path)


def test_batch_on_two_workers_matches_serial_survives_a_killed_worker_and_resumes(tmp_path, client):
    data = tmp_path / "panels.csv"
    data.write_text(CSV)
    out = tmp_path / "results.csv"
    killed = []

    def kill_one_worker(row, n, total):  # after the first result, one worker process dies mid-batch (SIGKILL)
        if not killed:
            pid = sorted(client.run(os.getpid).items())[0][1]
            os.kill(pid, signal.SIGKILL)
            killed.append(pid)

    rows = fit_panels(data, out, client=client, on_result=kill_one_worker, **SETTINGS)
    assert killed
    by_id = {r["id"]: r for r in rows}
    assert [r["id"] for r in rows] == ["a", "b", "c", "d", "bad-text", "bad-range"]
    assert all(by_id[i]["status"] == "ok" for i in "abcd")
    assert "L25 must be a number" in by_id["bad-text"]["error"] and "L45 must lie in" in by_id["bad-range"]["error"]
    # the same numbers as the serial path, panel by panel
    panels, _ = read_panels(data)
    for p in panels:
        serial = fit_panel(p, SETTINGS["forward"], SETTINGS["free"], SETTINGS["n_starts"], SETTINGS["seed"])
        for name in ("shape", "scale", "sigma", "tau", "chi2"):
            np.testing.assert_allclose(by_id[p["id"]][name], serial[name], rtol=1e-6, err_msg=f"{p['id']} {name}")
    assert by_id["d"]["dof"] == 0  # four angles, four free parameters: the missing 45° is left out, not invented
    # a rerun recomputes nothing and keeps every row
    stored = read_results(out)
    calls = []
    again = fit_panels(data, out, client=client, on_result=lambda *a: calls.append(a), **SETTINGS)
    assert calls == [] and [r["id"] for r in again] == [r["id"] for r in stored]
    assert read_results(out) == stored
