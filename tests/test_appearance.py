"""The car-paint model and its fit to a paint's gonio table (`paintjax.appearance`).

Checked against closed forms (reciprocity; a Lambertian base under a coat: albedo T(θi)·a·(1 − r_i);
a narrow Beckmann lobe with F0 = 1 reflects all it receives under the coat), a fit that recovers a
known model from a synthetic table, the MA98 geometries against their names, and a small traced
table against the tracer's own symmetries (reciprocity, mirror symmetry out of the plane).
"""

import dataclasses
import json

import jax.numpy as jnp
import numpy as np
import pytest

from paintjax.appearance import CarPaintBRDF, GonioTable, fit_car_paint, gonio_table, load_car_paint, ma98_geometries
from paintjax.appearance._gonio import _aspecular
from paintjax.instrument._geometry import direction, refract_into_coat
from paintjax.optics._fresnel import coat_internal_diffuse_reflectance, fresnel_dielectric

SILVER = dict(diffuse=jnp.asarray(0.05), lobe_weight=jnp.asarray([0.3, 0.15, 0.05]), lobe_roughness=jnp.asarray([0.08, 0.2, 0.5]),
              lobe_f0=jnp.asarray([0.9, 0.9, 0.9]), coat_index=1.5)


def _hemisphere(n_theta=400, n_phi=256):
    """Midpoint quadrature of the upper hemisphere: directions (N, 3) and solid-angle weights."""
    t = (np.arange(n_theta) + 0.5) * (np.pi / 2) / n_theta
    p = (np.arange(n_phi) + 0.5) * 2 * np.pi / n_phi
    T, P = np.meshgrid(t, p, indexing="ij")
    w = np.sin(T) * (np.pi / 2 / n_theta) * (2 * np.pi / n_phi)
    d = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1)
    return d.reshape(-1, 3), w.ravel()


def test_ma98_geometries_match_their_names():
    rows = ma98_geometries()
    assert len(rows) == 19 and len({r["name"] for r in rows}) == 19
    for r in rows:
        theta_i, rest = r["name"].split("as")
        gamma = float(rest.split("az")[0])
        assert float(theta_i) == r["illumination_deg"]
        angle = _aspecular(r["illumination_deg"], r["polar_deg"], r["azimuth_deg"])
        assert abs(angle - abs(gamma)) < 0.06, (r, angle)  # names round to 0.1°
        if "az" in r["name"]:  # out of plane: the two mirror images
            assert abs(abs(r["azimuth_deg"]) - (33.40 if r["polar_deg"] > 46 else 90.0)) < 0.02


def test_car_paint_brdf_is_reciprocal_and_zero_below_the_horizon():
    m = CarPaintBRDF(**SILVER)
    rng = np.random.default_rng(1)
    v = rng.normal(size=(2, 500, 3))
    v[..., 2] = np.abs(v[..., 2])
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    f1, f2 = np.asarray(m.evaluate(v[0], v[1])), np.asarray(m.evaluate(v[1], v[0]))
    assert np.all(f1 > 0) and np.allclose(f1, f2, rtol=1e-12)
    below = v[1] * np.array([1, 1, -1])
    assert np.all(np.asarray(m.evaluate(v[0], below)) == 0.0)


@pytest.mark.parametrize("theta_i", [0.0, 40.0, 70.0])
def test_lambertian_base_under_a_coat_has_the_closed_form_albedo(theta_i):
    """f = T_i T_o a / (π n²): albedo = T_i a (1 − r_e) / n² = T_i a (1 − r_i), with r_i the coat's internal diffuse reflectance."""
    n, a = 1.5, 0.7
    m = CarPaintBRDF(diffuse=jnp.asarray(a), lobe_weight=jnp.asarray([0.0]), lobe_roughness=jnp.asarray([0.2]),
                     lobe_f0=jnp.asarray([1.0]), coat_index=n)
    d, w = _hemisphere()
    wi = np.asarray(direction(theta_i, 180.0))
    albedo = np.sum(np.asarray(m.evaluate(np.broadcast_to(wi, d.shape), d)) * d[:, 2] * w)
    Ti = 1.0 - float(fresnel_dielectric(np.cos(np.radians(theta_i)), 1.0, n)[2])
    assert albedo == pytest.approx(Ti * a * (1.0 - coat_internal_diffuse_reflectance(n)), rel=2e-3)


def test_a_narrow_mirror_lobe_reflects_what_it_receives_under_the_coat():
    """F0 = 1, weight 1, α = 0.05: ∫ f_base cos dω (inside the coat) = 1 − O(α²) at moderate incidence."""
    m = CarPaintBRDF(diffuse=jnp.asarray(0.0), lobe_weight=jnp.asarray([1.0]), lobe_roughness=jnp.asarray([0.05]),
                     lobe_f0=jnp.asarray([1.0]), coat_index=1.5)
    d, w = _hemisphere(2000, 512)
    for theta in (0.0, 20.0):
        wi = np.asarray(refract_into_coat(direction(theta, 180.0), 1.5))
        total = np.sum(np.asarray(m.base(np.broadcast_to(wi, d.shape), d)) * d[:, 2] * w)
        assert total == pytest.approx(1.0, abs=0.01)


def test_bad_models_are_refused_with_the_parameter_named():
    for bad, name in ((dict(lobe_roughness=jnp.asarray([0.08, 0.2, 5.0])), "lobe_roughness"), (dict(lobe_f0=jnp.asarray([1.2, 0.9, 0.9])), "lobe_f0"),
                      (dict(diffuse=jnp.asarray(-0.1)), "diffuse"), (dict(coat_index=0.9), "coat_index"),
                      (dict(lobe_weight=jnp.asarray([0.1] * 4), lobe_roughness=jnp.asarray([0.1] * 4), lobe_f0=jnp.asarray([0.9] * 4)), "lobe_weight")):
        with pytest.raises(ValueError, match=name):
            CarPaintBRDF(**(SILVER | bad))


def _synthetic_table(model, noise_L=0.2, seed=0) -> GonioTable:
    """The model's reflectance factors on a gonio grid with MA98 entries, plus Gaussian noise of `noise_L` in L*."""
    from paintjax.appearance._gonio import _detectors
    from paintjax.instrument._lightness import lightness_np, lightness_to_reflectance_factor

    rows = [(ti, p, a, nm) for ti in (0.0, 15.0, 30.0, 45.0, 60.0, 80.0)
            for p, a, nm in _detectors(ti, np.arange(0.0, 81.0, 10.0), (0.0, 45.0, 90.0, 135.0, 180.0))]
    ti, p, a, nm = (np.asarray(c) for c in zip(*rows))
    wi, wo = np.asarray(direction(ti, np.full_like(ti, 180.0))), np.asarray(direction(p, a))
    L = lightness_np(100.0 * np.asarray(model.reflectance_factor(wi, wo)))
    L = L + noise_L * np.random.default_rng(seed).normal(size=L.shape)
    R = lightness_to_reflectance_factor(L)
    se = R * 3.0 * noise_L / np.maximum(L + 16.0, 1.0)  # the delta method: dR/R = 3 dL/(L + 16)
    return GonioTable(illumination_deg=ti.astype(float), polar_deg=p.astype(float), azimuth_deg=a.astype(float), reflectance_factor=R,
                      reflectance_factor_se=se, name=nm.astype(str), paint={"sample": "synthetic"}, rays=0, seconds=0.0)


def test_fit_recovers_a_known_model_to_the_noise(tmp_path):
    truth = CarPaintBRDF(diffuse=jnp.asarray(0.08), lobe_weight=jnp.asarray([0.4, 0.1]), lobe_roughness=jnp.asarray([0.07, 0.25]),
                         lobe_f0=jnp.asarray([0.9, 0.6]), coat_index=1.5)
    table = _synthetic_table(truth, noise_L=0.2)
    fit = fit_car_paint(table, lobes=2, color_table=None)
    assert fit.converged
    assert fit.rms_all < 0.25 and fit.rms_ma98 < 0.3  # the noise is 0.2
    assert np.allclose(np.asarray(fit.model.lobe_roughness), [0.07, 0.25], rtol=0.05)
    assert float(fit.model.diffuse) == pytest.approx(0.08, rel=0.1)
    path = fit.save(tmp_path / "m.json")
    model, doc = load_car_paint(path)
    assert doc["fit"]["converged"] and len(doc["fit"]["ma98"]) == 19
    assert np.allclose(np.asarray(model.evaluate(table.wi, table.wo)), np.asarray(fit.model.evaluate(table.wi, table.wo)))


def test_an_unconverged_fit_is_reported_and_never_exported(tmp_path):
    table = _synthetic_table(CarPaintBRDF(**SILVER))
    fit = fit_car_paint(table, lobes=3, max_steps=2)
    assert not fit.converged and "NOT converged" in fit.summary()
    with pytest.raises(ValueError, match="did not converge"):
        fit.save(tmp_path / "m.json")
    assert not (tmp_path / "m.json").exists()


def test_a_model_the_fit_cannot_follow_is_named(tmp_path):
    """Two lobes fitted with one: the fit reports the entries it misses, by how much."""
    truth = CarPaintBRDF(diffuse=jnp.asarray(0.02), lobe_weight=jnp.asarray([0.5, 0.3]), lobe_roughness=jnp.asarray([0.03, 0.6]),
                         lobe_f0=jnp.asarray([1.0, 1.0]), coat_index=1.5)
    fit = fit_car_paint(_synthetic_table(truth, noise_L=0.1), lobes=1, color_table=None)
    worst = fit.worst
    assert worst and abs(worst[0]["delta_L"]) > 1.0 and "cannot follow" in fit.summary()


def test_json_files_are_checked(tmp_path):
    p = tmp_path / "x.json"
    p.write_text(json.dumps({"format": "something-else"}))
    with pytest.raises(ValueError, match="not a paintjax car-paint"):
        load_car_paint(p)
    doc = CarPaintBRDF(**SILVER).to_dict()
    doc["lobes"][0]["roughness"] = 7.0
    p.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="lobe_roughness"):
        load_car_paint(p)
    with pytest.raises(ValueError, match="not found"):
        load_car_paint(tmp_path / "missing.json")


@pytest.fixture(scope="module")
def small_table():
    """A traced table of Silver #1 with Kirchhoff platelets: few directions, few rays."""
    return gonio_table("silver1", brdf="kirchhoff", incidences_deg=(15.0, 30.0, 45.0), polar_deg=(0.0, 15.0, 30.0, 45.0),
                       azimuth_deg=(0.0, 90.0, 180.0), rays=24_576, seed=3)


def test_traced_table_is_reciprocal_and_mirror_symmetric(small_table):
    t = small_table
    R, se = t.reflectance_factor, t.reflectance_factor_se
    assert np.all(np.isfinite(R)) and np.all(R > 0) and np.all(se > 0)

    def at(ti, p, a, name=""):
        j = np.flatnonzero((t.illumination_deg == ti) & np.isclose(t.polar_deg, p) & np.isclose(t.azimuth_deg, a) & (t.name == name))
        assert j.size == 1
        return R[j[0]], se[j[0]]

    # reciprocity in the plane: f(θi = 15 → θo = 30 specular side) = f(30 → 15), also at 90° azimuth
    for (a1, a2) in ((0.0, 0.0), (90.0, 90.0)):
        (r1, s1), (r2, s2) = at(15.0, 30.0, a1), at(30.0, 15.0, a2)
        assert abs(r1 - r2) < 4 * np.hypot(s1, s2), (r1, r2, s1, s2)
    # the MA98's out-of-plane pairs see the same light (isotropic paint)
    for name in ("45as25az90", "45as60az125.3", "15as38.3az43"):
        (r1, s1), (r2, s2) = (at(*[(g["illumination_deg"], g["polar_deg"], g["azimuth_deg"], g["name"]) for g in ma98_geometries()
                                   if g["name"] == nm][0]) for nm in (name, name.replace("az", "az-")))
        assert abs(r1 - r2) < 4 * np.hypot(s1, s2), (name, r1, r2)
    # the table's MA98 45° in-plane entries are the simulate command's, same seed and rays
    assert t.is_ma98.sum() == 19 and set(t.illumination_deg[t.is_ma98]) == {15.0, 45.0}


def test_table_is_cached_and_written_as_csv(small_table, tmp_path):
    again = gonio_table("silver1", brdf="kirchhoff", incidences_deg=(15.0, 30.0, 45.0), polar_deg=(0.0, 15.0, 30.0, 45.0),
                        azimuth_deg=(0.0, 90.0, 180.0), rays=24_576, seed=3)
    assert np.array_equal(again.reflectance_factor, small_table.reflectance_factor)
    lines = small_table.save_csv(tmp_path / "t.csv").read_text().splitlines()
    assert len(lines) == small_table.reflectance_factor.size + 1 and lines[0].startswith("illumination_deg,")


def test_gonio_arguments_are_checked():
    with pytest.raises(ValueError, match="incidences_deg"):
        gonio_table("silver1", incidences_deg=(85.0,))
    with pytest.raises(ValueError, match="azimuth_deg"):
        gonio_table("silver1", azimuth_deg=(0.0, 0.0))
    with pytest.raises(ValueError, match="unknown paint parameter"):
        gonio_table("silver1", colour=3.0)
    with pytest.raises(ValueError, match="lobes"):
        fit_car_paint(_synthetic_table(CarPaintBRDF(**SILVER)), lobes=4)


def test_simulate_takes_a_custom_geometry_or_aspecular_angles_not_both():
    from paintjax import simulate
    from paintjax.instrument._geometry import custom_geometry

    with pytest.raises(ValueError, match="either geometry or aspecular_deg"):
        simulate("silver1", brdf="kirchhoff", geometry=custom_geometry(45.0, [30.0]), aspecular_deg=(15.0,), rays=1024)
    with pytest.raises(ValueError, match="geometry must be"):
        simulate("silver1", brdf="kirchhoff", geometry="45as15", rays=1024)


def test_dataclass_table_is_frozen(small_table):
    with pytest.raises(dataclasses.FrozenInstanceError):
        small_table.rays = 3


def test_gonio_command_writes_table_model_and_plot(small_table, tmp_path, capsys):
    """`paintjax gonio` as a user runs it (Kirchhoff platelets, two incidences, few rays)."""
    from paintjax.cli._main import main

    out = tmp_path / "gonio"
    # the `small_table` fixture's settings: its table comes from the cache, so only the fit runs here
    rc = main(["gonio", "--brdf", "kirchhoff", "--incidences", "15,30,45", "--polar", "0,15,30,45", "--azimuth", "0,90,180",
               "--rays", "24576", "--seed", "3", "--lobes", "2", "--out", str(out), "--json"])
    doc = json.loads(capsys.readouterr().out)
    assert rc == (0 if doc["fit"]["converged"] else 1) and doc["exported"] == doc["fit"]["converged"]
    assert len(doc["fit"]["ma98"]) == 19 and len(doc["lobes"]) == 2
    assert (out / "silver1_gonio.csv").exists() and (out / "silver1_car_paint.png").exists()
    assert (out / "silver1_car_paint.json").exists() == doc["fit"]["converged"]
    if doc["fit"]["converged"]:
        model, saved = load_car_paint(out / "silver1_car_paint.json")
        assert saved["fit"]["rms_delta_L_ma98"] == pytest.approx(doc["fit"]["rms_delta_L_ma98"])
    assert main(["gonio", "--lobes", "4", "--out", str(out)]) == 2
    assert "--lobes" in capsys.readouterr().err
    assert main(["gonio", "--color-table", "6by6", "--out", str(out)]) == 2
    assert "--color-table" in capsys.readouterr().err


def test_color_table_fit_recovers_a_model_with_a_table(tmp_path):
    """A model whose BRDF is multiplied by a smooth χ(θh, θd): fitted without a table it misses, with one it
    follows to the noise; the table travels through the JSON file, and a version-1 file (no table) still loads."""
    chi = np.exp(0.3 * np.cos(np.linspace(0.0, 2.0, 4))[:, None] * np.linspace(1.0, -1.0, 4)[None, :])
    truth = CarPaintBRDF(diffuse=jnp.asarray(0.06), lobe_weight=jnp.asarray([0.4, 0.1]), lobe_roughness=jnp.asarray([0.07, 0.25]),
                         lobe_f0=jnp.asarray([0.9, 0.6]), coat_index=1.5, color_table=jnp.asarray(chi))
    table = _synthetic_table(truth, noise_L=0.1)
    plain = fit_car_paint(table, lobes=2, color_table=None)
    with_table = fit_car_paint(table, lobes=2, color_table=(4, 4), smoothness=0.3)
    assert with_table.converged and with_table.rms_all < 0.2 < plain.rms_all
    model, doc = load_car_paint(with_table.save(tmp_path / "t.json"))
    assert doc["version"] == 2 and len(doc["color_table"]["values"]) == 4
    assert np.allclose(np.asarray(model.evaluate(table.wi, table.wo)), np.asarray(with_table.model.evaluate(table.wi, table.wo)))
    v1 = CarPaintBRDF(**SILVER).to_dict() | {"version": 1}
    del v1["color_table"]
    (tmp_path / "v1.json").write_text(json.dumps(v1))
    assert load_car_paint(tmp_path / "v1.json")[0].color_table is None
    with pytest.raises(ValueError, match="color_table"):
        CarPaintBRDF(**SILVER, color_table=jnp.asarray([[1.0, -1.0], [1.0, 1.0]]))
