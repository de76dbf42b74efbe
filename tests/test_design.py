"""Inverse design to a target curve, and the `paintjax fit` / `paintjax design` commands."""

import json

import numpy as np
import pytest

from paintjax.cli._main import main
from paintjax.inverse._analytic import AnalyticForward
from paintjax.inverse._design import design_to_target

MIRROR = AnalyticForward(rough=False)


def curve(x):
    return np.array(MIRROR(np.tile(np.asarray(x, dtype=float), (16, 1))))[0]


def test_reachable_target_is_reached():
    target = curve([2.8, 1.7, 0.12])
    r = design_to_target(MIRROR, target, free=("shape", "scale", "diffuse"), tolerance=0.5, n_starts=6)
    assert r.feasible, r.message
    assert r.max_abs_residual < 0.5 and "target reached" in r.message
    assert np.isfinite(r.flop_index) and r.flop_index == pytest.approx(r.target_flop_index, rel=0.05)
    json.dumps(r.to_dict())


def test_fixed_parameters_are_respected():
    target = curve([2.8, 1.7, 0.12])
    r = design_to_target(MIRROR, target, free=("shape", "diffuse"), fixed={"scale": 1.7}, tolerance=0.5, n_starts=4)
    assert r.fixed["scale"] == 1.7 and set(r.params) == {"shape", "diffuse"}
    assert r.params["shape"] == pytest.approx(2.8, rel=1e-3)


def test_weights_ignore_an_angle():
    target = curve([2.8, 1.7, 0.12])
    target[4] += 25.0  # an unreachable 110° value
    bad = design_to_target(MIRROR, target, free=("shape", "scale", "diffuse"), tolerance=0.5, n_starts=4)
    assert not bad.feasible
    ok = design_to_target(MIRROR, target, weights=[1, 1, 1, 1, 0], free=("shape", "scale", "diffuse"), tolerance=0.5, n_starts=4)
    assert ok.feasible, ok.message


def test_infeasible_target_reports_closest_curve():
    # Single scatter with no diffuse floor cannot light the far angles: 35 and 30 L* are out of reach.
    r = design_to_target(MIRROR, [140, 110, 60, 35, 30], free=("shape", "scale"), fixed={"diffuse": 0.0}, n_starts=4)
    assert not r.feasible
    assert "not reachable" in r.message and "closest reachable curve" in r.message
    assert r.max_abs_residual > 5 and len(r.L_star) == 5


def test_design_bad_inputs():
    with pytest.raises(ValueError, match="target must have 5 values"):
        design_to_target(MIRROR, [140, 110, 60])
    with pytest.raises(ValueError, match="target L\\* values must be finite"):
        design_to_target(MIRROR, [140, 110, 60, 35, -30])
    for bad in (0, float("inf")):
        with pytest.raises(ValueError, match="tolerance must be a finite number > 0"):
            design_to_target(MIRROR, [140, 110, 60, 35, 30], tolerance=bad)
    with pytest.raises(ValueError, match="must not include discrepancy"):
        design_to_target(MIRROR, [140, 110, 60, 35, 30], free=("shape", "discrepancy"))


def test_cli_design_and_fit(capsys, tmp_path):
    rc = main(["design", "--target", "140,110,60,35,30", "--forward", "analytic-mirror", "--free", "shape,scale",
               "--fix", "diffuse=0", "--starts", "4", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 1 and out["feasible"] is False and len(out["L_star"]) == 5 and "closest reachable" in out["message"]
    rc = main(["fit", "--measured", "143.3,107.2,58.6,37.2,32.1", "--forward", "analytic-mirror", "--free", "shape,scale,diffuse",
               "--starts", "4", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0
    assert set(out) >= {"params", "stderr", "posterior", "L_star_fit", "seconds"}
    assert set(out["params"]) == {"shape", "scale", "diffuse"} and out["posterior"] is None
    rc = main(["fit", "--sample", "silver2", "--forward", "analytic-mirror", "--free", "shape,scale,diffuse", "--starts", "3",
               "--posterior", "--inputs", "none", "--walkers", "8", "--max-steps", "60", "--min-ess", "0", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and set(out["posterior"]) >= {"mean", "q05", "q95", "tau_int"}
    assert set(out["posterior"]["mean"]) >= {"shape", "scale", "diffuse", "discrepancy", "mean_tilt"}
    assert 0.0 <= out["posterior"]["predictive_p_value"] <= 1.0 and out["posterior"]["inputs"] == "none"
    # the published tilt law as data (mirror platelets: no σ, τ, so no roughness reading)
    rc = main(["fit", "--sample", "silver2", "--forward", "analytic-mirror", "--free", "shape,scale,diffuse", "--starts", "3",
               "--posterior", "--inputs", "rq", "--tilt-platelets", "500", "--walkers", "8", "--max-steps", "60", "--min-ess", "0", "--json",
               "--out", str(tmp_path)])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and set(out["posterior"]["input_shift"]) == {"shape", "scale"}
    for name in ("posterior.nc", "corner.png", "predictive.png"):  # with --out: the chain, its corner plot, the predictive band
        assert (tmp_path / name).stat().st_size > 1000, name
    assert out["posterior"]["input_shift"]["shape"]["published"] == 2.98


def test_readme_design_example_is_reached(capsys):
    """The README's `paintjax design --target 148,124,73,35,35` (the default forward: the shipped tracer emulator)
    reaches its target within the default tolerance, 1 L* at every angle."""
    from pathlib import Path

    assert "paintjax design --target 148,124,73,35,35" in (Path(__file__).parents[1] / "README.md").read_text(encoding="utf-8")
    rc = main(["design", "--target", "148,124,73,35,35", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and out["feasible"] is True, out["message"]
    assert np.max(np.abs(np.asarray(out["L_star"]) - [148, 124, 73, 35, 35])) <= 1.0


def test_cli_errors_are_one_line(capsys):
    assert main(["fit", "--measured", "1,2,3", "--forward", "analytic-mirror"]) == 2
    assert "--measured must have 5" in capsys.readouterr().err
    assert main(["design", "--target", "140,110,60,35,30", "--fix", "shape=abc"]) == 2
    assert "--fix shape must be a number" in capsys.readouterr().err
    assert main(["fit", "--sample", "silver9"]) == 2
    assert "unknown sample" in capsys.readouterr().err
    assert main(["fit", "--sample", "silver1", "--inputs", "rq"]) == 2
    assert "--inputs applies to --posterior" in capsys.readouterr().err
    assert main(["fit", "--measured", "143.3,107.2,58.6,37.2,32.1", "--posterior", "--inputs", "rq"]) == 2
    assert "--inputs needs --sample" in capsys.readouterr().err
    assert main(["fit", "--sample", "silver1", "--posterior", "--inputs", "rq", "--tilt-platelets", "-3"]) == 2
    assert "--tilt-platelets" in capsys.readouterr().err
