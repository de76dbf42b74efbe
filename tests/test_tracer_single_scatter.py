"""The tracer's single-scatter paths (paintjax.tracer._trace, `single_scatter=True`) against independent models.

Mirror platelets (delta paths scored through the aperture splat) against the single-scatter model
of the same tile (`_tile_single_scatter`, flat coat) and the ensemble model under a wavy coat;
rough platelets (NEE in each platelet's frame) against the analytic model; wide horizontal
platelets against the hot spot's closed form. Tolerances are K standard errors (`_tracer_scenes`;
the wide-platelet test adds 1 % for its tile). The thin-mirror scene is a Boolean-model array of
thin boxes (t/w = 0.02) with absorbing side walls, which the models include (`side_walls`); the
wide-platelet scene's walls (t/w = 0.02/16) are left out of its closed form.
"""

from __future__ import annotations

import numpy as np
import pytest
from _tracer_scenes import N_COAT, SILVER1_TILT, K, coat_transmittance

from paintjax import GammaTilt, HotSpot, MirrorBRDF, boolean_platelet_array, fresnel_dielectric, ma98_geometry
from paintjax.instrument._single_scatter import microfacet_reflectance_factor
from paintjax.microstructure._grid import build_grid
from paintjax.tracer._options import TracerOptions
from paintjax.tracer._trace import trace

OPT_THIN = TracerOptions(lanes=1024, steps_per_call=16, batches=32, edges="absorb")

THIN_W, THIN_T, THIN_ELL = 1.0, 0.02, 50.0  # the thin-platelet scene: width, thickness, mean free depth t/PVC [µm]
THIN_ASPECT = THIN_T / THIN_W
THIN_HOT_SPOT = HotSpot.for_layer((THIN_W * 0.99999, THIN_W, THIN_W * 1.00001), thickness=THIN_T, pvc=THIN_T / THIN_ELL)


@pytest.fixture(scope="module")
def thin_mirror_scene():
    """7360 thin mirror platelets (w = 1, t = 0.02 µm, mean free path 50 µm) with Silver #1 tilts."""
    w, t, ell = THIN_W, THIN_T, THIN_ELL
    h_b, L = 230.0, 40.0
    count = int(round(L * L * h_b / (ell * w * w)))
    arr = boolean_platelet_array(2, count, tile=(L, L), basecoat_thickness=h_b, width=w, thickness=t,
                                 tilt=SILVER1_TILT, margin=0.6)
    return arr, build_grid(arr, 4.0)


def test_single_scatter_mirror_matches_tile_model(thin_mirror_scene):
    """Mirror platelets, gamma tilt, single scattering → the single-scatter model of this very tile, 15°, 25°, 45°.

    For mirrors one tile departs from the ensemble (`microfacet_reflectance_factor`) by more than
    the tracer's standard error: a detector sees only the platelets whose normals bisect the
    illumination and its aperture, few of them in the tail of the tilt law. Over 16 tiles of this
    scene the tile-to-tile SD of R is 2.1 / 4.2 / 22 % at 15 / 25 / 45°, against a ray SE of
    0.9 / 1.9 / 5.8 % here. So the reference is the model of the same tile
    (`_tile_single_scatter`): the tile's own platelets, tilts and widths in a quadrature over the
    instrument azimuth, and the visibility of their faces along the entry and exit paths sampled
    with the grid walk that `test_traversal_matches_brute_force` checks. It shares no sampling,
    splat, aperture or Fresnel bookkeeping with the tracer. Tolerance K·(combined SE).
    Measured (`experiments/tile_single_scatter.py`): on tiles 2–7 |z| ≤ 1.3 except 2.66 at 45° on
    tile 5; ten more ray seeds there average −1.0 SE, with a seed-to-seed SD of 1.02 / 0.89 / 0.59
    times the quoted SE. Averaged over the 16 tiles the tile model is within −1.1 ± 0.5 / −0.1 ±
    1.1 / +2.9 ± 5.4 % of the ensemble model, and over 8 tiles of 80 µm within −0.1 ± 0.4 /
    0.0 ± 1.0 / +1.6 ± 2.3 %, which checks that model (the hot spot and side walls included).
    """
    from paintjax.tracer._tile_single_scatter import tile_mirror_single_scatter

    arr, grid = thin_mirror_scene
    geo = ma98_geometry(45.0, (15.0, 25.0, 45.0, 75.0, 110.0), detector_aperture_deg=8.0)
    mirror = MirrorBRDF(n_binder=N_COAT)
    res = trace(arr, geo, mirror, grid=grid, n=N_COAT, primer_albedo=0.0, rays=200_000, seed=7,
                single_scatter=True, options=OPT_THIN)
    tile = tile_mirror_single_scatter(arr, ma98_geometry(45.0, (15.0, 25.0, 45.0), detector_aperture_deg=8.0), mirror, grid,
                                      n=N_COAT, samples=100_000, seed=0)
    ensemble = np.asarray(microfacet_reflectance_factor(geo, GammaTilt(*SILVER1_TILT), n=N_COAT, platelet=mirror, exit_occlusion=True,
                                                        hot_spot=THIN_HOT_SPOT, side_walls=THIN_ASPECT, aperture_nodes=12))[:3]
    R, se = res.reflectance_factor[:3], res.reflectance_factor_se[:3]
    Rt, se_t = tile["reflectance_factor"], tile["se"]
    print("single scatter: tracer", R, "SE", se, "tile model", Rt, "SE", se_t, "(tracer − tile)/SE",
          np.round((R - Rt) / np.hypot(se, se_t), 2), "tile / ensemble − 1", np.round(Rt / ensemble - 1.0, 3))
    assert np.all(se < np.array([0.03, 0.03, 0.08]) * R)  # the 45° detector sees the tilt tail (R ≈ 0.05)
    assert np.all(se_t < 0.01 * Rt)
    assert np.all(np.abs(R - Rt) < K * np.hypot(se, se_t)), (R, se, Rt, se_t)


def test_single_scatter_mirror_wavy_coat_matches_microfacet_model(thin_mirror_scene):
    """Mirror platelets under a wavy clearcoat (RMS slope 12°), single scattering → the ensemble model, 15°, 25°, 45°.

    The tracer draws facets at entry (visible-normal inversion) and exit (the histogram splat of
    the delta paths sees the facet refraction); the analytic model averages over both crossings
    by Gauss–Hermite quadrature (`_interface`). The waviness moves the model by −12 / +17 / +40 %
    at 15° / 25° / 45°, far beyond the tolerance, so this tests the interface and not just the
    flat limit. Hot spot and side walls as in the model (`HotSpot`, w/ℓ = 0.02, +1.1 … 1.8 %;
    black side walls of the t/w = 0.02 boxes, −0.7 … −1.1 %; the tracer's `edges="absorb"`).

    Limitation: the reference is the ensemble of tiles and the tracer sees one (the tile model
    of the flat test above has no wavy coat). The wavy coat widens the window of tilts each
    detector sees: over tiles 2–7 the tracer's deviation from this model spreads by 1.6 / 2.6 /
    8.7 % (SD) against a ray SE of 0.9 / 1.4 / 5.7 %, i.e. the tile adds about 1.3 / 2.2 / 6.6 %
    (flat coat: 2.1 / 4.2 / 22 %). This tile (seed 2) passes with K·SE alone, so the test
    resolves the wavy interface's −12 / +17 / +40 %, not the 1–2 % terms.
    """
    arr, grid = thin_mirror_scene
    geo = ma98_geometry(45.0, (15.0, 25.0, 45.0, 75.0, 110.0), detector_aperture_deg=8.0)
    mirror = MirrorBRDF(n_binder=N_COAT)
    res = trace(arr, geo, mirror, grid=grid, n=N_COAT, primer_albedo=0.0, rays=200_000, seed=7,
                single_scatter=True, waviness_deg=12.0, options=OPT_THIN)
    model = np.asarray(microfacet_reflectance_factor(geo, GammaTilt(*SILVER1_TILT), n=N_COAT, platelet=mirror, exit_occlusion=True,
                                                     hot_spot=THIN_HOT_SPOT, side_walls=THIN_ASPECT, aperture_nodes=12, waviness_deg=12.0))
    print("single scatter, wavy coat: tracer", res.reflectance_factor[:3], "SE", res.reflectance_factor_se[:3], "model", model[:3],
          "deviation / SE", np.round((res.reflectance_factor[:3] - model[:3]) / res.reflectance_factor_se[:3], 2))
    for j in range(3):  # 15°, 25°, 45°
        R, se = res.reflectance_factor[j], res.reflectance_factor_se[j]
        assert se < (0.03, 0.03, 0.08)[j] * R
        assert abs(R - model[j]) < K * se, (j, R, se, model[j])


def test_single_scatter_rough_matches_microfacet_model(thin_mirror_scene):
    """Rough platelets, gamma tilt, single scattering → analytic model at 15°, 25°, 45° (point detectors).

    The mirror test above scores delta platelets through the aperture splat; this one checks the
    path every rough (wave-based, Kirchhoff) platelet takes: NEE with the BRDF evaluated in each
    platelet's own frame, toward each detector's refracted direction. Beckmann platelets with
    σ = 0.1 µm, τ = 0.6 µm (kσ ≈ 1.9, no coherent part) have a lobe as wide as the tilt law, so a
    wrong platelet frame, a missing cosine or a wrong Jacobian moves 45° by far more than the
    tolerance (K·SE; hot spot and side walls in the model as in the mirror test; measured
    −0.2 / −0.4 / +0.9 %, i.e. −0.5 / −0.8 / +2.0 SE).
    """
    from paintjax.brdf._analytic import BeckmannBRDF

    arr, grid = thin_mirror_scene
    geo = ma98_geometry(45.0)
    brdf = BeckmannBRDF(0.1, 0.6, n_medium=N_COAT)
    res = trace(arr, geo, brdf, grid=grid, n=N_COAT, primer_albedo=0.0, rays=120_000, seed=7,
                single_scatter=True, options=OPT_THIN)
    model = np.asarray(microfacet_reflectance_factor(geo, GammaTilt(*SILVER1_TILT), n=N_COAT, platelet=brdf, exit_occlusion=True,
                                                     hot_spot=THIN_HOT_SPOT, side_walls=THIN_ASPECT))
    print("rough single scatter: tracer", res.reflectance_factor[:3], "SE", res.reflectance_factor_se[:3], "model", model[:3],
          "deviation / SE", np.round((res.reflectance_factor[:3] - model[:3]) / res.reflectance_factor_se[:3], 2))
    for j in range(3):
        R, se = res.reflectance_factor[j], res.reflectance_factor_se[j]
        assert se < 0.01 * R
        assert abs(R - model[j]) < K * se, (j, R, se, model[j])


def test_single_scatter_wide_platelets_hot_spot():
    """Wide platelets correlate the entry and exit paths: tracer vs the hot-spot closed form, all angles.

    Horizontal thin platelets 16 µm wide (the paint's D50) placed as a Boolean (Poisson) model with
    a mean free depth of 5 µm (the paint's t/PVC): single scattering by a rough Beckmann lobe is
    R = π T_i T_o f_p(ω_i, ω_o) G / n² exactly, G the hot spot's depth integral (`_hot_spot`). G is
    0.81 … 0.94 here against 1/2 for independent paths, so the independent model is 1.6–1.9× too
    dark. Tolerance K·SE + 1 % for the tile realisation (two seeds of this 384 µm tile differed by
    0.4 %; a 64 µm tile by 4 %).
    """
    import jax.numpy as jnp

    from paintjax.brdf._analytic import BeckmannBRDF
    from paintjax.instrument._geometry import refract_into_coat
    from paintjax.instrument._hot_spot import HotSpot

    w, t, ell, h_b, L = 16.0, 0.02, 5.0, 60.0, 384.0
    arr = boolean_platelet_array(4, int(round(L * L * h_b / (ell * w * w))), tile=(L, L), basecoat_thickness=h_b, width=w, thickness=t, margin=t)
    geo = ma98_geometry(45.0)
    brdf = BeckmannBRDF(0.1, 0.6, n_medium=N_COAT)
    res = trace(arr, geo, brdf, grid=build_grid(arr, 4.0), n=N_COAT, primer_albedo=0.0, rays=120_000, seed=5,
                single_scatter=True, options=OPT_THIN)
    wi_air, wo_air = geo.illumination_air(), geo.detectors_air()
    wi, wo = refract_into_coat(wi_air, N_COAT), refract_into_coat(wo_air, N_COAT)
    f = np.asarray(brdf.evaluate(jnp.broadcast_to(wi, wo.shape), wo))
    G = np.asarray(HotSpot.for_layer((w * 0.99999, w, w * 1.00001), thickness=t, pvc=t / ell).joint_escape(wi, wo, 1.0, 1.0))
    factor = np.pi * np.asarray(coat_transmittance(45.0)) * np.asarray(1.0 - fresnel_dielectric(wo_air[:, 2], 1.0, N_COAT)[2]) * f / N_COAT**2
    model, independent = factor * G, factor * 0.5
    R, se = res.reflectance_factor, res.reflectance_factor_se
    print("hot spot: G", np.round(G, 3), "tracer", R, "model", model, "deviation / SE", np.round((R - model) / se, 2))
    assert np.all(se < 0.005 * R)
    assert np.all(np.abs(R - model) < K * se + 0.01 * model), (R, se, model)
    assert np.all(R > 1.5 * independent)  # the check has teeth: the independent model is far off
