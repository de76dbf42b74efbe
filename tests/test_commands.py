"""The main job and the tracer's command line: `paintjax table1` and `paintjax simulate`, run as a user would.

Small ray budgets (the numbers are the model's, not checked against fixed values); the checks are
the JSON contracts of the issue, internal consistency (RMS, flop index, the measured rows, the
standard-error target, the energy ledger) and the result files.
"""

import json

import jax
import numpy as np
import pytest

from paintjax import flop_index, load_sample
from paintjax.cli._main import main

#: The ledger's entries come from float32 geometry (`TracerOptions.float64` False) summed in float64:
#: each path's shares add to its weight within float32 rounding.
LEDGER_ROUNDING = 1e-6


@pytest.fixture(scope="module")
def table1_run(tmp_path_factory):
    import contextlib
    import io

    out = tmp_path_factory.mktemp("table1")
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = main(["table1", "--json", "--target-se", "3", "--max-rays", "131072", "--mirror-rays", "8192", "--out", str(out)])
    return rc, json.loads(buf.getvalue()), out


def test_table1_json_contract_and_consistency(table1_run):
    rc, data, out = table1_run
    assert rc == 0
    assert set(data) == {"samples", "notes"} and set(data["samples"]) == {"silver1", "silver2"}
    for name, row in data["samples"].items():
        assert set(row) == {"measured", "hybrid", "hybrid_se", "mirror", "analytic", "rms_hybrid"} | {
            "mirror_se", "rms_mirror", "rms_analytic", "flop", "resolved"}
        s = load_sample(name)
        np.testing.assert_array_equal(row["measured"], np.asarray(s.L_star))
        hybrid, se = np.asarray(row["hybrid"]), np.asarray(row["hybrid_se"])
        for key in ("hybrid", "hybrid_se", "mirror", "analytic"):
            assert np.shape(row[key]) == (5,) and np.all(np.isfinite(row[key])), key
        assert np.all(se > 0) and np.all(se <= 3.0)
        assert row["rms_hybrid"] == pytest.approx(float(np.sqrt(np.mean((hybrid - np.asarray(s.L_star)) ** 2))), rel=1e-12)


def test_table1_result_files(table1_run):
    _, data, out = table1_run
    saved = json.loads((out / "table1.json").read_text())
    assert (out / "table1.png").stat().st_size > 10_000
    assert not list(out.glob("*.tmp*"))
    for name, row in saved["samples"].items():
        np.testing.assert_allclose(row["hybrid"], data["samples"][name]["hybrid"], rtol=1e-12)
        L = np.asarray(row["hybrid"])
        assert row["flop"]["hybrid"] == pytest.approx(float(flop_index(L[0], L[2], L[4])), rel=1e-12)
        assert sum(row["energy_hybrid"].values()) == pytest.approx(1.0, abs=LEDGER_ROUNDING)
        assert row["rays"]["mirror"] == 8192 and row["rays"]["hybrid"] <= 131072 + 8 * jax.local_device_count()  # passes round up
        assert row["resolved"]["hybrid"] == [True] * 5 and len(row["resolved"]["mirror"]) == 5  # the rough lobe reaches every detector


def test_simulate_json_contract_and_result_files(capsys, tmp_path):
    argv = ["simulate", "--sample", "silver2", "--brdf", "kirchhoff", "--rays", "16384", "--seed", "3", "--json", "--out", str(tmp_path)]
    assert main(argv) == 0
    r = json.loads(capsys.readouterr().out)
    saved = json.loads((tmp_path / "simulate.json").read_text())
    assert saved["L_star"] == r["L_star"] and saved["inputs"]["brdf"] == "kirchhoff" and saved["sample"] == "silver2"
    assert (tmp_path / "simulate.png").stat().st_size > 10_000
    assert set(r) == {"aspecular_deg", "reflectance_factor", "L_star", "L_star_se", "energy", "rays", "seconds"} | {"resolved", "flop_index"}
    assert r["aspecular_deg"] == [15.0, 25.0, 45.0, 75.0, 110.0]
    assert 16384 <= r["rays"] <= 16384 + 8 * jax.local_device_count()  # each pass rounds up
    assert np.all(np.diff(r["L_star"])[:3] < 0)  # lightness falls away from the specular direction (15° … 75°)
    assert sum(r["energy"].values()) == pytest.approx(1.0, abs=LEDGER_ROUNDING)


def test_simulate_other_illuminations_are_reciprocal():
    """MA98's 15° illumination set and a 30° one through `simulate`: source and detector swapped
    (15° → 30° on the specular side vs 30° → 15° there; 15° → 30° on the illuminator side vs 30° → 15°
    there) give the same reflectance factor within 4 combined SE. Reciprocity, and the paint's statistical
    isotropy under the half-turn that carries each swapped pair onto the instrument's plane convention."""
    from paintjax._pipeline import simulate

    kw = dict(brdf="kirchhoff", rays=16384, seed=3)
    a = simulate("silver2", illumination_deg=15.0, **kw)
    b = simulate("silver2", illumination_deg=30.0, aspecular_deg=[15, 45, -15, 75, 100], **kw)
    assert a["aspecular_deg"].tolist() == [-45.0, -15.0, 15.0, 45.0, 80.0] and a["illumination_deg"] == 15.0
    assert a["measured_L_star"] is None and a["flop_index"] is None and b["flop_index"] is None  # no published values here
    for ia, ib in ((1, 0), (3, 1)):
        diff = a["reflectance_factor"][ia] - b["reflectance_factor"][ib]
        se = np.hypot(a["reflectance_factor_se"][ia], b["reflectance_factor_se"][ib])
        assert abs(diff) < 4 * se, (ia, ib, diff, se)
    assert abs(a["reflectance_factor"][0] - a["reflectance_factor"][1]) > 4 * np.hypot(*a["reflectance_factor_se"][:2])  # distinct angles


def test_simulate_averages_independent_arrays():
    """`arrays` traces one array per seed (seed, seed + 1, …) and reports their mean, with L*'s standard error
    from their spread; a count outside [1, MAX_ARRAYS] is refused by name."""
    from paintjax._pipeline import MAX_ARRAYS, simulate

    kw = dict(brdf="kirchhoff", rays=2048)
    one = [simulate("silver1", seed=s, **kw) for s in (4, 5)]
    both = simulate("silver1", seed=4, arrays=2, **kw)
    L = np.array([r["L_star"] for r in one])
    np.testing.assert_allclose(both["L_star"], L.mean(0), rtol=1e-12)
    np.testing.assert_allclose(both["L_star_array_sd"], L.std(0, ddof=1), rtol=1e-12)
    np.testing.assert_allclose(both["L_star_se"], L.std(0, ddof=1) / np.sqrt(2), rtol=1e-12)
    np.testing.assert_allclose(both["L_star_rays_se"], np.hypot(one[0]["L_star_se"], one[1]["L_star_se"]) / 2, rtol=1e-12)
    assert both["arrays"] == 2 and both["rays"] == one[0]["rays"] + one[1]["rays"]
    for bad in (0, MAX_ARRAYS + 1, 1.5):
        with pytest.raises(ValueError, match="arrays"):
            simulate("silver1", arrays=bad, **kw)


def test_simulate_measured_follows_the_geometry():
    """The published L* are compared only in their own geometry; given values must match the detectors."""
    from paintjax._pipeline import instrument_geometry, measured_lightness
    from paintjax._samples import load_sample

    s = load_sample("silver1")
    np.testing.assert_array_equal(measured_lightness(s, instrument_geometry()), s.L_star)
    assert measured_lightness(s, instrument_geometry(45.0, [-15, 15, 25, 45, 75, 110])) is None
    assert measured_lightness(s, instrument_geometry(15.0)) is None
    np.testing.assert_array_equal(measured_lightness(s, instrument_geometry(45.0, [15, 45]), [140, 60]), [140.0, 60.0])
    for bad in ([140.0], [140.0, np.nan]):
        with pytest.raises(ValueError, match="measured"):
            measured_lightness(s, instrument_geometry(45.0, [15, 45]), bad)


def test_adaptive_first_round_follows_the_target():
    """The first round scales as (0.5 / target)² from the default's 131 072 rays, within [16 384, 131 072];
    a target outside (0, 10] fails before any table or array is built."""
    from paintjax._pipeline import first_round_rays, simulate

    assert first_round_rays(0.5) == 131072 and first_round_rays(0.3) == 131072
    assert first_round_rays(1.0) == 32768 and first_round_rays(3.0) == 16384
    for bad in (0.0, -1.0, 12.0):
        with pytest.raises(ValueError, match="target_se"):
            simulate("silver1", target_se=bad)
    with pytest.raises(ValueError, match="max_rays"):
        simulate("silver1", max_rays=0)


def test_simulate_array_overrides_reach_the_generator():
    """`--d50` scales the sample's width law (and the default tile) and `--platelet-thickness` sets t."""
    from paintjax._pipeline import sample_array
    from paintjax.microstructure._sizes import LogNormalSizes
    from paintjax.microstructure._statistics import array_statistics

    a = sample_array("silver1", d50=8.0, platelet_thickness=0.5, pvc=0.05, seed=1)
    w = np.asarray(a.widths)
    assert a.thickness == 0.5
    assert np.median(w) == pytest.approx(8.0, rel=0.05)  # log-normal, ~1300 draws: SE of the median ≈ 1.3 %
    assert np.quantile(w, 0.9) / np.quantile(w, 0.1) == pytest.approx(30.0 / 8.0, rel=0.15)  # same spread as the sample's
    expected_tile = np.ceil(10 * LogNormalSizes.from_quantiles(4.0, 8.0, 15.0).max_width)
    assert a.tile == (expected_tile, expected_tile)
    assert array_statistics(a)["pvc"] == pytest.approx(0.05, rel=0.05)
