"""The `paintjax` console script: JSON round trip, readable table, clear errors."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

import paintjax as pj
from paintjax.cli._main import main


def test_microfacet_json_round_trip(capsys):
    assert main(["microfacet", "--sample", "silver1", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) == {"aspecular_deg", "tilt_probed_deg", "reflectance_factor", "L_star", "flop_index"}
    assert out["aspecular_deg"] == list(pj.STANDARD_ASPECULAR)
    s = pj.load_sample("silver1")
    tilt = pj.GammaTilt(s.tilt_shape.value, s.tilt_scale.value)
    expected = pj.microfacet_reflectance_factor(pj.ma98_geometry(), tilt, hot_spot=pj.HotSpot.for_sample(s))
    np.testing.assert_allclose(out["reflectance_factor"], np.asarray(expected), rtol=1e-12)
    assert main(["microfacet", "--sample", "silver1", "--no-hot-spot", "--json"]) == 0
    independent = json.loads(capsys.readouterr().out)
    np.testing.assert_allclose(independent["reflectance_factor"], np.asarray(pj.microfacet_reflectance_factor(pj.ma98_geometry(), tilt)), rtol=1e-12)
    L = np.asarray(out["L_star"])
    np.testing.assert_allclose(L, pj.lightness_np(100 * np.asarray(out["reflectance_factor"])), atol=1e-9)
    assert out["flop_index"] == pytest.approx(float(pj.flop_index(L[0], L[2], L[4])))


def test_microfacet_without_exit_occlusion(capsys):
    """`--no-exit-occlusion` (no exit attenuation at all) works with the hot-spot default and is brighter."""
    assert main(["microfacet", "--sample", "silver1", "--json"]) == 0
    hot = json.loads(capsys.readouterr().out)
    assert main(["microfacet", "--sample", "silver1", "--no-exit-occlusion", "--json"]) == 0
    clear = json.loads(capsys.readouterr().out)
    s = pj.load_sample("silver1")
    expected = pj.microfacet_reflectance_factor(pj.ma98_geometry(), pj.GammaTilt(s.tilt_shape.value, s.tilt_scale.value), exit_occlusion=False)
    np.testing.assert_allclose(clear["reflectance_factor"], np.asarray(expected), rtol=1e-12)
    assert np.all(np.asarray(clear["reflectance_factor"])[:3] > np.asarray(hot["reflectance_factor"])[:3])


def test_microfacet_overrides_change_the_answer(capsys):
    main(["microfacet", "--sample", "silver1", "--json"])
    base = json.loads(capsys.readouterr().out)
    main(["microfacet", "--sample", "silver1", "--shape", "3.5", "--scale", "3", "--reflectance", "0.5", "--json"])
    other = json.loads(capsys.readouterr().out)
    assert other["L_star"][0] < base["L_star"][0]


def test_readable_table(capsys):
    assert main(["microfacet", "--sample", "silver2"]) == 0
    text = capsys.readouterr().out
    assert "flop index" in text and "4.33°" in text and "129.0" in text


@pytest.mark.parametrize(
    "argv,needle",
    [
        (["microfacet", "--sample", "gold"], "unknown sample"),
        (["microfacet", "--shape", "-2"], "shape"),
        (["microfacet", "--scale", "0"], "scale"),
        (["microfacet", "--reflectance", "1.5"], "reflectance"),
        (["microfacet", "--n", "0.5"], "refractive index"),
        (["table1", "--target-se", "0"], "--target-se must lie in (0.0, 10.0] L*"),
        (["table1", "--max-rays", "0"], "--max-rays must be an integer in [32, 1000000000]"),
        (["table1", "--waviness", "40"], "--waviness must lie in [0.0, 15.0] degrees"),
        (["simulate", "--brdf", "mirror", "--brdf-method", "rotate"], "--brdf-method applies to --brdf wave only"),
        (["simulate", "--brdf", "kirchhoff", "--correlation", "exponential"], "--correlation applies to --brdf wave only"),
        (["simulate", "--rays", "0"], "--rays must be an integer in [32, 1000000000]"),
        (["simulate", "--rays", "16"], "--rays must be an integer in [32, 1000000000]"),
        (["simulate", "--tau", "500"], "--tau must lie in (0.0, 100.0] µm"),
        (["simulate", "--brdf", "kirchhoff", "--tau", "150"], "--tau must lie in (0.0, 100.0] µm"),
        (["gonio", "--tau", "500"], "--tau must lie in (0.0, 100.0] µm"),
        (["brdf", "--tau", "500"], "--tau must lie in (0.0, 100.0] µm"),
        (["simulate", "--platelet-thickness", "0.001", "--pvc", "0.4"], "lower --pvc, or a larger --platelet-thickness or --d50"),
        (["array", "--platelet-thickness", "0.001", "--pvc", "0.4"], "lower --pvc, a smaller --tile, or a larger --platelet-thickness"),
        (["simulate", "--brdf", "mirror", "--sigma", "0.05"], "sigma and tau apply to --brdf wave or kirchhoff only"),
        (["simulate", "--primer-albedo", "2"], "--primer-albedo must lie in [0.0, 1.0]"),
        (["simulate", "--waviness", "30"], "--waviness must lie in [0.0, 15.0] degrees"),
        (["simulate", "--seed", "-1"], "--seed must be an integer ≥ 0"),
        (["simulate", "--shape", "0"], "--shape must be a number > 0.0 (tilt gamma shape)"),
        (["simulate", "--out", "/proc/version/sub"], "--out must be a folder"),
        (["brdf", "--n", "0.5"], "--n must lie in"),
        (["brdf", "--sigma", "-1"], "--sigma"),
        (["lobe", "--wavelength", "1e-6", "--profiles", "1"], "--wavelength must lie in [0.2, 12.0]"),
        (["lobe", "--wavelength", "15"], "--wavelength must lie in [0.2, 12.0]"),
        (["lobe", "--length", "2000", "--profiles", "1"], "--length"),
        (["simulate", "--aspecular=15,15,25"], "--aspecular must list each angle once"),
        (["fit", "--posterior", "--walkers", "1"], "--walkers must be even"),
        (["fit", "--posterior", "--walkers", "13"], "--walkers must be even"),
        (["fit", "--overwrite"], "--overwrite applies to --chain"),
        (["fit", "--posterior", "--chain", "/proc/version/c.h5"], "--chain '/proc/version/c.h5' cannot be written"),
        (["design", "--target", "140,110,60,35,30", "--weights", "0,0,0,0,0"], "weights must be 5 finite non-negative numbers, not all zero"),
        (["simulate", "--rays", "1000000000000", "--brdf", "mirror"], "--rays must be an integer in [32, 1000000000]"),
        (["lobe", "--profile", "/tmp"], "--profile must be a two-column text file, but '/tmp' is a folder"),
        (["lobe", "--profile", "x.csv", "--units", "furlong"], "--units must be one of"),
        (["brdf", "--cache-dir", "/proc/version"], "--cache-dir must be a folder"),
        (["simulate", "--d50", "0"], "--d50 must lie in [1.0, 50.0] µm"),
        (["simulate", "--platelet-thickness", "25"], "--platelet-thickness: the platelets (t = 25 µm) must be thinner"),
        (["simulate", "--pvc", "0.45"], "--pvc must lie in (0.0, 0.4]"),
        (["simulate", "--d50", "80"], "--d50 must lie in [1.0, 50.0] µm"),
        (["simulate", "--thickness", "0.8"], "--thickness: the platelets (t = 1 µm) must be thinner"),
        (["array", "--platelet-thickness", "0", "--no-plots"], "--platelet-thickness must be a number > 0.0 µm"),
        (["simulate", "--sample", "gold"], "unknown sample"),
        (["simulate", "--illumination", "0"], "--illumination must lie in (0.0, 85.0] degrees"),
        (["simulate", "--aspecular", "15,140"], "--aspecular must lie in [-40, 130] for 45° illumination"),
        (["simulate", "--illumination", "15"] + ["--aspecular", "110"], "--aspecular must lie in"),
        (["simulate", "--aspecular", "15,nan"], "--aspecular"),
        (["simulate", "--measured", "140,100"], "--measured must hold 5 finite L* values"),
        (["fit", "--measured", "143,107,inf,37,32"], "--measured"),
        (["fit", "--data", "example", "--inputs", "rq"], "--inputs and --chain apply to one panel"),
        (["fit", "--data", "example", "--posterior", "--walkers", "7"], "--walkers must be even"),
        (["fit", "--no-figures"], "--no-figures applies to --data"),
        (["posterior", "--walkers", "3"], "--walkers must be even"),
        (["posterior", "--walkers", "100000"], "--walkers must be even, >= 2 × the sampled parameters and <= 4096"),
        (["fit", "--starts", "1000000000"], "--starts must be an integer in [1, 1024]"),
        (["fit", "--posterior", "--max-steps", "1000000000000"], "--max-steps must be an integer in [1, 10000000]"),
        (["fit", "--data", "example", "--starts", "0"], "--starts must be an integer in [1, 1024]"),
        (["fit", "--data", "/nonexistent/panels.csv"], "--data file not found"),
    ],
)
def test_bad_input_is_a_one_line_error(argv, needle, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert needle in err and "Traceback" not in err


def test_every_numeric_flag_has_its_range_checked_first():
    """The validation layer covers every number option of every sub-command under the option's own name (a range
    under a name the command lacks would be an AttributeError, never a check skipped); the two left to later checks
    depend on other options: --incidence (the beam's largest incidence: --length, --wavelength, --n) and --walkers
    (twice the sampled parameters)."""
    import argparse
    import importlib

    from paintjax.cli._main import COMMANDS, build_parser

    later = {"--incidence", "--walkers"}
    subs = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)).choices
    for name in COMMANDS:
        module = importlib.import_module(f"paintjax.cli._{name}")
        options = {o: a for a in subs[name]._actions for o in a.option_strings if o.startswith("--")}
        for bc in ("impedance", "dirichlet"):
            ranges = module.flag_ranges(argparse.Namespace(bc=bc)) if hasattr(module, "flag_ranges") else module.RANGES
            assert all(f in options and options[f].dest == f[2:].replace("-", "_") for f in ranges), (name, sorted(ranges))
            numeric = {o for o, a in options.items() if a.type in (int, float)}
            assert numeric - later <= set(ranges), (name, sorted(numeric - later - set(ranges)))


def test_cache_env_pointing_at_a_file_is_named(tmp_path, monkeypatch, capsys):
    (tmp_path / "file").write_text("x")
    monkeypatch.setenv("PAINTJAX_CACHE", str(tmp_path / "file" / "sub"))
    assert main(["brdf", "--profiles", "2"]) == 2
    err = capsys.readouterr().err
    assert "$PAINTJAX_CACHE" in err and "is a file" in err and "Traceback" not in err


def test_lobe_refuses_an_unconverged_solve(tmp_path, capsys):
    """A steep surface sampled at 12 points per wavelength (not the default curvature-following grid)
    creates energy (scattered 1.64 + absorbed 1.47): refused with the ledger and the fix, exit 2,
    nothing written."""
    argv = ["lobe", "--sigma", "0.3", "--tau", "0.1", "--profiles", "1", "--length", "5", "--out", str(tmp_path / "o")]
    assert main(argv + ["--ppw", "12"]) == 2
    err = capsys.readouterr().err
    assert "not converged" in err and "--ppw" in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_array_refuses_leftover_overlaps(tmp_path, capsys):
    """Without re-placements the generator leaves overlaps: refused unless --allow-overlaps."""
    argv = ["array", "--max-attempts", "0", "--no-plots", "--tile", "150", "--json"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "--allow-overlaps" in err and "Traceback" not in err
    assert main(argv + ["--allow-overlaps"]) == 0
    assert json.loads(capsys.readouterr().out)["overlaps_exact"] > 0


@pytest.mark.parametrize("argv,expected", [
    (["posterior"], "rq"), (["fit", "--posterior", "--sample", "silver2"], "rq"), (["posterior", "--inputs", "none"], "none"),
    (["posterior", "--inputs", "scan_pv"], "scan_pv"), (["posterior", "--measured", "143,107,59,37,32"], "none"),
    (["fit"], "none"), (["fit", "--sample", "silver2"], "none"),
])
def test_a_reference_samples_posterior_uses_its_published_inputs(argv, expected):
    """`paintjax posterior --sample …` combines the L* with the sample's published inputs (σ read as Rq) unless
    `--inputs none` asks for the L* alone; measured values without a sample, and plain fits, have no inputs."""
    from paintjax.cli._fit import resolve_inputs
    from paintjax.cli._main import build_parser

    assert resolve_inputs(build_parser().parse_args(argv)) == expected


def test_chain_checks_come_before_the_fit(tmp_path, capsys, monkeypatch):
    """An unreadable --chain is refused before the least-squares fit, naming --chain, and left as it is."""
    import paintjax.inverse._fit as fit_module

    def no_fit(*a, **k):
        raise AssertionError("the least-squares fit ran before --chain was checked")

    monkeypatch.setattr(fit_module, "fit_least_squares", no_fit)
    path = tmp_path / "notes.h5"
    path.write_text("not a chain")
    assert main(["fit", "--posterior", "--chain", str(path), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "--chain" in err and "not a readable emcee chain" in err and "Traceback" not in err
    assert "AssertionError" not in err and "least-squares fit ran" not in err
    assert path.read_text() == "not a chain"


def test_a_foreign_chain_is_kept(tmp_path, capsys):
    """A --chain holding steps of another run is refused before the fit, named, and left byte-identical;
    --overwrite is offered."""
    import emcee

    path = tmp_path / "other.h5"
    sampler = emcee.EnsembleSampler(8, 2, lambda x: -0.5 * float(x @ x), backend=emcee.backends.HDFBackend(str(path)))
    sampler.run_mcmc(np.random.default_rng(0).standard_normal((8, 2)), 5)
    before = path.read_bytes()
    assert main(["fit", "--posterior", "--chain", str(path), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "--chain" in err and "holds 5 steps" in err and "--overwrite" in err and "Traceback" not in err
    assert path.read_bytes() == before


def test_ctrl_c_is_one_line(monkeypatch, capsys):
    """Ctrl-C inside any command: exit status 130 and one line, no traceback."""
    import paintjax.cli._microfacet as microfacet

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(microfacet, "compute", interrupted)
    assert main(["microfacet"]) == 130
    err = capsys.readouterr().err
    assert err.strip() == "paintjax microfacet: interrupted"


def test_undefined_values_are_null_in_json(tmp_path):
    """JSON output is standard JSON: a flop index without light at 45° is None (null), never NaN."""
    from paintjax._io import atomic_write_json, to_jsonable
    from paintjax._pipeline import flop_index_or_none

    assert flop_index_or_none(140.0, 0.0, 30.0) is None and flop_index_or_none(140.0, 60.0, 30.0) > 0
    assert to_jsonable({"a": np.array([1.0, np.nan, np.inf]), "b": np.float64("nan")}) == {"a": [1.0, None, None], "b": None}
    path = atomic_write_json(tmp_path / "x.json", {"flop": float("nan")})
    assert json.loads(path.read_text()) == {"flop": None}


def test_console_script_runs_as_a_user_would():
    exe = os.path.join(os.path.dirname(sys.executable), "paintjax")
    proc = subprocess.run([exe, "microfacet", "--sample", "silver1", "--json"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert len(json.loads(proc.stdout)["L_star"]) == 5


def test_closed_pipe_is_no_traceback():
    """`paintjax … | head` closes the pipe early: a quiet exit (status 1), no BrokenPipeError traceback."""
    exe = os.path.join(os.path.dirname(sys.executable), "paintjax")
    proc = subprocess.Popen([exe, "microfacet", "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    proc.stdout.close()  # before the child (which first imports JAX) writes anything
    err = proc.stderr.read()
    assert proc.wait(timeout=300) == 1, err
    assert "Traceback" not in err and "BrokenPipe" not in err


def test_demo_reads_each_panels_posterior_summary_from_the_cache(tmp_path, monkeypatch):
    """`paintjax demo`'s inference: each panel's summary is sampled once and read from the cache after,
    and a different seed (or any other input of its key) samples again. The sampling is replaced by a
    stand-in that counts its calls (the real one takes a minute per panel)."""
    from paintjax.cli import _demo

    monkeypatch.setenv("PAINTJAX_CACHE", str(tmp_path / "cache"))
    calls = []

    def stand_in(forward, reading, s, runs, seed):
        calls.append((s.name, seed))
        return {"measured": list(s.L_star), "estimates": {}, "L_star_q50": np.asarray(s.L_star) + seed, "predictive_p_value": 0.5, "predictive_p_value_se": 0.01,
                "verdict": "agree", "at_edge": {}, "converged": {label: True for label in runs}, "seconds": 1.0}

    monkeypatch.setattr(_demo, "_panel_summary", stand_in)  # in this process: one worker (spawned workers would not see it)
    first = _demo.inference(seed=0, progress=False, workers=1)
    again = _demo.inference(seed=0, progress=False, workers=1)
    other = _demo.inference(seed=1, progress=False, workers=1)
    assert calls == [("silver1", 0), ("silver2", 0), ("silver1", 1), ("silver2", 1)]
    for name in ("silver1", "silver2"):
        assert not first["panels"][name]["cached"] and again["panels"][name]["cached"] and not other["panels"][name]["cached"]
        assert again["panels"][name] | {"cached": False} == first["panels"][name]
        np.testing.assert_allclose(other["panels"][name]["L_star_q50"], np.asarray(first["panels"][name]["L_star_q50"]) + 1)
