"""Platelet arrays from statistics: PVC, overlap removal, tilt law, determinism, sizes, errors, CLI.

Reference arrays use a 250 µm tile (≥ √2·75 + 1 µm, the smallest allowed for the default
size law) to keep the suite fast; the 400 µm case is the benchmark (benchmarks/microstructure.py).
"""

import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from paintjax import (
    GammaTilt,
    LogNormalSizes,
    PlateletArray,
    PolynomialCDFSizes,
    TabulatedCDFSizes,
    array_statistics,
    cross_section,
    default_sizes,
    generate_platelet_array,
    platelet_array_for_sample,
    tilt_ks,
)
from paintjax.microstructure._grid import platelet_boxes

#: Level of the KS test of the realised tilts against the gamma law.
KS_LEVEL = 0.01
TILE = 250.0


@pytest.fixture(scope="module", params=["silver1", "silver2"])
def reference(request):
    from paintjax import load_sample

    s = load_sample(request.param)
    array, log = platelet_array_for_sample(request.param, 0, tile=TILE, return_log=True)
    tilt = GammaTilt(s.tilt_shape.value, s.tilt_scale.value)
    return s, array, log, tilt, array_statistics(array, tilt)


def test_reference_arrays_reach_the_pvc(reference):
    s, array, log, _, st = reference
    assert abs(st["pvc"] - s.pvc.value) < 0.01  # the criterion: 1 % absolute
    # by construction: within half of the largest platelet volume
    w_max = float(np.max(np.asarray(array.widths)))
    assert abs(st["pvc"] - s.pvc.value) <= 0.5 * w_max**2 * array.thickness / array.tile_volume()
    assert st["pvc"] == pytest.approx(log.pvc, rel=1e-12)
    assert st["count"] == log.count == array.count > 300


def test_reference_arrays_have_no_residual_overlaps(reference):
    _, _, log, _, st = reference
    assert log.n_failed == 0
    assert st["overlaps_exact"] == 0
    assert st["overlaps_midplane"] == 0
    assert log.n_replaced > 0.5 * log.count  # overlaps were frequent before removal


def test_reference_tilts_pass_ks(reference):
    _, array, _, tilt, st = reference
    assert st["tilt_ks_pvalue"] > KS_LEVEL
    # the test has power: a law with 30 % larger mean tilt is rejected
    wrong = GammaTilt(float(tilt.shape), 1.3 * float(tilt.scale_deg))
    assert tilt_ks(array, wrong)[1] < KS_LEVEL


def test_generator_tilt_law_is_gammatilt():
    """The NumPy tilt CDF/sampler of the generator reproduce GammaTilt (same formula and table)."""
    from paintjax.microstructure._array import _sample_tilt_np, _tilt_cdf_np

    tilt = GammaTilt(2.98, 2.10)
    t = np.array([0.0, 0.5, 2.0, 6.0, 15.0, 40.0, 90.0, 120.0])
    np.testing.assert_allclose(_tilt_cdf_np(tilt, t), np.asarray(tilt.cdf_deg(jnp.asarray(t))), atol=1e-12)
    # same inverse-CDF table: identical uniforms give identical tilts
    u = np.random.default_rng(0).random(50)
    grid = 90.0 * np.linspace(0, 1, 4097) ** 2
    ref = np.asarray(jnp.interp(jnp.asarray(u), tilt.cdf_deg(jnp.asarray(grid)), jnp.asarray(grid)))
    np.testing.assert_allclose(_sample_tilt_np(tilt, np.random.default_rng(0), 50), ref, rtol=1e-10, atol=1e-10)
    # truncated at 90°: a very wide law still gives tilts ≤ 90°
    wide = _sample_tilt_np(GammaTilt(3.0, 60.0), np.random.default_rng(1), 5000)
    assert wide.max() <= 90.0 and wide.max() > 85.0


def test_array_contract(reference):
    s, array, _, _, _ = reference
    assert isinstance(array, PlateletArray)
    n = array.count
    assert array.centers.shape == (n, 3) and array.normals.shape == (n, 3) and array.axes_u.shape == (n, 3)
    assert array.widths.shape == (n,)
    nrm, u = np.asarray(array.normals), np.asarray(array.axes_u)
    np.testing.assert_allclose(np.linalg.norm(nrm, axis=1), 1, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(u, axis=1), 1, atol=1e-12)
    np.testing.assert_allclose(np.sum(nrm * u, axis=1), 0, atol=1e-12)
    assert np.all(nrm[:, 2] > 0)
    c = np.asarray(array.centers)
    assert np.all((c[:, 0] >= 0) & (c[:, 0] < TILE) & (c[:, 1] >= 0) & (c[:, 1] < TILE))
    # whole boxes inside the basecoat
    hz = np.asarray(array.aabb_half_extents())[:, 2]
    assert np.all(c[:, 2] - hz >= -1e-12) and np.all(c[:, 2] + hz <= s.basecoat_thickness + 1e-12)
    # no layering: centres spread over the film, both halves populated alike
    assert abs(np.mean(c[:, 2] < s.basecoat_thickness / 2) - 0.5) < 0.08
    assert array.thickness == s.platelet_thickness and array.tile == (TILE, TILE)
    assert array.basecoat_thickness == s.basecoat_thickness
    # lateral positions uniform after overlap removal
    assert stats.kstest(c[:, 0] / TILE, "uniform").pvalue > KS_LEVEL
    assert stats.kstest(c[:, 1] / TILE, "uniform").pvalue > KS_LEVEL
    np.testing.assert_allclose(np.asarray(array.axes_v), np.cross(nrm, u), atol=1e-12)


def test_orientations_uniform_in_azimuth_and_in_plane_rotation():
    arr = generate_platelet_array(0, pvc=0.2, tilt=(2.29, 2.18), tile=500.0, overlap_test="none")
    nrm, u = np.asarray(arr.normals), np.asarray(arr.axes_u)
    az = np.arctan2(nrm[:, 1], nrm[:, 0]) % (2 * np.pi)
    assert stats.kstest(az / (2 * np.pi), "uniform").pvalue > KS_LEVEL
    # rotation of the square about its normal, measured from the in-plane steepest-descent direction
    e1 = np.stack([nrm[:, 2] * np.cos(az), nrm[:, 2] * np.sin(az), -np.hypot(nrm[:, 0], nrm[:, 1])], axis=1)
    e2 = np.cross(nrm, e1)
    rot = np.arctan2(np.sum(u * e2, 1), np.sum(u * e1, 1)) % (np.pi / 2)
    assert stats.kstest(rot / (np.pi / 2), "uniform").pvalue > KS_LEVEL


def test_array_is_a_pytree_usable_under_jit(reference):
    _, array, _, _, _ = reference
    leaves = jax.tree_util.tree_leaves(array)
    assert len(leaves) == 4
    total = jax.jit(lambda a: a.volume())(array)
    np.testing.assert_allclose(float(total), np.sum(np.asarray(array.widths) ** 2) * array.thickness)
    p = jnp.asarray([[1.0, 1.0, 5.0]])
    img = np.asarray(array.nearest_image_centers(jnp.asarray([0]), p))
    d = img - np.asarray(p)
    assert np.all(np.abs(d[:, :2]) <= np.array(array.tile) / 2 + 1e-9)
    np.testing.assert_allclose((img - np.asarray(array.centers)[[0]])[:, :2] % TILE, 0, atol=1e-9)


def test_same_seed_same_array_and_key_equivalence():
    kw = dict(pvc=0.2, tilt=(2.98, 2.10), tile=120.0)
    a = generate_platelet_array(11, **kw)
    b = generate_platelet_array(11, **kw)
    c = generate_platelet_array(jax.random.PRNGKey(11), **kw)
    d = generate_platelet_array(12, **kw)
    for x, y in ((a, b), (a, c)):
        for f in ("centers", "normals", "axes_u", "widths"):
            np.testing.assert_array_equal(np.asarray(getattr(x, f)), np.asarray(getattr(y, f)))
    assert a.count != d.count or not np.array_equal(np.asarray(a.centers), np.asarray(d.centers))
    generate_platelet_array(jax.random.key(3), **kw)  # new-style typed keys work too


def test_midplane_removal_leaves_exact_overlaps():
    """The original study's test misses overlaps that the exact test catches."""
    arr = generate_platelet_array(5, pvc=0.2, tilt=(2.29, 2.18), tile=150.0, overlap_test="midplane")
    st = array_statistics(arr)
    assert st["overlaps_midplane"] == 0
    assert st["overlaps_exact"] > 0
    assert st["tilt_ks"] is None


def test_no_removal_and_failed_removal_are_reported():
    arr = generate_platelet_array(6, pvc=0.2, tilt=(2.29, 2.18), tile=150.0, overlap_test="none")
    assert array_statistics(arr)["overlaps_exact"] > 20
    with pytest.warns(RuntimeWarning, match="still overlap"):
        arr, log = generate_platelet_array(6, pvc=0.2, tilt=(2.29, 2.18), tile=150.0, max_attempts=0, return_log=True)
    st = array_statistics(arr)
    assert log.n_failed > 0 and st["overlaps_exact"] > 0
    assert st["pvc"] == pytest.approx(0.2, abs=0.01)  # offenders are kept, PVC unchanged


def test_wide_platelets_are_confined_by_the_film():
    sizes = TabulatedCDFSizes([40.0, 60.0], [0.0, 1.0])
    arr, log = generate_platelet_array(
        2, pvc=0.1, tilt=(4.0, 4.0), sizes=sizes, tile=2.0**0.5 * 60 + 2, basecoat_thickness=12.0, return_log=True
    )
    assert log.n_orientation_redrawn > 0
    c = np.asarray(arr.centers)
    hz = np.asarray(arr.aabb_half_extents())[:, 2]
    assert np.all(c[:, 2] - hz >= -1e-12) and np.all(c[:, 2] + hz <= 12.0 + 1e-12)
    assert array_statistics(arr)["overlaps_exact"] == 0


def test_cross_section_of_a_flat_platelet():
    one = PlateletArray(
        centers=jnp.asarray([[10.0, 10.0, 5.0]]),
        normals=jnp.asarray([[0.0, 0.0, 1.0]]),
        axes_u=jnp.asarray([[1.0, 0.0, 0.0]]),
        widths=jnp.asarray([8.0]),
        thickness=1.0,
        tile=(50.0, 50.0),
        basecoat_thickness=20.0,
    )
    (poly,) = cross_section(one, 12.0)
    np.testing.assert_allclose(poly.min(axis=0), [6.0, 4.5])
    np.testing.assert_allclose(poly.max(axis=0), [14.0, 5.5])
    assert cross_section(one, 30.0) == []
    assert len(cross_section(one, 10.0 + 50.0 - 1.0)) == 1  # periodic image in y


# ----------------------------------------------------------------------------- sizes


def test_default_size_law():
    s = default_sizes()
    q = np.asarray(s.quantile(jnp.asarray([0.1, 0.5, 0.9])))
    np.testing.assert_allclose(q, [8.26, 16.0, 31.0], rtol=0.01)
    assert s.min_width == pytest.approx(16 * math.exp(-3 * s.sigma))
    assert s.max_width == pytest.approx(16 * math.exp(3 * s.sigma))
    w = s.sample_np(np.random.default_rng(0), 20000)
    assert w.min() >= s.min_width and w.max() <= s.max_width
    p_lo = stats.norm.cdf(-3.0)

    def cdf(x):  # truncated log-normal, independent of the package
        return (stats.norm.cdf(np.log(x / 16.0) / s.sigma) - p_lo) / (1 - 2 * p_lo)

    assert stats.kstest(w, cdf).pvalue > KS_LEVEL
    x = jnp.asarray([5.0, 12.0, 16.0, 40.0])
    np.testing.assert_allclose(np.asarray(s.cdf(x)), cdf(np.asarray(x)), atol=1e-6)
    np.testing.assert_allclose(np.asarray(s.ppf(jnp.asarray([0.3]))), s.ppf_np([0.3]), rtol=1e-6)
    assert np.asarray(s.sample(jax.random.PRNGKey(0), 5)).shape == (5,)


def test_tabulated_and_polynomial_cdfs_are_sampled_faithfully():
    rng = np.random.default_rng(1)
    tab = TabulatedCDFSizes([5.0, 10.0, 20.0, 40.0], [0.0, 0.3, 0.9, 1.0])
    w = tab.sample_np(rng, 20000)
    assert stats.kstest(w, lambda x: np.interp(x, [5, 10, 20, 40], [0, 0.3, 0.9, 1.0])).pvalue > KS_LEVEL
    # F(w) = ((w − 5)/25)² on [5, 30] = (w² − 10w + 25)/625
    poly = PolynomialCDFSizes([25 / 625, -10 / 625, 1 / 625], 5.0, 30.0)
    w = poly.sample_np(rng, 20000)
    assert stats.kstest(w, lambda x: ((np.clip(x, 5, 30) - 5) / 25) ** 2).pvalue > KS_LEVEL
    assert float(poly.quantile(0.25)) == pytest.approx(17.5, rel=1e-4)
    # a user CDF drives the generator
    arr = generate_platelet_array(0, pvc=0.15, tilt=(2.29, 2.18), sizes=tab, tile=70.0)
    assert np.all((np.asarray(arr.widths) >= 5) & (np.asarray(arr.widths) <= 40))
    # (d10, d50, d90) tuples mean a log-normal
    arr = generate_platelet_array(0, pvc=0.15, tilt=(2.29, 2.18), sizes=(4.0, 8.0, 15.0), tile=60.0)
    assert 5.0 < float(np.median(np.asarray(arr.widths))) < 11.0


def test_polynomial_cdf_end_tolerance():
    ok = PolynomialCDFSizes([0.01, 1 / 10], 0.0 + 1e-9, 9.95)  # F from ≈0.01 to ≈1.005: rescaled
    assert float(ok.cdf(ok.min_width)) == 0.0 and float(ok.cdf(ok.max_width)) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="coefficients.*run from 0"):
        PolynomialCDFSizes([0.0, 1 / 20], 1.0, 10.0)  # reaches only 0.5


# ----------------------------------------------------------------------------- bad input

BASE = dict(pvc=0.2, tilt=(2.29, 2.18), tile=120.0)


@pytest.mark.parametrize(
    "override, name",
    [
        (dict(pvc=0.0), "pvc"),
        (dict(pvc=-0.1), "pvc"),
        (dict(pvc=0.45), "pvc"),
        (dict(pvc=20.0), "pvc"),
        (dict(pvc=float("nan")), "pvc"),
        (dict(pvc=1e-7), "pvc"),  # less than half a platelet in the tile
        (dict(thickness=0.0), "thickness"),
        (dict(thickness=-1.0), "thickness"),
        (dict(basecoat_thickness=0.0), "basecoat_thickness"),
        (dict(basecoat_thickness=0.8), "basecoat_thickness"),
        (dict(tile=50.0), "tile"),
        (dict(tile=(120.0, 90.0)), "tile"),
        (dict(tile=(120.0, -1.0)), "tile"),
        (dict(overlap_test="aabb"), "overlap_test"),
        (dict(max_attempts=-1), "max_attempts"),
        (dict(max_attempts=2.5), "max_attempts"),
        (dict(tilt=(0.0, 2.0)), "shape"),
        (dict(tilt=(2.0, -2.0)), "scale"),
        (dict(tilt="gamma"), "tilt"),
        (dict(sizes="lognormal"), "sizes"),
        (dict(sizes=(8.0, 16.0, -30.0)), "d90"),
        (dict(sizes=(30.0, 16.0, 8.0)), "d10 < d50 < d90"),
    ],
)
def test_bad_input_names_the_parameter(override, name):
    with pytest.raises(ValueError, match=name):
        generate_platelet_array(0, **(BASE | override))


@pytest.mark.parametrize("seed", [-1, 1.5, "zero", None])
def test_bad_seed(seed):
    with pytest.raises(ValueError, match="seed"):
        generate_platelet_array(seed, **BASE)


@pytest.mark.parametrize(
    "make, name",
    [
        (lambda: LogNormalSizes(d50=-16.0), "d50"),
        (lambda: LogNormalSizes(d50=16.0, sigma=0.0), "sigma"),
        (lambda: LogNormalSizes(truncation=0.5), "truncation"),
        (lambda: TabulatedCDFSizes([0.0, 10.0], [0.0, 1.0]), "widths"),
        (lambda: TabulatedCDFSizes([5.0, 10.0, 8.0], [0.0, 0.5, 1.0]), "widths"),
        (lambda: TabulatedCDFSizes([5.0, 10.0, 20.0], [0.0, 0.7, 0.4]), "cdf.*non-decreasing"),
        (lambda: TabulatedCDFSizes([5.0, 10.0, 20.0], [0.0, 0.5, 0.8]), "cdf.*run from 0"),
        (lambda: TabulatedCDFSizes([5.0], [1.0]), "widths and cdf"),
        (lambda: PolynomialCDFSizes([0.0, 1.5, -1.0], 0.01, 1.0), "coefficients.*non-decreasing"),
        (lambda: PolynomialCDFSizes([0.0, 1.0], -1.0, 1.0), "min_width"),
        (lambda: PolynomialCDFSizes([0.0, 1.0], 1.0, 0.5), "max_width"),
        (lambda: PolynomialCDFSizes([1.0], 1.0, 2.0), "coefficients"),
    ],
)
def test_bad_size_laws_name_the_parameter(make, name):
    with pytest.raises(ValueError, match=name):
        make()


def test_sample_overrides_and_unknown_sample():
    arr = platelet_array_for_sample("silver2", 1, tile=110.0, pvc=0.1)
    assert arr.tile == (110.0, 110.0)
    assert abs(float(arr.pvc) - 0.1) < 0.01
    with pytest.raises(ValueError, match="unknown sample"):
        platelet_array_for_sample("gold", 0)


# ----------------------------------------------------------------------------- CLI


@pytest.fixture
def main(monkeypatch):
    """`paintjax` entry point with only this command registered (independent of other commands)."""
    from paintjax.cli import _main as _cli

    assert "array" in _cli.COMMANDS
    monkeypatch.setattr(_cli, "COMMANDS", ("array",))
    return _cli.main


def test_cli_json_and_pictures(tmp_path, capsys, main):

    rc = main(["array", "--sample", "silver2", "--seed", "1", "--tile", "120", "--json", "--out", str(tmp_path)])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) == {"count", "pvc", "overlaps_exact", "overlaps_midplane", "tilt_ks", "seconds"}
    assert out["overlaps_exact"] == 0 and abs(out["pvc"] - 0.2) < 0.01 and out["count"] > 50
    pngs = sorted(p.name for p in tmp_path.glob("*.png"))
    assert pngs == ["silver2_seed1_cross_section.png", "silver2_seed1_tilt_histogram.png"]
    assert all((tmp_path / p).stat().st_size > 10_000 for p in pngs)


def test_cli_table_and_bad_input(tmp_path, capsys, main):

    assert main(["array", "--tile", "110", "--no-plots", "--out", str(tmp_path)]) == 0
    text = capsys.readouterr().out
    assert "residual overlaps" in text and "PVC" in text
    assert main(["array", "--pvc", "0", "--no-plots", "--out", str(tmp_path)]) == 2
    assert "pvc" in capsys.readouterr().err
    assert main(["array", "--tile", "10", "--no-plots", "--out", str(tmp_path)]) == 2
    assert "tile" in capsys.readouterr().err


def test_boxes_helper_matches_array_methods(reference):
    _, array, _, _, _ = reference
    c, R, e = platelet_boxes(array)
    np.testing.assert_allclose(R, np.asarray(array.box_axes()), atol=1e-12)
    np.testing.assert_allclose(e, np.asarray(array.half_extents()), atol=1e-12)


def test_boolean_array_statistics():
    """Independent placement: uniform centres inside the margins, the gamma tilt law, unit frames."""
    from paintjax import boolean_platelet_array

    a = boolean_platelet_array(3, 4000, tile=(60.0, 40.0), basecoat_thickness=20.0, width=4.0, thickness=0.5, tilt=(2.29, 2.18), margin=2.5)
    c = np.asarray(a.centers)
    assert a.count == 4000 and a.tile == (60.0, 40.0) and np.all(np.asarray(a.widths) == 4.0)
    for col, lo, hi in ((0, 0.0, 60.0), (1, 0.0, 40.0), (2, 2.5, 17.5)):
        assert lo <= c[:, col].min() and c[:, col].max() <= hi
        assert stats.kstest(c[:, col], stats.uniform(lo, hi - lo).cdf).pvalue > KS_LEVEL
    assert tilt_ks(a, GammaTilt(2.29, 2.18))[1] > KS_LEVEL
    n, u = np.asarray(a.normals), np.asarray(a.axes_u)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.sum(n * u, axis=1), 0.0, atol=1e-12)
    flat = boolean_platelet_array(3, 50, tile=(60.0, 40.0), basecoat_thickness=20.0, width=4.0, thickness=0.5)
    np.testing.assert_array_equal(np.asarray(flat.normals), np.tile([0.0, 0.0, 1.0], (50, 1)))
    again = boolean_platelet_array(3, 50, tile=(60.0, 40.0), basecoat_thickness=20.0, width=4.0, thickness=0.5)
    np.testing.assert_array_equal(np.asarray(flat.centers), np.asarray(again.centers))
    assert boolean_platelet_array(0, 0, tile=(10.0, 10.0), basecoat_thickness=5.0, width=1.0, thickness=0.1).count == 0


@pytest.mark.parametrize(
    "override, name",
    [({"count": -1}, "count"), ({"seed": 1.5}, "seed"), ({"width": 0.0}, "width"), ({"thickness": -1.0}, "thickness"),
     ({"tile": (5.0, 40.0)}, "tile"), ({"margin": 10.0}, "margin"), ({"basecoat_thickness": float("nan")}, "basecoat_thickness"),
     ({"tilt": (0.0, 2.0)}, "shape")],
)
def test_boolean_array_bad_input_names_the_parameter(override, name):
    from paintjax import boolean_platelet_array

    kw = dict(seed=0, count=10, tile=(40.0, 40.0), basecoat_thickness=20.0, width=4.0, thickness=0.5) | override
    with pytest.raises(ValueError, match=name):
        boolean_platelet_array(**kw)


def test_platelets_that_cannot_fit_the_film_raise_a_named_error():
    """A tilt law so steep that wide platelets cannot lie in a thin basecoat at any drawn orientation: no array
    exists, and the error says so as its own type (a ValueError), which callers that skip such draws catch."""
    from paintjax.microstructure import PlateletFitError

    with pytest.raises(PlateletFitError, match="sizes/tilt: .* do not fit in the basecoat_thickness 3"):
        generate_platelet_array(0, pvc=0.05, tilt=(20.0, 4.0), basecoat_thickness=3.0, tile=300.0, overlap_test="none")
    assert issubclass(PlateletFitError, ValueError)
