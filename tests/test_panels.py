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
    (tmp_path / "q.csv").write_text("id,L80,L15\na,1,2\n")  # 80° is an angle of 15° illumination
    with pytest.raises(ValueError, match=r"\['L80'\] are not modelled"):
        read_panels(tmp_path / "q.csv")
    with pytest.raises(ValueError, match="is a folder"):
        read_panels(tmp_path)


def test_minus_15_enters_the_fit_of_a_panel_that_gives_it(tmp_path):
    """`L-15` (and `sd-15`): a panel with L* at −15° is fitted at six angles, its −15° residual in the χ²
    (one more dof); a panel without it is fitted at the standard five; a row with −15° and two other angles
    is a panel; the analytic model gives −15° too; a forward model without −15° refuses the file by name."""
    from paintjax import ASPECULAR_45
    from paintjax.inverse import make_forward
    from paintjax.inverse._panels import panel_figure

    path = tmp_path / "p.csv"
    path.write_text("id,L-15,L15,L25,L45,L75,L110,sd-15\nfive,,143.3,107.2,58.6,37.2,32.1,\nsix,150,143.3,107.2,58.6,37.2,32.1,0.5\n"
                    "low,100,143.3,107.2,58.6,37.2,32.1,0.5\nthree,150,143.3,,58.6,,,\n")
    panels, bad = read_panels(path)
    assert not bad and [p["id"] for p in panels] == ["five", "six", "low", "three"]
    assert panels[1]["sd"][0] == 0.5 and panels[0]["sd"][0] == 0.3 and np.isnan(panels[3]["L_star"][[2, 4, 5]]).all()
    five, six, low = (fit_panel(p, **SETTINGS) for p in panels[:3])
    assert five["dof"] == 1 and "L-15_fit" not in five and six["dof"] == 2 and np.isfinite(six["L-15_fit"])
    # the −15° residual enters: the fit follows it (the fitted −15° drops by more than 5 L*), and 100 L* is far from any
    # of the model's curves: the χ² rises by more than 25, a miss of over 5 SD at −15° (by 44 with the shipped emulator)
    print("chi2", six["chi2"], low["chi2"], "L-15 fitted", six["L-15_fit"], low["L-15_fit"])
    assert low["chi2"] > six["chi2"] + 25 and low["L-15_fit"] < six["L-15_fit"] - 5 and low["shape"] != six["shape"]
    panel_figure(panels[1], six, tmp_path / "six.png")
    assert (tmp_path / "six.png").stat().st_size > 0
    analytic = make_forward("analytic", angles=ASPECULAR_45)
    theta = np.array([[2.3, 2.2, 0.05, 0.64, 0.0]])
    np.testing.assert_array_equal(np.asarray(analytic(theta))[:, 1:], np.asarray(make_forward("analytic")(theta)))
    with pytest.raises(ValueError, match=r"\['L-15'\] hold L\* at -15°, which the forward model 'tracer-emulator' does not give"):
        fit_panels(path, tmp_path / "out.csv", **(SETTINGS | {"forward": "tracer-emulator"}))


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


def test_known_inputs_posterior_netcdf_and_figures_of_a_batch(tmp_path, client):
    """Known-input columns become Gaussian terms (the row's dof counts them); with a posterior each row
    carries quantiles, R-hat, bulk ESS and the predictive p-value; the table goes to CSV and NetCDF
    with the same numbers, and each panel gets a figure. A known input of a parameter that is not free
    is an error for the whole file; a known input without its SD is a row error."""
    xr = pytest.importorskip("xarray")
    data = tmp_path / "panels.csv"
    data.write_text("id,L15,L25,L45,L75,L110,sigma,sigma_sd,tau,tau_sd\n"
                    "s1,143.3,107.2,58.6,37.2,32.1,0.051,0.01,0.64,0.11\n"
                    "odd/id,129.0,106.1,67.7,43.7,36.2,,,,\n"
                    "half,129.0,106.1,67.7,43.7,36.2,0.05,,,\n")
    panels, bad = read_panels(data)
    assert panels[0]["known"] == {"sigma": (0.051, 0.01), "tau": (0.64, 0.11)} and panels[1]["known"] == {}
    assert "known input sigma needs both sigma and sigma_sd" in bad[0]["error"]
    post = {"walkers": 12, "max_steps": 300, "min_ess": 100.0}
    out = tmp_path / "res" / "fit_panels.csv"
    rows = fit_panels(data, out, client=client, posterior=post, **SETTINGS)
    by_id = {r["id"]: r for r in rows}
    s1, odd = by_id["s1"], by_id["odd/id"]
    assert s1["dof"] == 5 + 2 - 4 and odd["dof"] == 5 - 4
    for r in (s1, odd):
        assert r["sigma_q05"] < r["sigma_q50"] < r["sigma_q95"] and 0 < r["predictive_p"] <= 1 and 0 <= r["predictive_p_se"] < 0.5
        assert r["rhat_max"] > 0.9 and r["ess_bulk_min"] > 0 and r["steps"] == 300
    assert np.isfinite(s1["sigma_known_z"]) and "sigma_known_z" not in odd
    serial = fit_panel(panels[0], SETTINGS["forward"], SETTINGS["free"], SETTINGS["n_starts"], SETTINGS["seed"], post)
    assert serial["sigma_q50"] == pytest.approx(s1["sigma_q50"], rel=1e-9)
    ds = xr.open_dataset(out.with_suffix(".nc"), engine="h5netcdf")
    assert list(ds["panel"].values) == ["s1", "odd/id", "half"]
    np.testing.assert_allclose(ds["sigma_q50"].values[:2], [s1["sigma_q50"], odd["sigma_q50"]], rtol=1e-12)
    assert ds["status"].values[2] == "error" and np.isnan(ds["sigma_q50"].values[2])
    ds.close()
    figures = sorted(p.name for p in (out.parent / "figures").glob("*.png"))
    assert len(figures) == 2 and "s1.png" in figures and all("/" not in f for f in figures)
    (tmp_path / "bad.csv").write_text("id,L15,L25,L45,pvc,pvc_sd\na,140,110,60,0.2,0.02\n")
    with pytest.raises(ValueError, match=r"data columns \['pvc'\] are known inputs of parameters that are not free"):
        fit_panels(tmp_path / "bad.csv", tmp_path / "bad_out.csv", client=client, **SETTINGS)


def test_cli_batch_on_the_shipped_example(tmp_path, capsys):
    """`paintjax fit --data example` fits the 3-panel file shipped with the package on a local cluster
    and writes the CSV, the NetCDF and a figure per panel; a rerun does no work."""
    pytest.importorskip("distributed")
    from paintjax.cli._main import main

    argv = ["fit", "--data", "example", "--out", str(tmp_path), "--starts", "2", "--json"]
    assert main(argv) == 0
    import json

    report = json.loads(capsys.readouterr().out)
    assert [r["id"] for r in report["panels"]] == ["silver1", "silver2", "trial-3"]
    assert all(r["status"] == "ok" for r in report["panels"])
    assert (tmp_path / "fit_panels.nc").stat().st_size > 0 and len(list((tmp_path / "figures").glob("*.png"))) == 3
    assert report["panels"][1]["dof"] == 5 + 2 - 4  # silver2 carries its published σ, τ as known inputs
    assert main(argv) == 0


def test_coverage_replicates_run_as_dask_tasks_with_the_serial_numbers(tmp_path):
    """`experiments/coverage.py --workers 2`: the noise-free curves and every dataset's fit and posterior
    are tasks on a local cluster, and the study's numbers are those of the serial run (draws, noise and
    seeds do not depend on where or in which order the tasks run). Each run keeps every dataset's row in its
    output folder's `parts/` (an interrupted study resumes from them), so the Dask run computes its own;
    `--interim` then reads the stored rows back without running a fit."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    pytest.importorskip("distributed")
    script = Path(__file__).parents[1] / "experiments" / "coverage.py"
    common = ["--datasets", "2", "--steps", "60", "--walkers", "8", "--starts", "2", "--seed", "11", "--free", "shape,scale,sigma"]
    for name, extra in (("serial", []), ("dask", ["--workers", "2"])):
        env = os.environ | {"PAINTJAX_CACHE": str(tmp_path / f"cache-{name}")}
        subprocess.run([sys.executable, str(script), *common, *extra, "--out", str(tmp_path / name)], check=True, capture_output=True,
                       timeout=600, env=env)
        assert len(list((tmp_path / name / "parts").glob("coverage-row-*.npz"))) == 2
    serial, spread = (json.loads((tmp_path / name / "summary.json").read_text()) for name in ("serial", "dask"))
    assert len(serial["rows"]) == len(spread["rows"]) == 2
    for a, b in zip(serial["rows"], spread["rows"]):
        assert a["truth"] == b["truth"]
        np.testing.assert_allclose(a["L_star"], b["L_star"], rtol=1e-12)
        np.testing.assert_allclose([a["lsq"][n] for n in a["lsq"]], [b["lsq"][n] for n in b["lsq"]], rtol=1e-6)
        np.testing.assert_allclose(list(a["pit"].values()), list(b["pit"].values()), atol=1e-9)
    assert serial["coverage"] == spread["coverage"]
    # `--interim` runs nothing: it tabulates the stored rows, here all of them, as the summary did
    subprocess.run([sys.executable, str(script), *common, "--interim", "--out", str(tmp_path / "serial")], check=True, capture_output=True,
                   timeout=600, env=os.environ | {"PAINTJAX_CACHE": str(tmp_path / "cache-interim")})
    interim = json.loads((tmp_path / "serial" / "interim.json").read_text())
    assert interim["datasets_done"] == 2 and interim["coverage"] == serial["coverage"]
    assert [r["pit"] for r in interim["rows"]] == [r["pit"] for r in serial["rows"]]


def test_coverage_studies_of_different_seeds_pool_into_one(tmp_path):
    """`experiments/coverage.py --combine`: the rows of studies with different seeds are pooled and the coverage
    and rank-histogram tests recomputed over all of them; studies of another model or the same seed are refused."""
    import importlib.util
    import json
    from pathlib import Path

    spec = importlib.util.spec_from_file_location("coverage_study", Path(__file__).parents[1] / "experiments" / "coverage.py")
    study = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(study)
    rng = np.random.default_rng(0)

    def write(name, seed, n, **over):
        rows = [{"truth": {"shape": 2.0}, "pit": {"shape": float(rng.uniform())},
                 "inside": {"shape@0.68": bool(k % 3), "shape@0.95": bool(k % 10)}} for k in range(n)]
        summary = {"forward": "tracer-emulator-wide", "forward_model": "m", "free": ["shape"], "walkers": 16, "steps": 2000,
                   "prior_box": {"shape": [1.2, 12.0]}, "seed": seed, "datasets": n, "rows": rows, "skipped_prior_draws": [],
                   "coverage": {"0.68": {}, "0.95": {}}} | over
        (tmp_path / name).mkdir()
        (tmp_path / name / "summary.json").write_text(json.dumps(summary))
        return rows

    a, b = write("a", 1, 30), write("b", 2, 20)
    pooled = study.combine([tmp_path / "a", tmp_path / "b"], tmp_path / "pooled")
    assert pooled["datasets"] == 50 and [p["seed"] for p in pooled["pooled_from"]] == [1, 2]
    for lv in ("0.68", "0.95"):
        assert pooled["coverage"][lv]["hits"]["shape"] == sum(r["inside"][f"shape@{lv}"] for r in a + b)
    assert json.loads((tmp_path / "pooled" / "summary.json").read_text())["coverage"] == pooled["coverage"]
    assert (tmp_path / "pooled" / "coverage.png").stat().st_size > 0
    write("same_seed", 1, 5)
    with pytest.raises(SystemExit, match="distinct seeds"):
        study.combine([tmp_path / "a", tmp_path / "same_seed"], tmp_path / "x")
    write("other_model", 3, 5, steps=1000)
    with pytest.raises(SystemExit, match="steps differ"):
        study.combine([tmp_path / "a", tmp_path / "other_model"], tmp_path / "x")


def test_two_samplers_on_the_same_panels_are_compared_panel_by_panel(tmp_path, monkeypatch):
    """`experiments/posterior_reproducibility.py --against`: the PIT change per parameter and the truths each study's
    intervals gain or lose; studies of other panels are refused. `coverage.py --combine` refuses studies of other samplers
    (a study without a recorded sampler used the small ball)."""
    import importlib
    import json
    from pathlib import Path

    monkeypatch.syspath_prepend(str(Path(__file__).parents[1] / "experiments"))
    repro, study = importlib.import_module("posterior_reproducibility"), importlib.import_module("coverage")
    names = ("shape", "scale", "sigma", "tau")
    rng = np.random.default_rng(1)

    def rows(pit, inside):
        return [{"truth": {n: 1.0 + k for n in names}, "L_star": [float(k)] * 5, "pit": {n: p for n in names},
                 "inside": {f"{n}@{lv}": bool(i) for n in names for lv in ("0.68", "0.95")}} for k, (p, i) in enumerate(zip(pit, inside))]

    pit_a, pit_b = rng.uniform(size=6), rng.uniform(size=6)
    a, b = rows(pit_a, [1, 1, 0, 0, 1, 1]), rows(pit_b, [1, 0, 1, 0, 1, 1])
    table = repro.compare_studies(a, b)
    d = pit_a - pit_b
    assert table["tau"]["pit_change_rms"] == pytest.approx(np.sqrt(np.mean(d**2)))
    assert table["tau"]["largest_at_panel"] == int(np.argmax(np.abs(d)))
    assert table["sigma"]["inside@0.68"] == {"both": 3, "gained": 1, "lost": 1, "this": 4, "other": 4}
    with pytest.raises(SystemExit, match="do not hold the same panels"):
        repro.compare_studies(a, rows(pit_b, [1] * 5 + [0])[::-1])

    def write(name, seed, **over):
        summary = {"forward": "tracer-emulator-wide", "forward_model": "m", "free": list(names), "walkers": 16, "steps": 2000,
                   "prior_box": {}, "seed": seed, "datasets": 6, "rows": a, "skipped_prior_draws": [],
                   "coverage": {"0.68": {}, "0.95": {}}} | over
        (tmp_path / name).mkdir()
        (tmp_path / name / "summary.json").write_text(json.dumps(summary))

    write("ball", 1)
    write("dispersed", 2, sampler=study.SAMPLER)
    write("ball_recorded", 3, sampler=study.SAMPLER_BEFORE)
    with pytest.raises(SystemExit, match="sampler differ"):
        study.combine([tmp_path / "ball", tmp_path / "dispersed"], tmp_path / "x")
    assert study.combine([tmp_path / "ball", tmp_path / "ball_recorded"], tmp_path / "y")["sampler"] == study.SAMPLER_BEFORE
    with pytest.raises(ValueError, match=r"sampler settings \['walkers'\] are not known"):
        study.sampler_settings({"walkers": 32})


def test_coverage_study_measures_the_emulators_miss_at_the_truths():
    """`emulator_miss`: the forward model against each row's noise-free tracer curve. A forward that is the
    tracer curve plus a known offset and noise gives that offset as the mean miss (within 3 stated SE), the RMS
    of the miss, and a rank correlation of +1 between a PIT that rises with the miss and the miss."""
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location("coverage_study", Path(__file__).parents[1] / "experiments" / "coverage.py")
    study = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(study)
    rng = np.random.default_rng(3)
    n, offset = 400, np.array([0.0, 0.5, 1.5, -1.0, 2.0])
    truths = rng.uniform(1.0, 2.0, (n, 4))
    curve = lambda t: np.stack([10.0 * t[:, 0] + k * t[:, 1] for k in range(5)], axis=1)  # noqa: E731
    noise = rng.normal(0.0, 1.0, (n, 5))

    class Shifted:
        aspecular_deg = (15.0, 25.0, 45.0, 75.0, 110.0)

        def __call__(self, theta):
            return curve(np.asarray(theta)) + offset + noise

    rows = [{"truth": dict(zip(study.ALL, t)), "L_star_clean": curve(t[None])[0].tolist(), "pit": {"shape": float(noise[i, 2])}}
            for i, t in enumerate(truths)]
    miss = study.emulator_miss(Shifted(), rows, ("shape",))
    assert miss["angles"] == list(Shifted.aspecular_deg)
    assert np.all(np.abs(np.array(miss["mean"]) - offset) <= 3 * np.array(miss["mean_se"])), miss
    np.testing.assert_allclose(miss["mean_se"], noise.std(0, ddof=1) / np.sqrt(n), rtol=1e-9)
    np.testing.assert_allclose(miss["rms"], np.sqrt(np.mean((offset + noise) ** 2, 0)), rtol=1e-9)
    assert miss["pit_spearman"]["shape"][2] == pytest.approx(1.0) and abs(miss["pit_spearman"]["shape"][0]) < 0.2
    # a miss that grows with a truth: rank correlation 1 with that truth, none with the others
    grows = [{**row, "L_star_clean": (np.asarray(row["L_star_clean"]) - 30.0 * row["truth"]["scale"]).tolist()} for row in rows]
    steep = study.emulator_miss(Shifted(), grows, ("shape",))["truth_spearman"]
    assert min(steep["scale"]) > 0.9 and max(abs(c) for c in steep["sigma"]) < 0.2, steep


def test_likelihood_variants_of_the_calibration_diagnosis():
    """`experiments/coverage_variants.py`: the fixed-width variant evaluates the wrapped model's residual law at
    its θ0 whatever θ it is given (and that law does vary with θ), the bias-corrected one shifts the L* by its
    offset and keeps the law; both keep the model's names, angles and error."""
    import importlib.util
    import sys
    from pathlib import Path

    import jax.numpy as jnp

    from paintjax.inverse import EmulatorError, ForwardModel
    from paintjax.inverse._analytic import AnalyticForward

    spec = importlib.util.spec_from_file_location("coverage_variants", Path(__file__).parents[1] / "experiments" / "coverage_variants.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # its equinox module needs a registered home
    spec.loader.exec_module(mod)
    mirror = AnalyticForward(rough=False)
    law = EmulatorError(np.ones(5), np.array([0.5, -1.0, 2.0]), 3.0)

    class Regional(ForwardModel):  # the mirror model with a residual law whose width varies with θ
        parameter_names = mirror.parameter_names
        aspecular_deg = mirror.aspecular_deg

        def evaluate(self, theta):
            return mirror.evaluate(theta)

        def fingerprint(self):
            return "regional mirror"

        def residual_log_density(self, r, var, theta, have=None):
            return law.residual_log_density(r, var, theta, have)

    base = Regional()
    rng = np.random.default_rng(0)
    theta = jnp.asarray(np.c_[rng.uniform(1.5, 3.0, 8), rng.uniform(1.0, 2.5, 8), rng.uniform(0.0, 0.3, 8)])
    theta0 = jnp.asarray([[2.6, 1.9, 0.15]])
    r, var = jnp.asarray(rng.normal(0.0, 2.0, (8, 5))), jnp.full((8, 5), 0.09)
    fixed = mod._Variant(base, jnp.zeros(5), theta0)
    at0 = base.residual_log_density(r, var, jnp.broadcast_to(theta0, theta.shape))
    np.testing.assert_allclose(fixed.residual_log_density(r, var, theta), at0, rtol=1e-12)
    assert not np.allclose(base.residual_log_density(r, var, theta), at0, rtol=1e-3)
    np.testing.assert_allclose(fixed(theta), base(theta), rtol=1e-12)
    shifted = mod._Variant(base, jnp.arange(5.0))
    np.testing.assert_allclose(shifted(theta), base(theta) - jnp.arange(5.0), rtol=1e-12)
    np.testing.assert_allclose(shifted.residual_log_density(r, var, theta), base.residual_log_density(r, var, theta), rtol=1e-12)
    assert shifted.parameter_names == base.parameter_names and list(shifted.aspecular_deg) == list(base.aspecular_deg)
    assert mod.parse_rows("0-2,5", 10) == [0, 1, 2, 5]
    with pytest.raises(SystemExit, match="--rows"):
        mod.parse_rows("8-12", 10)
