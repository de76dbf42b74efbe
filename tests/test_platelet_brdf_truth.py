"""Platelet BRDF against physics at every roughness the inverse explores.

The wave table is checked against closed forms and independent implementations: the exact
expectation of the Kirchhoff control variate, the Kirchhoff coherent fall-off, He–Torrance across
the whole lobe including specular, geometric optics (Beckmann slopes with Smith shadowing, written
out here), the analytic 3-D Kirchhoff BRDF over the full hemisphere, energy against the flat
surface and reciprocity over the box σ 0.01–0.30 µm, τ 0.2–2.0 µm in binder and air, and the
(σ, τ) grid against a table built directly.
"""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.special import erf

from paintjax import (
    BeckmannBRDF,
    HeTorranceBRDF,
    TabulatedBRDF,
    kirchhoff_lobes,
    platelet_brdf_grid,
    platelet_brdf_table,
    platelet_table_arrays,
    synthesize_profiles,
    table_from_lobes,
)
from paintjax.brdf import hemisphere_directions as hemisphere
from paintjax.brdf._in_plane import _fresnel_np
from paintjax.optics._aluminium import aluminium_index
from paintjax.wave._coherent import expected_control_amplitude, expected_control_power
from paintjax.wave._solver import profile_averaged_lobes

HT = dict(sigma_um=0.28, tau_um=1.77, n_medium=1.0)  # the published full-wave validation case (λ0 = 0.5 µm)
AL = complex(np.asarray(aluminium_index(0.5)))


@functools.lru_cache(maxsize=None)
def _jitted(name):
    return eqx.filter_jit(lambda b, *a: getattr(b, name)(*a))


def call(brdf, name, *args):
    return _jitted(name)(brdf, *args)


def direction(theta_deg, phi_deg=0.0):
    t, p = np.deg2rad(theta_deg), np.deg2rad(phi_deg)
    return np.stack(np.broadcast_arrays(np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)), -1)


@functools.lru_cache(maxsize=None)
def ht_table():
    arrays, _ = platelet_table_arrays(HT["sigma_um"], HT["tau_um"], n_medium=HT["n_medium"])
    return arrays, TabulatedBRDF.from_arrays(arrays, n_medium=HT["n_medium"])


def test_control_variate_expectation_is_exact():
    """E|S|² and E S of the Kirchhoff control sum, computed in closed form for the synthesised process,
    match a Monte Carlo over 4000 profiles (S needs no wave solve) within 4 standard errors."""
    k, g = 2 * np.pi * 1.5 / 0.5, 2.0
    p = synthesize_profiles(jax.random.PRNGKey(11), 0.051, 0.64, length_um=8.0, spacing_um=0.04, num_profiles=4000)
    x, h = np.asarray(p.x), np.asarray(p.h)
    inc, ang = np.radians([0.0, 40.0]), np.radians(np.array([-50.0, -10.0, 0.0, 3.0, 25.0, 40.0, 70.0]))
    qx = k * (np.sin(ang)[:, None] - np.sin(inc)[None, :])
    qz = k * (np.cos(ang)[:, None] + np.cos(inc)[None, :])
    w = np.exp(-(x**2) / g**2)
    S = np.einsum("n,ain,bain->bai", w, np.exp(-1j * qx[..., None] * x), np.exp(-1j * qz[None, ..., None] * h[:, None, None, :]))
    power, mean = np.abs(S) ** 2, S
    want_p = expected_control_power(p.covariance, x, p.spacing, g, k, inc, ang)
    want_m = expected_control_amplitude(p.covariance, x, g, k, inc, ang)
    z_p = (power.mean(0) - want_p) / (power.std(0) / np.sqrt(power.shape[0]))
    z_m = np.abs(mean.mean(0) - want_m) / (np.abs(mean - mean.mean(0)).std(0) * np.sqrt(2) / np.sqrt(mean.shape[0]) + 1e-300)
    assert np.max(np.abs(z_p)) < 4.0, z_p
    assert np.max(z_m) < 4.0, z_m


def test_coherent_reflectance_follows_kirchhoff_fall_off():
    """σ = 20 nm, τ = 640 nm in the binder (2kσ = 0.75, Kirchhoff valid): the unbiased coherent
    reflectance follows R_F(θ) e^{−(2kσ cosθ)²} at 0–60° within 3 SE + 1 % (Kirchhoff's own error;
    measured ≤ 0.3 %), rising with the incidence as the fall-off weakens."""
    inc = np.array([0.0, 20.0, 40.0, 60.0])
    r = profile_averaged_lobes(0.02, 0.64, num_profiles=16, seed=2, incidence_deg=inc, theta_s_deg=np.linspace(-89.5, 89.5, 359))
    k = 2 * np.pi * 1.5 / 0.5
    mu = np.cos(np.deg2rad(inc))
    want = _fresnel_np(mu, 1.5, AL) * np.exp(-((2 * k * 0.02 * mu) ** 2))
    got, se = np.asarray(r.coherent_reflectance), np.asarray(r.coherent_reflectance_se)
    assert np.all(np.abs(got - want) <= 3 * se + 0.01 * want), (got, want, se)
    assert np.all(np.diff(got) > 0)


def test_rough_surface_has_no_coherent_spike():
    """The He–Torrance surface (2kσ = 7, exact coherent part ~1e-21): the wave estimate is consistent with
    0 within 3 SE at every solved incidence up to 60°, the table stores ≤ 3 SE at normal incidence (it
    stored 0.0039 when the mean field carried the diffuse power / N), and the in-plane cut has no spike:
    within ±3° of specular it stays within 10 % of the lobe just outside."""
    arrays, table = ht_table()
    inc = np.asarray(arrays["incidence_deg"])
    rc, se = np.asarray(arrays["coherent_reflectance"]), np.asarray(arrays["coherent_reflectance_se"])
    solved = np.asarray(arrays["wave_solved"], bool) & (inc <= 60.0)
    assert np.all(rc[solved] <= 3 * se[solved] + 1e-12), (rc[solved], se[solved])
    assert rc[0] <= 3 * se[0] + 1e-12 and se[0] < 1e-4
    to = np.linspace(-20.0, 20.0, 401)
    cut = np.asarray(table.in_plane(0.0, to))[0]
    near, ring = cut[np.abs(to) <= 3.0], cut[(np.abs(to) > 3.0) & (np.abs(to) <= 4.0)]
    assert near.max() <= 1.10 * ring.max(), (near.max(), ring.max())


def test_he_torrance_whole_lobe_including_specular():
    """10° incidence in air, the published validation case: the wave table's full BRDF (coherent lobe
    included) against He–Torrance's over the core (He–Torrance ≥ half its peak): rms relative error
    ≤ 10 % and peak ratio 0.9–1.1 (measured 1.0 % and 0.99; were 27 % and 1.85)."""
    _, table = ht_table()
    ht = HeTorranceBRDF(HT["sigma_um"], HT["tau_um"], wavelength_um=0.5, n_medium=HT["n_medium"])
    to = np.linspace(-89.0, 89.0, 357)
    wi, wo = jnp.asarray(direction(10.0)), jnp.asarray(direction(-to))
    f, ref = np.asarray(call(table, "evaluate", wi, wo)), np.asarray(call(ht, "evaluate", wi, wo))
    core = ref >= 0.5 * ref.max()
    rel = f[core] / ref[core] - 1.0
    assert np.sqrt(np.mean(rel**2)) <= 0.10
    assert 0.9 <= f.max() / ref.max() <= 1.1


def _geometric_optics(theta_i, theta_o, sigma, tau, n, metal):
    """Beckmann microfacet BRDF (slopes of C = σ² e^{−x²/τ²}: m = 2σ/τ) with Smith shadowing, in plane."""
    wi, wo = direction(theta_i), direction(-np.asarray(theta_o))
    h = wi + wo
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    m = 2.0 * sigma / tau
    ch = h[..., 2]
    D = np.exp(-(1.0 - ch**2) / (ch**2 * m**2)) / (np.pi * m**2 * ch**4)

    def g1(mu):
        a = mu / (m * np.sqrt(np.maximum(1.0 - mu**2, 1e-300)))
        return 1.0 / (1.0 + (erf(a) - 1.0) / 2.0 + np.exp(-(a**2)) / (2.0 * a * np.sqrt(np.pi)))

    F = _fresnel_np(np.sum(wi * h, -1), n, metal)
    return F * D * g1(wi[2]) * g1(wo[..., 2]) / (4.0 * wi[2] * wo[..., 2])


def _fwhm(theta, f):
    i = int(np.argmax(f))
    above = np.nonzero(f >= 0.5 * f[i])[0]
    lo, hi = above[0], above[-1]
    assert 0 < lo and hi < theta.size - 1, "lobe reaches the end of the cut"
    left = theta[lo - 1] + (0.5 * f[i] - f[lo - 1]) * (theta[lo] - theta[lo - 1]) / (f[lo] - f[lo - 1])
    right = theta[hi] + (0.5 * f[i] - f[hi]) * (theta[hi + 1] - theta[hi]) / (f[hi + 1] - f[hi])
    return right - left


@pytest.mark.parametrize("theta_i", [0.0, 10.0, 20.0, 40.0])
def test_in_plane_width_matches_geometric_optics(theta_i):
    """He–Torrance surface (kσ = 3.5: geometric optics): the full width at half maximum of the in-plane
    scattered intensity f cosθ_o is within 10 % of geometric optics (measured −2…−3 %). (f alone peaks
    at grazing beyond ~10° incidence in both, so its width is not defined there.)"""
    _, table = ht_table()
    to = np.linspace(-89.9, 89.9, 3597)
    f = np.asarray(call(table, "evaluate", jnp.asarray(direction(theta_i)), jnp.asarray(direction(-to)))) * np.cos(np.deg2rad(to))
    ref = _geometric_optics(theta_i, to, HT["sigma_um"], HT["tau_um"], HT["n_medium"], AL) * np.cos(np.deg2rad(to))
    assert abs(_fwhm(to, f) / _fwhm(to, ref) - 1.0) <= 0.10, (_fwhm(to, f), _fwhm(to, ref))


@functools.lru_cache(maxsize=None)
def kirchhoff_pair(sigma, tau, known_roughness=True):
    table = table_from_lobes(kirchhoff_lobes(sigma, tau), min_width=2.0 * 0.5 / (2 * np.pi * 1.5 * tau), sigma_um=sigma if known_roughness else None)
    return table, BeckmannBRDF(sigma, tau)


def construction_l1(theta_i, sigma, tau, known_roughness=True):
    """Scattered-power-weighted L1 of the table built from 1-D Kirchhoff lobes against the analytic 3-D Kirchhoff BRDF."""
    table, analytic = kirchhoff_pair(sigma, tau, known_roughness)
    wo, wt = hemisphere()
    wi = jnp.asarray(direction(theta_i))
    f, ref = np.asarray(call(table, "incoherent", wi, wo)), np.asarray(call(analytic, "incoherent", wi, wo))
    return np.sum(np.abs(f - ref) * wt) / np.sum(ref * wt)


def _open(reason):
    return pytest.mark.xfail(strict=True, reason=f"open: {reason}")


_GRAZING_ROUGH = _open("σ 0.3 µm (kσ 5.7, slope 0.3) near grazing: the lobe continued in q_z from (kσc)² ≈ 32 to ≈ 3 needs its "
                       "transform far below what a fitted lobe carries (measured 4.5 % at 70°, 13 % at 80°, where shadowing also takes 12 %)")
_WIDE_LOBE = _open("τ 0.2 µm at σ 0.01 µm: a lobe of width 2/(kτ) ≈ 0.5 in β reaches past the in-plane data at every incidence and is not continued (measured 4.6 / 4.2 / 5.9 % at 40 / 60 / 80°)")
_CASES = [(0.051, 0.64), (0.051, 1.2), (0.051, 2.0), (0.01, 2.0), (0.02, 0.3), (0.1, 0.5), (0.15, 1.0), (0.3, 2.0), (0.01, 0.2)]
_OPEN = {(0.3, 2.0, 70.0): _GRAZING_ROUGH, (0.3, 2.0, 80.0): _GRAZING_ROUGH,
         (0.01, 0.2, 40.0): _WIDE_LOBE, (0.01, 0.2, 60.0): _WIDE_LOBE, (0.01, 0.2, 80.0): _WIDE_LOBE}


@pytest.mark.parametrize("sigma,tau,theta_i", [pytest.param(s, t, i, marks=_OPEN.get((s, t, i), ())) for s, t in _CASES
                                               for i in (0.0, 10.0, 20.0, 40.0, 60.0, 70.0, 80.0)])
def test_3d_construction_over_the_full_hemisphere(sigma, tau, theta_i):
    """The 2-D → 3-D step (inverse Abel, q_z continuation, symmetric scale) applied to 1-D Kirchhoff
    lobes reproduces the analytic isotropic 3-D Kirchhoff BRDF over the whole exit hemisphere, not only
    in the plane: the scattered-power-weighted L1 difference ∫|f − f_K| cos dω / ∫ f_K cos dω ≤ 3 % at
    0–80°, across the box where Kirchhoff holds (slopes 2σ/τ ≤ 0.3, kσ 0.2–5.7, τ 0.3–2 µm; measured
    ≤ 2.4 %), the surface's (kσ)² given as for the package's own tables. Tables before version 11 were up
    to 21 % off at τ ≥ 1 µm near grazing (a ridge that suppressed the narrow basis widths) and up to 23 %
    at kσ ≳ 2 (a (kσ)² estimate stuck near 4, so the lobes continued towards grazing did not narrow); the
    expected failures are the cells still open."""
    l1 = construction_l1(theta_i, sigma, tau)
    assert l1 <= 0.03, l1


def test_3d_construction_with_estimated_roughness():
    """Lobes of unknown surface (`table_from_lobes` without `sigma_um`): (kσ)² for the q_z continuation is
    estimated from the lobes themselves. At σ 0.15, τ 1.0 µm (kσ 2.8: no usable coherent part) the table
    is within 3 % of 3-D Kirchhoff at 0–80° (measured ≤ 2.4 %; estimate 7.6 for a true 8.0). The estimate
    from the lobe integrals that tables before version 11 used (3.8) left it 15 % / 23 % off at 70° / 80°."""
    errors = [construction_l1(t, 0.15, 1.0, known_roughness=False) for t in (0.0, 10.0, 20.0, 40.0, 60.0, 70.0, 80.0)]
    assert max(errors) <= 0.03, errors


def _continued_from(sigma, tau):
    arrays, _ = platelet_table_arrays(sigma, tau, source="kirchhoff", cache=False)
    return int(np.argmax(arrays["continued"])) if np.any(arrays["continued"]) else -1


def test_table_is_continuous_where_the_continuation_changes_its_reference_node():
    """Where, as σ grows, a node's in-plane coverage falls below 99 % and the q_z continuation starts one node earlier
    (here between σ 0.0382 and 0.0398 µm at τ 0.42 µm, Kirchhoff-source tables), the table does not jump: bisected to
    σ steps of 2.5 × 10⁻⁶ (relative), the L1 across the switch at 60–80° is below 1 % of the change over a 0.1 % step in
    σ beside it (measured 0.25 %; tables before version 13 switched reference outright: 74–170 %, and on the wave
    tables 7.7 % L1 at 80° between a grid-built and a direct table at σ 0.091, τ 0.42 µm)."""
    tau, lo, hi = 0.42, 0.0382, 0.0398
    below = _continued_from(lo, tau)
    assert _continued_from(hi, tau) == below - 1
    for _ in range(14):
        mid = float(np.sqrt(lo * hi))
        lo, hi = (mid, hi) if _continued_from(mid, tau) == below else (lo, mid)
    assert hi / lo - 1 < 1e-5

    def table(s):
        return platelet_brdf_table(s, tau, source="kirchhoff", coherent="delta", cache=False)

    a, b, beside = table(lo), table(hi), table(lo * 0.999)
    wo, wt = hemisphere()
    for ti in (60.0, 70.0, 80.0):
        across, step = _l1(a, b, ti, wo, wt), _l1(beside, a, ti, wo, wt)
        assert across <= 0.01 * step, (ti, across, step)


BOX = [(0.01, 0.2), (0.01, 2.0), (0.3, 0.2), (0.3, 2.0), (0.051, 0.64)]


@functools.lru_cache(maxsize=None)
def box_table(sigma, tau, n):
    arrays, _ = platelet_table_arrays(sigma, tau, n_medium=n, num_profiles=8)
    return arrays, TabulatedBRDF.from_arrays(arrays, coherent="delta", n_medium=n)


@pytest.mark.parametrize("n", [1.5, 1.0])
@pytest.mark.parametrize("sigma,tau", BOX)
def test_energy_and_reciprocity_over_the_box(sigma, tau, n):
    """At the corners of σ 0.01–0.30 µm × τ 0.2–2.0 µm and at the measured roughness, in binder and
    air: the directional albedo (coherent part + independent hemisphere quadrature of the diffuse
    lobe) never exceeds the reflectance of the flat surface under the same impedance (Leontovich)
    boundary, r = (cosθ − η)/(cosθ + η), by more than 3 stated SE + 2e-3 (the solver's flat-surface
    discretisation error at its beam limit) at 0–85°, agrees with the table's stated albedo within
    1 % at the tabulated incidences, and the BRDF is reciprocal."""
    arrays, table = box_table(sigma, tau, n)
    wo, wt = hemisphere(240, 480)
    nodes = np.asarray(arrays["incidence_deg"])
    inc = np.concatenate([nodes[nodes <= 85.0], [85.0]])
    mu = np.cos(np.deg2rad(inc))
    se = np.interp(mu, np.cos(np.deg2rad(arrays["incidence_deg"]))[::-1], np.asarray(arrays["reflectance_se"])[::-1])
    root = np.sqrt((AL / n) ** 2)
    flat = 0.5 * (np.abs((mu - root) / (mu + root)) ** 2 + np.abs((mu - 1 / root) / (mu + 1 / root)) ** 2)
    for j, ti in enumerate(inc):
        wi = jnp.asarray(direction(ti))
        diffuse = float(np.sum(np.asarray(call(table, "incoherent", wi, wo)) * wt))
        albedo = diffuse + float(call(table, "coherent_reflectance", jnp.asarray(mu[j])))
        stated = float(call(table, "albedo", jnp.asarray(mu[j])))
        assert albedo <= flat[j] + 3 * se[j] + 2e-3, (ti, albedo, flat[j], se[j])
        if ti in nodes:
            assert abs(albedo - stated) <= 0.01 * stated, (ti, albedo, stated)
    rng = np.random.default_rng(0)
    a = direction(rng.uniform(0, 85, 200), rng.uniform(0, 360, 200))
    b = direction(rng.uniform(0, 85, 200), rng.uniform(0, 360, 200))
    fab, fba = np.asarray(call(table, "evaluate", jnp.asarray(a), jnp.asarray(b))), np.asarray(call(table, "evaluate", jnp.asarray(b), jnp.asarray(a)))
    np.testing.assert_allclose(fab, fba, rtol=1e-9, atol=1e-300)


@functools.lru_cache(maxsize=None)
def grid_and_direct():
    kw = dict(num_profiles=8)
    grid = platelet_brdf_grid([0.05, 0.1, 0.2], [0.3, 0.6, 1.2], coherent="delta", **kw)
    return grid.at(0.14, 0.39), platelet_brdf_table(0.14, 0.39, coherent="delta", **kw)


def test_grid_interpolation_conserves_energy():
    """The grid [0.05, 0.1, 0.2] × [0.3, 0.6, 1.2] µm at σ = 0.14, τ = 0.39 µm, between every node: the
    albedo (independent quadrature) equals the interpolated reflectance within 1 % (a direct table's own
    consistency between tabulated incidences, `test_table_reflectance_equals_source`) and a table built
    directly there within 3 % at 0–80° (it was 0.944 against 0.845 when the scale was interpolated
    separately from the lobe)."""
    between, direct = grid_and_direct()
    built = platelet_brdf_grid([0.05, 0.1, 0.2], [0.3, 0.6, 1.2], coherent="delta", num_profiles=8).build_at(0.14, 0.39)
    wo, wt = hemisphere()
    for ti in (0.0, 20.0, 40.0, 60.0, 80.0):
        wi, mu = jnp.asarray(direction(ti)), jnp.cos(jnp.deg2rad(ti))
        albedo = float(np.sum(np.asarray(call(between, "incoherent", wi, wo)) * wt)) + float(call(between, "coherent_reflectance", mu))
        assert abs(albedo / float(call(between, "albedo", mu)) - 1.0) <= 0.01, ti
        assert abs(albedo / float(call(direct, "albedo", mu)) - 1.0) <= 0.03, ti
        assert abs(float(call(built, "albedo", mu)) / float(call(direct, "albedo", mu)) - 1.0) <= 0.03, ti


def _l1(a, b, theta_i, wo, wt):
    wi = jnp.asarray(direction(theta_i))
    fa, fb = np.asarray(call(a, "incoherent", wi, wo)), np.asarray(call(b, "incoherent", wi, wo))
    return np.sum(np.abs(fa - fb) * wt) / np.sum(fb * wt)


FINE = 1.41  # node ratio of the grids below (the tracer forward map's default grid: 1.35 in σ, 1.41 in τ)


@functools.lru_cache(maxsize=None)
def fine_grid(sigma, tau, source):
    kw = dict(source=source) if source == "kirchhoff" else dict(num_profiles=8)  # the control variate leaves ~1e-3 relative SE here
    grid = platelet_brdf_grid([sigma / FINE, sigma, sigma * FINE], [tau / FINE, tau, tau * FINE], coherent="delta", **kw)
    return grid, kw


def mid_cells(sigma, tau):
    """The four mid-cell points of the grid about (σ, τ): the centres of its four cells."""
    r = np.sqrt(FINE)
    return [(sigma * a, tau * b) for b in (1 / r, r) for a in (1 / r, r)]


@functools.lru_cache(maxsize=None)
def direct_table(q, source):
    kw = dict(source=source) if source == "kirchhoff" else dict(num_profiles=8)
    return platelet_brdf_table(*q, coherent="delta", **kw)


GRID_CASES = [(0.051, 0.64, "wave"), (0.14, 0.39, "kirchhoff")]
GRID_INCIDENCES = (0.0, 40.0, 70.0, 80.0)


@pytest.mark.parametrize("sigma,tau,source", GRID_CASES)
def test_grid_built_table_within_3_percent_of_a_direct_table(sigma, tau, source):
    """A table built from the grid's in-plane lobes interpolated at the centre of each of the grid's
    four cells (`build_at`) is within 3 % of a table built there directly (scattered-power weighted L1)
    at 0°, 40°, 70° and 80°: the measured roughness with wave tables, and a steep surface (σ 0.14,
    τ 0.39 µm) with Kirchhoff-source tables (measured ≤ 2.6 %); at a node it is the node's table."""
    grid, kw = fine_grid(sigma, tau, source)
    wo, wt = hemisphere()
    for q in mid_cells(sigma, tau):
        built, direct = grid.build_at(*q), direct_table(q, source)
        for ti in GRID_INCIDENCES:
            assert _l1(built, direct, ti, wo, wt) <= 0.03, (q, ti, _l1(built, direct, ti, wo, wt))
    node = platelet_brdf_table(sigma, tau, coherent="delta", **kw)
    assert _l1(grid.build_at(sigma, tau), node, 0.0, wo, wt) < 1e-6
    with pytest.raises(ValueError, match="tau_um"):
        grid.build_at(sigma, 3.0 * tau)


_AT_OPEN = pytest.mark.xfail(strict=True, reason="`at` is more than 3 % from a direct table at 70–80° in this cell (open)")


@pytest.mark.parametrize("sigma,tau,source,cell", [
    *[(0.051, 0.64, "wave", cell) for cell in range(4)],
    *[pytest.param(0.14, 0.39, "kirchhoff", cell, marks=_AT_OPEN) for cell in range(4)],
])
def test_grid_at_within_3_percent_of_a_direct_table(sigma, tau, source, cell):
    """The differentiable path `at` (lobes aligned in width, then interpolated) within 3 % of a direct
    table at the centre of each grid cell, at 0°, 40°, 70° and 80°. Measured for the wave tables about
    the measured roughness 1.1–2.8 % in all four cells (up to 3.6 % at 80° before table version 11);
    for the steep surface 1.1–2.8 % at 0–40°, 2.0–3.5 % at 70° and 3.3–9.0 % at 80°: those cells are
    expected to fail."""
    grid, _ = fine_grid(sigma, tau, source)
    wo, wt = hemisphere()
    q = mid_cells(sigma, tau)[cell]
    between, direct = grid.at(*q), direct_table(q, source)
    errors = {ti: _l1(between, direct, ti, wo, wt) for ti in GRID_INCIDENCES}
    assert max(errors.values()) <= 0.03, errors
