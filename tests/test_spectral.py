"""Spectral mode (paintjax.tracer._spectral): node weights and L*a*b* against colour-science, combination of runs."""

from __future__ import annotations

import numpy as np
import pytest

import paintjax as pj
from paintjax.tracer._result import TraceResult
from paintjax.tracer._spectral import SPECTRAL_NODES_NM, combine_spectral, lab_from_xyz, spectral_node_weights


def test_node_weights_integrate_the_piecewise_linear_spectrum():
    """XYZ of node values = colour-science's integration of their piecewise-linear spectrum (constant beyond the ends)."""
    import colour

    rng = np.random.default_rng(3)
    omega = spectral_node_weights(SPECTRAL_NODES_NM)
    shape = colour.SpectralShape(380, 780, 5)
    cmfs = colour.MSDS_CMFS["CIE 1964 10 Degree Standard Observer"].copy().align(shape)
    ill = colour.SDS_ILLUMINANTS["D65"].copy().align(shape)
    for _ in range(3):
        values = rng.uniform(0.2, 1.6, len(SPECTRAL_NODES_NM))
        on_grid = np.interp(shape.wavelengths, SPECTRAL_NODES_NM, values)
        ref = colour.sd_to_XYZ(colour.SpectralDistribution(dict(zip(shape.wavelengths, on_grid))), cmfs, ill, method="Integration")
        np.testing.assert_allclose(omega @ values, ref, rtol=1e-6)
    assert omega[1].sum() == pytest.approx(100.0, abs=1e-10)  # a perfect reflector


def test_lab_matches_colour_science():
    import colour

    white = spectral_node_weights(SPECTRAL_NODES_NM).sum(axis=1)
    xyz = np.array([[20.0, 21.0, 25.0], [150.0, 160.0, 170.0], [0.3, 0.25, 0.4], [94.0, 100.0, 110.0]])
    ref = colour.XYZ_to_Lab(xyz / 100.0, illuminant=colour.XYZ_to_xy(white / 100.0))
    np.testing.assert_allclose(lab_from_xyz(xyz, white), ref, atol=1e-9)


def _result(R, se, batches=None):
    m = len(R)
    z = np.zeros(m)
    batches = np.tile(np.asarray(R, float), (4, 1)) if batches is None else batches
    return TraceResult(aspecular_deg=np.array(pj.STANDARD_ASPECULAR), reflectance_factor=np.asarray(R, float),
                       reflectance_factor_se=np.asarray(se, float), L_star=z, L_star_se=z, histogram_reflectance_factor=z,
                       histogram_se=z, energy={"exited": 0.5, "absorbed_platelets": 0.5}, rays=100, seconds=1.0,
                       batch_reflectance_factor=batches, batch_histogram=np.zeros_like(batches))


def test_combination():
    K = len(SPECTRAL_NODES_NM)
    R0 = np.array([1.2, 0.8, 0.3, 0.1, 0.05])
    batches = R0 * (1 + 0.02 * np.random.default_rng(1).standard_normal((32, 5)))  # the same batches in every run
    flat = [_result(batches.mean(0), [0.01] * 5, batches) for _ in range(K)]
    res, spectrum = combine_spectral(flat, SPECTRAL_NODES_NM)
    np.testing.assert_allclose(res.reflectance_factor, flat[0].reflectance_factor, rtol=1e-12)
    np.testing.assert_allclose(res.reflectance_factor_se, 0.01, rtol=1e-12)  # full correlation: the bound is attained
    np.testing.assert_allclose(res.L_star, pj.lightness_np(100 * flat[0].reflectance_factor), atol=1e-9)
    np.testing.assert_allclose(spectrum["Lab"][:, 1:], 0.0, atol=1e-9)  # a grey spectrum is neutral
    np.testing.assert_allclose(spectrum["Lab_se"][:, 0], res.L_star_se, rtol=1e-12)  # one L* SE: the bound
    np.testing.assert_allclose(spectrum["Lab_se"][:, 1:], 0.0, atol=1e-9)  # a*, b* of identical grey batches cancel
    assert res.rays == 100 * K and sum(res.energy.values()) == pytest.approx(1.0)
    blue = [_result([1.0 - 0.05 * k] * 5, [0.01] * 5, None) for k in range(K)]  # reflectance falling toward red
    assert np.all(combine_spectral(blue, SPECTRAL_NODES_NM)[1]["Lab"][:, 2] < 0)  # b* < 0: bluish
    with pytest.raises(ValueError, match="one result per node"):
        combine_spectral(flat[:3], SPECTRAL_NODES_NM)


def test_bad_nodes():
    with pytest.raises(ValueError, match="nodes_nm"):
        spectral_node_weights([500, 450, 600])
    with pytest.raises(ValueError, match="nodes_nm"):
        spectral_node_weights([300, 500])


def test_simulate_spectral_with_grey_platelets_is_the_single_wavelength_result(capsys, monkeypatch):
    """Wavelength-independent platelets (constant-reflectance mirrors): every node run is the same
    run (same array, same seed), so the spectral Y equals the one-wavelength R and a*, b* vanish
    (through the CLI: `paintjax simulate --spectral --json`)."""
    import json

    import paintjax._pipeline as sim
    from paintjax.cli._main import main

    asked, original = [], sim.platelet_brdf

    def recording(*a, **kw):  # the node wavelengths must reach the platelet BRDF
        asked.append(kw.get("wavelength_um"))
        return original(*a, **kw)

    monkeypatch.setattr(sim, "platelet_brdf", recording)
    args = ["simulate", "--brdf", "mirror", "--reflectance", "0.9", "--rays", "8192", "--seed", "1", "--json"]
    assert main(args) == 0
    mono = json.loads(capsys.readouterr().out)
    assert main(args + ["--spectral"]) == 0
    spec = json.loads(capsys.readouterr().out)
    np.testing.assert_allclose(spec["reflectance_factor"], mono["reflectance_factor"], rtol=1e-9)
    np.testing.assert_allclose(spec["L_star"], mono["L_star"], rtol=1e-9)
    np.testing.assert_allclose(np.asarray(spec["Lab"])[:, 1:], 0.0, atol=1e-7)
    assert spec["rays"] == len(SPECTRAL_NODES_NM) * mono["rays"] and spec["wavelengths_nm"] == list(SPECTRAL_NODES_NM)
    assert "Lab" not in mono and np.asarray(spec["spectral_reflectance_factor"]).shape == (len(SPECTRAL_NODES_NM), 5)
    assert asked == [None] + [w / 1000 for w in SPECTRAL_NODES_NM]


def test_platelet_brdfs_follow_the_wavelength():
    """`platelet_brdf(..., wavelength_um=λ)` changes the optics (aluminium index, kσ)."""
    import jax.numpy as jnp

    from paintjax._pipeline import platelet_brdf

    wi, wo = jnp.array([0.3, 0.0, 0.954]), jnp.array([-0.25, 0.1, 0.963])
    for kind in ("mirror", "kirchhoff"):
        a, b = (platelet_brdf(kind, sigma=0.051, tau=0.64, n=1.5, wavelength_um=w) for w in (0.4, 0.7))
        fa, fb = (float(x.albedo(jnp.asarray(0.9))) if kind == "mirror" else float(x.evaluate(wi, wo)) for x in (a, b))
        assert abs(fa - fb) > 1e-3 * abs(fa), kind


def test_lab_standard_error_matches_replicates():
    """Independent node runs: the batch-means SE of L*a*b* agrees with the spread over replicate runs."""
    rng = np.random.default_rng(7)
    K = len(SPECTRAL_NODES_NM)
    R0 = np.linspace(1.1, 0.9, K)[:, None] * np.array([1.2, 0.8, 0.3, 0.1, 0.05])  # (K, m), slightly bluish

    def replicate():
        runs = []
        for k in range(K):
            b = R0[k] * (1 + 0.05 * rng.standard_normal((32, 5)))
            runs.append(_result(b.mean(0), b.std(0, ddof=1) / np.sqrt(32), b))
        return combine_spectral(runs, SPECTRAL_NODES_NM)[1]

    reps = [replicate() for _ in range(400)]
    spread = np.std([r["Lab"] for r in reps], axis=0, ddof=1)
    reported = np.mean([r["Lab_se"] for r in reps], axis=0)
    np.testing.assert_allclose(reported[:, 1:], spread[:, 1:], rtol=0.15)  # 400 replicates: ≈ 4 % sampling error of the spread
    assert np.all(reported[:, 0] > 0.9 * spread[:, 0])  # L*: the bound (here ≈ √K too large: independent runs)
