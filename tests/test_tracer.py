"""Validation of the ray-batch tracer (paintjax.tracer._trace) against closed forms and between its estimators.

White furnace, energy closure, NEE against the histogram, MIS, reciprocity, determinism, device
spread and the grid walk; the single-scatter comparisons with independent models are in
`test_tracer_single_scatter.py`. Every statistical check states its tolerance as a multiple K of
the Monte Carlo standard error (batch means over 32 lane groups); K = 4 gives a false-alarm rate
below 1e-4 per comparison. Scenes are small Boolean-model platelet arrays
(`boolean_platelet_array`, independent placement); the non-delta tests share one compilation
(same padded shapes, same options).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from _tracer_scenes import N_COAT, SILVER1_TILT, K, LambertPlateletBRDF, coat_transmittance, empty_array

from paintjax import (
    MirrorBRDF,
    boolean_platelet_array,
    coat_internal_diffuse_reflectance,
    custom_geometry,
    hemisphere_quadrature,
    ma98_geometry,
)
from paintjax.microstructure._grid import build_grid
from paintjax.tracer._options import TracerOptions, detector_reverse_shares
from paintjax.tracer._trace import trace

OPT = TracerOptions(lanes=1024, steps_per_call=16, batches=32)
OPT_NEE = TracerOptions(lanes=1024, steps_per_call=16, batches=32, mis=False)  # NEE alone at finite apertures
OPT_FWD = TracerOptions(lanes=1024, steps_per_call=16, batches=32, reverse_share=0.0)  # point detectors: forward tracer alone


@pytest.fixture(scope="module")
def empty_scene():
    arr = empty_array(tile=(40.0, 40.0), h_b=20.0, thickness=0.2)
    return arr, build_grid(arr, 5.0, capacity=24)


@pytest.fixture(scope="module")
def lambert_scene():
    """400 platelets (w = 4, t = 0.2 µm) with Silver #1 tilts in a 40 × 40 × 20 µm tile."""
    arr = boolean_platelet_array(1, 400, tile=(40.0, 40.0), basecoat_thickness=20.0, width=4.0, thickness=0.2,
                                 tilt=SILVER1_TILT, margin=2.2)
    return arr, build_grid(arr, 5.0, capacity=24)


@pytest.mark.parametrize("opt", [OPT_FWD, OPT], ids=["forward", "bidirectional"])
def test_white_furnace(empty_scene, opt):
    """No platelets, Lambertian primer ρ under the coat: R = T_i T_o ρ / (n² (1 − ρ r_i)).

    Forward alone, and bidirectional: for pure primer paths the two path densities are equal, so
    this checks the weights' ray-count factor and how the forward pass and the reverse pool are
    combined (the density ratio itself is checked by `test_bidirectional_mis`).
    """
    arr, grid = empty_scene
    geo = ma98_geometry(45.0)
    rho = 0.8
    res = trace(arr, geo, LambertPlateletBRDF(0.5), grid=grid, n=N_COAT, primer_albedo=rho, rays=30_000, seed=3, options=opt)
    r_i = coat_internal_diffuse_reflectance(N_COAT)
    expected = coat_transmittance(45.0) * coat_transmittance(np.asarray(geo.detector_polar_deg)) * rho / (N_COAT**2 * (1 - rho * r_i))
    dev = (res.reflectance_factor - expected) / res.reflectance_factor_se
    print("furnace: deviation / SE", np.round(dev, 2), "relative SE", np.round(res.reflectance_factor_se / expected, 4))
    assert np.all(np.abs(dev) < K), dev
    assert np.all(res.reflectance_factor_se < 0.01 * expected)  # the check has teeth (< 1 % SE)
    e = res.energy
    assert abs(sum(e.values()) - 1.0) < 1e-5
    assert e["absorbed_platelets"] == 0.0
    assert abs(e["top_reflection"] - (1 - coat_transmittance(45.0))) < 1e-5


@pytest.mark.parametrize("waviness", [0.0, 8.0])
def test_energy_lossless(lambert_scene, waviness):
    """Lossless platelets and a ρ = 1 primer: everything that enters leaves, flat or wavy coat.

    Two checks. The ledger: exited / entered = 1 to 1e-3 (roulette is zero-mean, caps are all
    that remain). The detectors: the next-event estimates over the exit hemisphere, integrated
    (R cos θ / π, 16 detectors under normal illumination), must also equal the entered fraction, a white furnace with platelets that
    tests NEE's normalisation (n², exit Fresnel, facet weights of the wavy coat) against the
    ledger; within K·SE of the integral (batch means), no allowance.
    """
    arr, grid = lambert_scene
    geo, weights = hemisphere_quadrature(N_COAT)  # normal illumination: one azimuth stands for all
    res = trace(arr, geo, LambertPlateletBRDF(1.0), grid=grid, n=N_COAT, primer_albedo=1.0,
                rays=15_000, seed=5, waviness_deg=waviness, options=OPT_FWD)
    e = res.energy
    entered = 1.0 - e["top_reflection"]
    assert e["absorbed_platelets"] == 0.0 and e["absorbed_primer"] == 0.0
    assert abs(sum(e.values()) - 1.0) < 1e-5
    print("energy: exited / entered - 1 =", e["exited"] / entered - 1.0, e)
    assert abs(e["exited"] / entered - 1.0) < 1e-3, e
    hemisphere = res.reflectance_factor @ weights
    batches = res.batch_reflectance_factor @ weights
    se = batches.std(ddof=1) / np.sqrt(batches.size)
    print("NEE over the hemisphere", hemisphere, "entered", entered, "deviation / SE", (hemisphere - entered) / se)
    assert se < 0.01 * entered  # the check has teeth
    assert abs(hemisphere - entered) < K * se


def test_energy_creating_platelets_are_refused(lambert_scene):
    """A platelet BRDF whose albedo exceeds 1 (e.g. an unconverged wave table) would give an
    unphysical paint; the ledger shows it as negative platelet absorption and trace refuses it."""
    import equinox as eqx
    import jax.numpy as jnp

    from paintjax import EnergyCreationError

    arr, grid = lambert_scene
    for albedo in (1.05, 3.0):  # a few per cent per bounce; and weights that grow without bound (inf in the ledger)
        bright = eqx.tree_at(lambda b: b.albedo_value, LambertPlateletBRDF(1.0), jnp.asarray(albedo))  # past the constructor's check
        with pytest.raises(EnergyCreationError, match="brdf creates energy"):
            trace(arr, ma98_geometry(45.0), bright, grid=grid, rays=1024, seed=2, options=OPT_FWD)
    ok = trace(arr, ma98_geometry(45.0), LambertPlateletBRDF(1.0), grid=grid, rays=4096, seed=2, options=OPT_FWD)
    assert ok.energy["absorbed_platelets"] == 0.0  # lossless, and not refused


def test_energy_lossless_mirror_platelets():
    """Lossless delta platelets (reflectance 1) and a ρ = 1 primer: the delta paths (no NEE, scored on
    exit into the apertures) keep every bit of weight too, and the reported estimate (primer NEE by
    MIS, delta splats) agrees with the plain histogram of the exits.

    The two differ only on paths whose last event is the primer, so the comparison needs many primer
    exits into the cones: a layer of about one platelet coverage (100 of the 400 platelets of
    `lambert_scene`) and 12° apertures give some in every batch. Under four coverages and 6° there
    were one or two in 15 000 rays, and batch means cannot judge that (z = 18 on one realisation).
    """
    arr = boolean_platelet_array(1, 100, tile=(40.0, 40.0), basecoat_thickness=20.0, width=4.0, thickness=0.2,
                                 tilt=SILVER1_TILT, margin=2.2)
    grid = build_grid(arr, 5.0, capacity=24)
    geo = ma98_geometry(45.0, detector_aperture_deg=12.0)
    res = trace(arr, geo, MirrorBRDF(n_binder=N_COAT, reflectance=1.0), grid=grid, n=N_COAT, primer_albedo=1.0,
                rays=15_000, seed=6, options=OPT_FWD)
    e = res.energy
    entered = 1.0 - e["top_reflection"]
    print("mirror energy: exited / entered - 1 =", e["exited"] / entered - 1.0, e)
    assert e["absorbed_platelets"] == 0.0 and e["absorbed_primer"] == 0.0
    assert abs(sum(e.values()) - 1.0) < 1e-5
    assert abs(e["exited"] / entered - 1.0) < 1e-3, e
    diff = res.batch_reflectance_factor - res.batch_histogram  # primer NEE (MIS) and delta splats vs plain exits, same paths
    z = diff.mean(axis=0) / (diff.std(axis=0, ddof=1) / np.sqrt(diff.shape[0]))
    print("(estimate − histogram)/paired SE", np.round(z, 2))
    assert np.all(np.abs(z) < K)


def test_detectors_no_light_reaches_are_flagged_not_resolved():
    """Horizontal mirrors over a black primer send light only into the specular direction: the detector
    there is reached in every batch, the others never (R exactly 0, batch-means SE 0). Those are flagged
    as not resolved with a warning, and the adaptive rule does not call them converged."""
    from paintjax.tracer._result import resolved_detectors

    arr = boolean_platelet_array(1, 100, tile=(40.0, 40.0), basecoat_thickness=20.0, width=4.0, thickness=0.2, margin=2.2)
    grid = build_grid(arr, 5.0, capacity=24)
    geo = ma98_geometry(45.0, [0.0, 15.0, 25.0, 45.0, 75.0], detector_aperture_deg=12.0)  # the cones miss the specular one by ≥ 3°
    kw = dict(grid=grid, n=N_COAT, primer_albedo=0.0, seed=6, options=OPT_FWD)
    with pytest.warns(RuntimeWarning, match=r"15° \(0 of 32 batches\).*not resolved"):
        res = trace(arr, geo, MirrorBRDF(n_binder=N_COAT), rays=4096, **kw)
    assert res.resolved.tolist() == [True, False, False, False, False]
    assert res.reflectance_factor[0] > 0 and np.all(res.reflectance_factor[1:] == 0.0) and np.all(res.L_star_se[1:] == 0.0)
    assert res.to_dict()["resolved"].tolist() == res.resolved.tolist()
    with pytest.warns(RuntimeWarning, match="not resolved"):  # SE 0 ≤ target, yet it keeps tracing to the ceiling
        adaptive = trace(arr, geo, MirrorBRDF(n_binder=N_COAT), rays=4096, target_se_lstar=5.0, max_rays=16384, **kw)
    assert adaptive.rays >= 16384
    assert resolved_detectors(np.array([[1.0, 0.0, 0.0], [2.0, 3.0, 0.0]])).tolist() == [True, True, False]  # half suffices


@pytest.mark.parametrize("waviness", [0.0, 8.0])
def test_nee_and_histogram_agree_as_aperture_shrinks(lambert_scene, waviness):
    """NEE and the finite-aperture histogram estimate the same cone average; both tend to NEE(0).

    With a wavy coat this checks the NEE facet formula (weighted facet draw, refraction of the
    detector direction, v G1 T / n²) against the rays that actually leave through sampled facets.
    """
    arr, grid = lambert_scene
    brdf = LambertPlateletBRDF(0.9)
    kw = dict(grid=grid, n=N_COAT, primer_albedo=0.5, rays=60_000, seed=11, waviness_deg=waviness, options=OPT_NEE)
    exact = trace(arr, ma98_geometry(45.0), brdf, **(kw | dict(options=OPT_FWD)))  # the same forward NEE at point detectors
    for alpha in (12.0, 6.0):
        res = trace(arr, ma98_geometry(45.0, detector_aperture_deg=alpha), brdf, **kw)
        diff = res.batch_reflectance_factor - res.batch_histogram
        se_diff = diff.std(axis=0, ddof=1) / np.sqrt(diff.shape[0])
        se = np.hypot(res.histogram_se, exact.reflectance_factor_se)
        print(f"aperture {alpha}°: (NEE − hist)/SE", np.round((res.reflectance_factor - res.histogram_reflectance_factor) / se_diff, 2),
              "(hist − NEE(0))/SE", np.round((res.histogram_reflectance_factor - exact.reflectance_factor) / se, 2),
              "hist rel. SE", np.round(res.histogram_se / res.histogram_reflectance_factor, 3))
        assert np.all(np.abs(res.reflectance_factor - res.histogram_reflectance_factor) < K * se_diff)
        assert np.all(np.abs(res.histogram_reflectance_factor - exact.reflectance_factor) < K * se)
        assert np.all(res.histogram_se < 0.1 * res.histogram_reflectance_factor)


def test_multiple_importance_sampling(lambert_scene):
    """MIS of NEE and BRDF-sampled exits estimates the same cone average as NEE alone and the histogram.

    Rough platelets (σ = 40 nm, τ = 0.6 µm) with their narrow coherent diffraction lobe, 5° apertures:
    NEE alone meets the lobe only in rare large spikes, which the exits into the aperture cover, so
    MIS must also lower the standard error where the lobe matters.
    """
    from paintjax.brdf._analytic import BeckmannBRDF

    arr, grid = lambert_scene
    brdf = BeckmannBRDF(0.04, 0.6, n_medium=N_COAT)
    geo = ma98_geometry(45.0, detector_aperture_deg=5.0)
    kw = dict(grid=grid, n=N_COAT, primer_albedo=0.5, rays=60_000, seed=12)
    mis = trace(arr, geo, brdf, options=OPT, **kw)
    nee = trace(arr, geo, brdf, options=OPT_NEE, **kw)
    # all three come from the same paths (one seed): compare batch by batch, the paired difference's SE
    for name, other in (("NEE", nee.batch_reflectance_factor), ("hist", mis.batch_histogram)):
        diff = mis.batch_reflectance_factor - other
        z = diff.mean(axis=0) / (diff.std(axis=0, ddof=1) / np.sqrt(diff.shape[0]))
        print(f"(MIS − {name})/paired SE", np.round(z, 2))
        assert np.all(np.abs(z) < K), name
    ratio = (mis.reflectance_factor_se / mis.reflectance_factor) / (nee.reflectance_factor_se / nee.reflectance_factor)
    print("relative SE, MIS / NEE alone", np.round(ratio, 2))  # measured 0.78 0.65 0.63 0.71 0.95 (seed 12)
    assert np.mean(ratio) < 0.9  # MIS off gives exactly 1 (same seed, same numbers)


@pytest.fixture(scope="module")
def beckmann_forward(lambert_scene):
    """The forward tracer alone on rough Beckmann platelets (σ 0.1, τ 0.6 µm), 30 000 rays, seed 13 (independent of
    the bidirectional runs' forward passes), single scattering or all orders: the reference of the bidirectional tests."""
    from paintjax.brdf._analytic import BeckmannBRDF

    arr, grid = lambert_scene
    done = {}

    def run(single):
        if single not in done:
            done[single] = trace(arr, ma98_geometry(45.0), BeckmannBRDF(0.1, 0.6, n_medium=N_COAT), grid=grid, n=N_COAT,
                                 primer_albedo=0.5, single_scatter=single, rays=30_000, seed=13, options=OPT_FWD)
        return done[single]

    return run


@pytest.mark.parametrize("single, share", [(False, 0.5), (True, 0.5), (False, (0.0, 0.0, 0.0, 0.5, 1.0))],
                         ids=["all orders", "single scatter", "per-detector shares"])
def test_bidirectional_mis(lambert_scene, beckmann_forward, single, share):
    """Point detectors: forward NEE weighted against the reverse tracer (balance heuristic over the
    two path densities) plus the reverse passes estimates the same reflectance factor as the forward
    tracer alone.

    Any weights for which the reverse pass computes exactly 1/ρ of the forward pass are unbiased, so
    what this checks is that consistency and the combination of the passes. Rough Beckmann platelets
    (σ = 0.1 µm, τ = 0.6 µm: broad, asymmetric sampling densities, no coherent lobe) keep both
    estimators precise. Dropping the detector's 1/|z_D| from the forward weight alone, or the running
    ratio of the earlier vertices, moved the estimates by 3–9 SE here. The bidirectional run has
    120 000 rays: at 60 000 its relative SE at 110° (all orders) had a median of 4.1–4.3 % over six
    seeds (2.4–12 %: rare heavy paths), at the 5 % the check's teeth require. Per-detector shares: no
    reverse rays for 15–45° (their NEE weight is 1), 0.5 and 1 reverse rays per forward ray for 75° and 110°
    (the reverse pool deals its rays 1 : 2 between them, and both passes weight by those shares). What makes it
    unbiased is that both passes use the same share per detector (each column is normalised by its own rays, so
    the dealing changes only the variance): reverse weights from the mean share instead put 75° 4 SE off.
    """
    from paintjax.brdf._analytic import BeckmannBRDF

    arr, grid = lambert_scene
    brdf = BeckmannBRDF(0.1, 0.6, n_medium=N_COAT)
    geo = ma98_geometry(45.0)
    kw = dict(grid=grid, n=N_COAT, primer_albedo=0.5, single_scatter=single)
    fwd = beckmann_forward(single)
    bid = trace(arr, geo, brdf, rays=120_000, seed=12, options=dataclasses.replace(OPT, reverse_share=share), **kw)
    assert 120_000 <= bid.rays < 121_000  # 1 + Σ shares rays per forward ray, in all
    z = (bid.reflectance_factor - fwd.reflectance_factor) / np.hypot(bid.reflectance_factor_se, fwd.reflectance_factor_se)
    print("(bidirectional − forward)/SE", np.round(z, 2), "relative SE", np.round(bid.reflectance_factor_se / bid.reflectance_factor, 4))
    assert np.all(np.abs(z) < K)
    assert np.all(bid.reflectance_factor_se < (0.01 if single else 0.05) * bid.reflectance_factor)  # the check has teeth



def test_detector_reverse_shares():
    """A number applies to every detector (the reverse pool deals its rays 0, 1, …, m − 1 in turn); a tuple
    gives each detector its own share, rounded to a ratio of small integers that the wheel of sources repeats."""
    shares, wheel = detector_reverse_shares(0.5, 5)
    np.testing.assert_array_equal(shares, np.full(5, 0.5))
    np.testing.assert_array_equal(wheel, np.arange(5))
    shares, wheel = detector_reverse_shares((0.0, 0.0, 0.0, 0.5, 1.0), 5)
    np.testing.assert_allclose(shares, [0, 0, 0, 0.5, 1.0], rtol=1e-12)
    np.testing.assert_array_equal(wheel, [3, 4, 4])
    shares, wheel = detector_reverse_shares((0.3, 0.7), 2)  # 3 : 7
    np.testing.assert_allclose(shares, [0.3, 0.7], rtol=1e-12)
    assert np.sum(wheel == 0) == 3 and np.sum(wheel == 1) == 7
    shares, wheel = detector_reverse_shares((0.2, 0.7001), 2)  # rounded to 2 : 7, the total kept
    np.testing.assert_allclose(shares, [0.9001 * 2 / 9, 0.9001 * 7 / 9], rtol=1e-12)
    assert wheel.size == 9
    shares, wheel = detector_reverse_shares(0.0, 5)
    assert not shares.any()
    # the default, by aspecular angle: none near specular, 0.5 from 60°, 1 from 90°, 0.5 out of the plane
    shares, wheel = detector_reverse_shares("aspecular", 7, [-15.0, 15.0, 25.0, 45.0, 75.0, 110.0, np.nan])
    np.testing.assert_allclose(shares, [0, 0, 0, 0, 0.5, 1.0, 0.5], rtol=1e-12)
    np.testing.assert_array_equal(np.sort(wheel), [4, 5, 5, 6])
    with pytest.raises(ValueError, match="reverse_share must be a number or a tuple of 5 numbers"):
        detector_reverse_shares((0.5, 0.5), 5)


@pytest.mark.parametrize("waviness", [0.0, 8.0])
def test_reciprocity(lambert_scene, waviness):
    """Swapping source and detector leaves the reflectance factor unchanged (non-delta platelets; flat or wavy coat).

    Under the flat coat the platelets are Beckmann lobes (σ = 0.1, τ = 0.6 µm), unlike a Lambertian
    platelet sensitive to a platelet frame or an argument order that broke the symmetry of
    f(ω_i, ω_o); the lobe makes forward next-event estimates spiky, and the reverse pool (OPT, flat
    coat only) tames them. The wavy coat, whose crossings are what it tests, keeps Lambertian
    platelets: through it the forward estimates of the lobe have too heavy a tail for a 2 % SE.
    Even under the flat coat the lobe's estimates are heavy-tailed (rare paths of large weight move
    both the estimate and its SE upward), and the batch-means SE is itself noisy: at
    30 000 rays it ranged 0.9–6.6 % of R over six seeds each of two ray streams, at 60 000 rays
    0.8–2.9 % over three. Hence 60 000 rays and a relative SE below 3 % (then K SE detects a
    reciprocity error above ≈ 13 %).
    """
    from paintjax.brdf._analytic import BeckmannBRDF

    arr, grid = lambert_scene
    flat = waviness == 0
    brdf = BeckmannBRDF(0.1, 0.6, n_medium=N_COAT) if flat else LambertPlateletBRDF(0.9)
    kw = dict(grid=grid, n=N_COAT, primer_albedo=0.5, rays=60_000 if flat else 25_000, waviness_deg=waviness, options=OPT if flat else OPT_FWD)
    # A: source (30°, az 180); detectors (60°, az 0) and (45°, az 90) among five
    a = trace(arr, custom_geometry(30.0, [60.0, 45.0, 10.0, 20.0, 70.0], [0.0, 90.0, 0.0, 180.0, 45.0]), brdf, seed=21, **kw)
    b = trace(arr, custom_geometry(60.0, [30.0, 5.0, 15.0, 25.0, 35.0], [180.0] * 5, illumination_azimuth_deg=0.0), brdf, seed=22, **kw)
    c = trace(arr, custom_geometry(45.0, [30.0, 5.0, 15.0, 25.0, 35.0], [180.0] * 5, illumination_azimuth_deg=90.0), brdf, seed=23, **kw)
    for fwd, fse, bwd, bse in ((a.reflectance_factor[0], a.reflectance_factor_se[0], b.reflectance_factor[0], b.reflectance_factor_se[0]),
                               (a.reflectance_factor[1], a.reflectance_factor_se[1], c.reflectance_factor[0], c.reflectance_factor_se[0])):
        print("reciprocity:", fwd, bwd, "deviation / SE", (fwd - bwd) / np.hypot(fse, bse), "rel. SE", fse / fwd)
        assert abs(fwd - bwd) < K * np.hypot(fse, bse), (fwd, fse, bwd, bse)
        assert fse < (0.03 if flat else 0.02) * fwd


def test_deterministic_and_validated(empty_scene):
    arr, grid = empty_scene
    geo = ma98_geometry(45.0)
    kw = dict(grid=grid, primer_albedo=0.5, rays=4096, seed=9, options=OPT)
    r1 = trace(arr, geo, LambertPlateletBRDF(0.5), **kw)
    calls = []
    r2 = trace(arr, geo, LambertPlateletBRDF(0.5), progress=lambda *a: calls.append(a), **kw)
    np.testing.assert_array_equal(r1.reflectance_factor, r2.reflectance_factor)
    assert np.all(np.isfinite(r1.L_star)) and np.all(np.isfinite(r1.L_star_se))
    assert len(calls) == 1 and calls[0][0] == r2.rays  # progress: one round, reported as traced
    np.testing.assert_allclose(calls[0][1], r2.L_star_se, rtol=1e-12)
    calls.clear()  # the adaptive rule reports every round, rays growing up to the ceiling
    r3 = trace(arr, geo, LambertPlateletBRDF(0.5), progress=lambda *a: calls.append(a),
               **{**kw, "target_se_lstar": 1e-3, "max_rays": 16384})
    assert len(calls) >= 2 and np.all(np.diff([c[0] for c in calls]) > 0) and calls[-1][0] == r3.rays
    np.testing.assert_allclose(calls[-1][1], r3.L_star_se, rtol=1e-12)
    with pytest.raises(ValueError, match="primer_albedo"):
        trace(arr, geo, LambertPlateletBRDF(0.5), grid=grid, primer_albedo=1.5)
    with pytest.raises(ValueError, match="detector_aperture_deg"):
        trace(arr, geo, MirrorBRDF(), grid=grid)
    with pytest.raises(ValueError, match=r"reverse_share must be 'aspecular', a number in \[0, 16\] or a tuple of them"):
        TracerOptions(reverse_share=-1.0)
    with pytest.raises(ValueError, match=r"reverse_share must be 'aspecular', a number in \[0, 16\] or a tuple of them"):
        TracerOptions(reverse_share=(0.5, 17.0))
    with pytest.raises(ValueError, match=r"reverse_share must be a number or a tuple of 5 numbers"):
        trace(arr, geo, LambertPlateletBRDF(0.5), grid=grid, options=dataclasses.replace(OPT, reverse_share=(0.5, 0.5)))
    with pytest.raises(ValueError, match="rays"):
        trace(arr, geo, LambertPlateletBRDF(0.5), grid=grid, rays=0)
    with pytest.raises(ValueError, match=r"grid was built for a \(40.0, 40.0\) µm tile"):  # another array's grid
        trace(empty_array(tile=(30.0, 30.0), h_b=20.0, thickness=0.2), geo, LambertPlateletBRDF(0.5), grid=grid)
    with pytest.raises(ValueError, match=r"built for a binder of index 1.5, but the coat index n is 1.4"):
        trace(arr, ma98_geometry(45.0, detector_aperture_deg=2.0), MirrorBRDF(n_binder=1.5), grid=grid, n=1.4)
    for bad in (None, "abc", float("nan")):
        with pytest.raises(ValueError, match="refractive index n"):
            trace(arr, geo, LambertPlateletBRDF(0.5), grid=grid, n=bad)
    with pytest.raises(ValueError, match="seed"):
        trace(arr, geo, LambertPlateletBRDF(0.5), grid=grid, seed=-1)
    with pytest.raises(ValueError, match=r"waviness_deg .*\[0, 15\]"):
        trace(arr, geo, LambertPlateletBRDF(0.5), grid=grid, waviness_deg=20.0)


_TWO_DEVICE_SCRIPT = """
import json, sys
import jax
jax.config.update("jax_enable_x64", True)
import numpy as np
sys.path.insert(0, {tests!r})
from _tracer_scenes import LambertPlateletBRDF, empty_array
from paintjax import build_grid, ma98_geometry, trace
from paintjax.tracer._trace import TracerOptions
arr = empty_array(tile=(40.0, 40.0), h_b=20.0, thickness=0.2)
opt = TracerOptions(lanes=512, steps_per_call=16, batches=32)
kw = dict(grid=build_grid(arr, 5.0, capacity=24), n=1.5, primer_albedo=0.8, rays=30_000, seed=3, options=opt)
r1 = trace(arr, ma98_geometry(45.0), LambertPlateletBRDF(0.5), **kw)
r2 = trace(arr, ma98_geometry(45.0), LambertPlateletBRDF(0.5), **kw)
print(json.dumps({{"devices": jax.local_device_count(), "R": r1.reflectance_factor.tolist(), "se": r1.reflectance_factor_se.tolist(),
                  "same": bool(np.array_equal(r1.reflectance_factor, r2.reflectance_factor)), "ledger": sum(r1.energy.values()),
                  "rays": r1.rays}}))
"""


def test_rays_spread_over_two_host_devices():
    """The shard_map path: two (forced) CPU devices give the white-furnace closed form, deterministically."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    env = os.environ | {"XLA_FLAGS": "--xla_force_host_platform_device_count=2", "JAX_PLATFORMS": "cpu"}
    script = _TWO_DEVICE_SCRIPT.format(tests=str(Path(__file__).parent))
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600, env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["devices"] == 2 and out["same"] and out["rays"] >= 30_000
    geo = ma98_geometry(45.0)
    rho, r_i = 0.8, coat_internal_diffuse_reflectance(N_COAT)
    expected = coat_transmittance(45.0) * coat_transmittance(np.asarray(geo.detector_polar_deg)) * rho / (N_COAT**2 * (1 - rho * r_i))
    dev = (np.asarray(out["R"]) - expected) / np.asarray(out["se"])
    assert np.all(np.abs(dev) < K), dev
    assert np.all(np.asarray(out["se"]) < 0.01 * expected)
    assert abs(out["ledger"] - 1.0) < 1e-5


@pytest.mark.parametrize("cell", [2.0, 8.0])
def test_shadow_rays_are_decided_at_any_obliquity(cell):
    """Shadow rays from anywhere in an empty basecoat are all visible, from the flat coat's steepest
    internal direction (the critical angle, within one cell budget) to a wavy coat's steepest scored
    one (tan θ_in = 3.5, which outruns the budget and must resume): a ray cut short would count as
    blocked. An empty 400 µm tile, 2 and 8 µm cells."""
    import jax
    import jax.numpy as jnp

    from paintjax.tracer._path import _shadows
    from paintjax.tracer._scene import _WAVY_MAX_TAN_IN, build_scene

    arr = empty_array(tile=(400.0, 400.0), h_b=20.0)
    grid = build_grid(arr, cell, capacity=4)
    rng = np.random.default_rng(1)
    lanes, m = 512, 4
    origins = np.column_stack([rng.uniform(0.0, 400.0, lanes), rng.uniform(0.0, 400.0, lanes), rng.uniform(0.0, 20.0, lanes)])
    for waviness, tan in ((0.0, 1.0 / np.sqrt(N_COAT**2 - 1.0)), (15.0, _WAVY_MAX_TAN_IN)):
        sc = build_scene(arr, ma98_geometry(45.0), LambertPlateletBRDF(1.0), grid, n=N_COAT, clearcoat_thickness=0.0,
                         primer_albedo=1.0, waviness_deg=waviness, dtype=jnp.float64)
        cz = rng.uniform(1.0 / np.sqrt(1.0 + tan**2), 1.0, (lanes, m))
        cz[:, 0] = 1.0 / np.sqrt(1.0 + tan**2) * (1.0 + 1e-9)  # the steepest
        phi = rng.uniform(0.0, 2 * np.pi, (lanes, m))
        dirs = np.stack([np.sqrt(1 - cz**2) * np.cos(phi), np.sqrt(1 - cz**2) * np.sin(phi), cz], axis=-1)
        lim = (20.0 - origins[:, 2:3]) / cz
        val = rng.uniform(0.5, 1.0, (lanes, m))
        val[::7, 1] = 0.0  # no shadow ray pending there
        nee = jax.jit(lambda *a: _shadows(sc, OPT, *a))(jnp.asarray(origins), jnp.asarray(dirs), jnp.asarray(lim), jnp.asarray(val))
        np.testing.assert_array_equal(np.asarray(nee), val)



def test_shadow_rays_in_legs_match_brute_force(lambert_scene):
    """The deferred shadow rays, walked in legs of 2, 4 (default) or all cells to the top per pass (those
    not yet decided resume in the next pass), against a brute-force slab test of every platelet in every
    nearby periodic image: a ray scores exactly when nothing lies between its origin and the top of the
    basecoat. Upward directions out to the flat coat's critical angle, origins anywhere in the film."""
    import dataclasses

    import jax
    import jax.numpy as jnp

    from paintjax.tracer._path import _shadows
    from paintjax.tracer._scene import build_scene

    arr, grid = lambert_scene
    rng = np.random.default_rng(4)
    lanes, m = 256, 4
    origins = np.column_stack([rng.uniform(0.0, 40.0, lanes), rng.uniform(0.0, 40.0, lanes), rng.uniform(0.0, 20.0, lanes)])
    cz = rng.uniform(np.sqrt(1.0 - 1.0 / N_COAT**2), 1.0, (lanes, m))
    phi = rng.uniform(0.0, 2 * np.pi, (lanes, m))
    dirs = np.stack([np.sqrt(1 - cz**2) * np.cos(phi), np.sqrt(1 - cz**2) * np.sin(phi), cz], axis=-1)
    lim = (20.0 - origins[:, 2:3]) / cz
    val = rng.uniform(0.5, 1.0, (lanes, m))
    first = _brute_force_first_hit(arr, np.repeat(origins, m, 0), dirs.reshape(-1, 3), lim.reshape(-1) * np.ones(lanes * m))
    expected = np.where(first.reshape(lanes, m) >= lim, val, 0.0)
    assert 0.2 < np.mean(expected > 0) < 0.95  # both outcomes are common: the check has teeth
    sc = build_scene(arr, ma98_geometry(45.0), LambertPlateletBRDF(1.0), grid, n=N_COAT, clearcoat_thickness=0.0,
                     primer_albedo=1.0, dtype=jnp.float64)
    for leg in (2, 4, 1000):
        opt = dataclasses.replace(OPT, shadow_leg_cells=leg)
        nee = jax.jit(lambda *a: _shadows(sc, opt, *a))(jnp.asarray(origins), jnp.asarray(dirs), jnp.asarray(lim), jnp.asarray(val))
        np.testing.assert_array_equal(np.asarray(nee), expected, err_msg=f"shadow_leg_cells={leg}")
    with pytest.raises(ValueError, match="shadow_leg_cells"):
        dataclasses.replace(OPT, shadow_leg_cells=1)

def _brute_force_first_hit(array, origins, dirs, t_limit, images=3):
    """Nearest box entry t_in ∈ (0, t_limit) over all platelets and periodic images (NumPy, float64)."""
    c = np.asarray(array.centers, float).reshape(-1, 3)
    u = np.asarray(array.axes_u, float).reshape(-1, 3)
    nrm = np.asarray(array.normals, float).reshape(-1, 3)
    v = np.cross(nrm, u)
    half = np.stack([np.asarray(array.widths, float).reshape(-1) / 2] * 2 + [np.full(len(c), array.thickness / 2)], -1)
    Lx, Ly = array.tile
    best = np.array(t_limit, float)
    for a in range(-images, images + 1):
        for b in range(-images, images + 1):
            rel = origins[:, None, :] - (c + np.array([a * Lx, b * Ly, 0.0]))[None]  # (rays, boxes, 3)
            t_near, t_far = np.full(rel.shape[:2], -np.inf), np.full(rel.shape[:2], np.inf)
            for k, axis in enumerate((u, v, nrm)):
                o = np.sum(rel * axis[None], -1)
                dd = dirs @ axis.T
                dd = np.where(np.abs(dd) < 1e-15, 1e-15, dd)
                t1, t2 = (-half[None, :, k] - o) / dd, (half[None, :, k] - o) / dd
                t_near, t_far = np.maximum(t_near, np.minimum(t1, t2)), np.minimum(t_far, np.maximum(t1, t2))
            ok = (t_near <= t_far) & (t_near > 0)
            best = np.minimum(best, np.where(ok, t_near, np.inf).min(-1))
    return best


@pytest.mark.parametrize("thickness", [0.2, 1.0])
def test_traversal_matches_brute_force(thickness):
    """The periodic grid walk finds the same first box as a brute-force search over all images,
    also for rays that start outside the tile (hit points and shadow-ray origins do)."""
    import jax
    import jax.numpy as jnp

    from paintjax.tracer._scene import _traverse, build_scene

    arr = boolean_platelet_array(4, 150, tile=(40.0, 40.0), basecoat_thickness=20.0, width=4.0, thickness=thickness,
                                 tilt=(1.2, 20.0), margin=3.4)  # margin ≥ w/√2 + t/2: any tilt stays in the film
    sc = build_scene(arr, ma98_geometry(45.0), LambertPlateletBRDF(1.0), build_grid(arr, 5.0, capacity=24), n=N_COAT,
                     clearcoat_thickness=0.0, primer_albedo=1.0, dtype=jnp.float64)
    rng = np.random.default_rng(0)
    n = 4000
    origins = np.column_stack([rng.uniform(-80.0, 120.0, n), rng.uniform(-80.0, 120.0, n), rng.uniform(0.5, 19.5, n)])
    dirs = rng.normal(size=(n, 3))
    dirs[:, 2] = np.sign(dirs[:, 2]) * np.maximum(np.abs(dirs[:, 2]), 0.6)  # at most ~60 µm lateral travel
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    t_limit = np.where(dirs[:, 2] > 0, (20.0 - origins[:, 2]) / dirs[:, 2], -origins[:, 2] / dirs[:, 2])
    walk = jax.jit(jax.vmap(lambda p, d, t: _traverse(sc, p, d, t, False, 64)))
    tb, jb, shift, _, done = (np.asarray(x) for x in walk(jnp.asarray(origins), jnp.asarray(dirs), jnp.asarray(t_limit)))
    assert done.all()
    expected = _brute_force_first_hit(arr, origins, dirs, t_limit)
    hit = expected < t_limit
    assert 0.2 < hit.mean() < 0.9  # the test sees both hits and misses
    np.testing.assert_allclose(tb, np.where(hit, expected, t_limit), rtol=1e-9, atol=1e-9)
    # the returned image of the hit box is the one at the hit point, relative to the ray's origin
    centre = np.asarray(arr.centers, float).reshape(-1, 3)[jb[hit]] + np.column_stack([shift[hit], np.zeros(hit.sum())])
    x_hit = origins[hit] + tb[hit, None] * dirs[hit]
    reach = np.asarray(arr.widths, float).reshape(-1)[jb[hit]] * np.sqrt(2) / 2 + thickness
    assert np.all(np.linalg.norm(x_hit - centre, axis=1) <= reach + 1e-9)


def test_wave_table_lookup_agrees_with_the_basis_sums(lambert_scene):
    """A tabulated (wave-type) platelet BRDF traced with its radial lobes looked up in textures (the
    default fast path) and summed over the basis (the reference, `with_radial_texture(False)`), five
    MA98 angles, bidirectional MIS. Same seed: the same paths, so the L* differ only by the lookup's
    ≤ 3 × 10⁻⁴ relative error in the BRDF (< 0.05 combined SE). Another seed for the reference: the
    two estimates agree within 3 combined SE (the statistical equivalence the fast path must keep)."""
    from paintjax import kirchhoff_lobes, table_from_lobes

    arr, grid = lambert_scene
    table = table_from_lobes(kirchhoff_lobes(0.051, 0.64, n_medium=N_COAT), n_medium=N_COAT)  # the paint regime
    geo = ma98_geometry(45.0)
    run = lambda brdf, seed: trace(arr, geo, brdf, grid=grid, n=N_COAT, rays=20_000, seed=seed, options=OPT)  # noqa: E731
    fast, ref, ref2 = run(table, 3), run(table.with_radial_texture(False), 3), run(table.with_radial_texture(False), 4)
    se = np.hypot(fast.L_star_se, ref.L_star_se)
    print("lookup − sums, same seed / combined SE", np.round((fast.L_star - ref.L_star) / se, 4),
          "another seed", np.round((fast.L_star - ref2.L_star) / np.hypot(fast.L_star_se, ref2.L_star_se), 2))
    assert np.all(np.isfinite(fast.L_star)) and np.all(se > 0)
    assert np.all(np.abs(fast.L_star - ref.L_star) < 0.05 * se)
    assert np.all(np.abs(fast.L_star - ref2.L_star) < 3.0 * np.hypot(fast.L_star_se, ref2.L_star_se))

