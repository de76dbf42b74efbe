"""Physics checks of the full-wave platelet solver (paintjax.wave._solver) and its closed-form references.

Surfaces are 10 µm long (taper g = 2.5 µm, N = 360 at the default 12 points per wavelength) so the
whole file runs in a couple of minutes on two cores; the physics does not need longer ones.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import paintjax
from paintjax.wave._beam import incident_field, incident_gradient, max_incidence_deg
from paintjax.wave._closed_forms import kirchhoff_sigma, spm_sigma, spm_sigma_realisation
from paintjax.wave._profiles import Profiles, grid, synthesize_profiles
from paintjax.wave._solver import channels, default_spacing, flat_profiles, scattering_amplitudes, solve_profiles, surface_fields

LAM, N_MED = 0.5, 1.5
K = 2 * np.pi * N_MED / LAM
DX = default_spacing(LAM, N_MED)
L = 10.0


@pytest.fixture(scope="module")
def platelet_pair():
    """Two realisations of the platelet roughness (σ = 51 nm, τ = 640 nm)."""
    return synthesize_profiles(jax.random.PRNGKey(11), 0.051, 0.64, length_um=L, spacing_um=DX, num_profiles=2)


def _analytic(length, spacing, scale=1.0):
    """A fixed smooth rough profile (sum of sines, σ ≈ 57 nm, slopes ≲ 0.3) on any grid."""
    x, dx = grid(length, spacing)
    amps = scale * np.array([0.04, 0.03, 0.05, 0.02, 0.015])
    ks = 2 * np.pi / np.array([2.3, 1.1, 0.83, 0.61, 0.47])
    ph = np.array([0.3, 1.9, 4.0, 2.2, 5.1])
    arg = ks[:, None] * x[None, :] + ph[:, None]
    h = (amps[:, None] * np.sin(arg)).sum(0)
    dh = (amps[:, None] * ks[:, None] * np.cos(arg)).sum(0)
    d2h = -(amps[:, None] * ks[:, None] ** 2 * np.sin(arg)).sum(0)
    return Profiles(jnp.asarray(x), jnp.asarray(h)[None], jnp.asarray(dh)[None], jnp.asarray(d2h)[None], float(dx))


@pytest.mark.parametrize("boundary", ["dirichlet", "neumann"])
def test_pec_energy_conservation(platelet_pair, boundary):
    """|∫σ dθ_s − 1| ≤ 2e-3 for the perfect conductor at the default discretisation (TE and TM).

    Angles up to 30°: for a Neumann (TM) surface of finite length, waves scattered to grazing
    angles run off the truncated ends and are lost below the horizon (physics of the truncation,
    not of the discretisation), which limits the check at larger angles.
    """
    r = solve_profiles(platelet_pair, [0.0, 20.0, 30.0], [0.0], boundary=boundary)
    err = np.abs(np.asarray(r.reflected) - 1.0)
    assert err.max() <= 2e-3, err
    assert np.all(np.asarray(r.absorbed) == 0.0)


@pytest.mark.parametrize("pol", ["te", "tm"])
def test_flat_impedance_matches_fresnel(pol):
    """Flat Al in n = 1.5: the solver reproduces the Leontovich reflectance to 5e-4, and the exact
    Fresnel reflectance within the Leontovich bound |R_L − R| (≤ 1e-2 up to 60° here: the exact
    √(ε_r − sin²θ) is replaced by √ε_r, a relative error sin²θ/(2|ε_r|) ≤ 2.4 % in η with
    |ε_r| = 15.7 at 500 nm; 0 at normal incidence, 2.6e-3 (TM) at 30°), and
    reflected + absorbed = 1 to 5e-4.
    """
    inc = np.array([0.0, 30.0, 60.0])
    flat = flat_profiles(L, DX)
    flat = Profiles(flat.x, jnp.tile(flat.h, (2, 1)), jnp.tile(flat.dh, (2, 1)), jnp.tile(flat.d2h, (2, 1)), flat.spacing)
    r = solve_profiles(flat, inc, [0.0], boundary="impedance", polarization=pol)
    m = complex(np.asarray(paintjax.aluminium_index(LAM)))
    eps_r = m**2 / N_MED**2
    c = np.cos(np.radians(inc))
    eta = np.sqrt(eps_r) if pol == "te" else 1 / np.sqrt(eps_r)
    R_leontovich = np.abs((c - eta) / (c + eta)) ** 2
    Rs, Rp, _ = paintjax.fresnel_conductor(c, N_MED, m)
    R_exact = np.asarray(Rs if pol == "te" else Rp)
    got = np.asarray(r.reflected)
    bound = np.abs(R_leontovich - R_exact)
    assert bound.max() <= 1.2e-2 and bound[0] <= 1e-12
    assert np.max(np.abs(got - R_leontovich)) <= 5e-4
    assert np.all(np.abs(got - R_exact) <= bound + 5e-4)
    assert np.max(np.abs(np.asarray(r.energy) - 1.0)) <= 5e-4
    assert np.all(np.asarray(r.absorbed) > 0.05)


def test_reciprocity_plane_waves_dirichlet(platelet_pair):
    """One realisation, plane-wave incidence: ψ_s^N(θ_i→θ_s) = ψ_s^N(−θ_s→−θ_i) to round-off
    (the discrete single-layer operator is symmetric, so reciprocity holds exactly)."""
    one = Profiles(platelet_pair.x, platelet_pair.h[:1], platelet_pair.dh[:1], platelet_pair.d2h[:1], platelet_pair.spacing)
    angles = [-50.0, -15.0, 0.0, 12.0, 25.0, 40.0]
    a = np.asarray(scattering_amplitudes(one, angles, [-t for t in angles], boundary="dirichlet", taper_um=np.inf))[0, 0]
    # a[i, j] = ψ(θ_i → −θ_j); reciprocity: ψ(θ_i → −θ_j) = ψ(θ_j → −θ_i)
    assert np.max(np.abs(a - a.T)) <= 1e-10 * np.max(np.abs(a))


@pytest.mark.parametrize("boundary, pol", [("dirichlet", "te"), ("neumann", "te"), ("impedance", "te"), ("impedance", "tm")])
def test_reciprocity_beam_coupling(platelet_pair, boundary, pol):
    """One realisation, tapered beams a, b: the coupling C(a→b) = ∫(ψ_a ∂_n b − b ∂_n ψ_a) ds equals
    C(b→a) (Lorentz reciprocity; with b a plane wave from −θ_s, C(a→b) is ψ_s^N(θ_s)).

    The σ of two tapered-beam set-ups is reciprocal only in the ensemble mean (each beam is a spread
    of plane waves over ~1/(kg) rad, the width of a speckle), so the single-realisation check uses the
    couplings. Tolerance 1e-4 of the largest coupling: the Thorsos beam solves Helmholtz only to
    O((kg cosθ)⁻²), which sets the level for the second-kind (Neumann, impedance) equations.
    """
    one = Profiles(platelet_pair.x, platelet_pair.h[:1], platelet_pair.dh[:1], platelet_pair.d2h[:1], platelet_pair.spacing)
    angles = [-30.0, -15.0, 0.0, 12.0, 25.0]
    g = L / 4
    rad = jnp.radians(jnp.asarray(angles))
    x, h, dh = one.x, one.h[0], one.dh[0]
    b = np.asarray(incident_field(x, h, rad, K, g))
    bx, bz = incident_gradient(x, h, rad, K, g)
    dnb = np.asarray(-dh[:, None] * bx + bz)  # ∂b/∂n · ds/dx
    psi = np.asarray(surface_fields(one, angles, boundary=boundary, polarization=pol))[0, 0]
    if boundary == "dirichlet":
        C = -(b.T @ psi) * one.spacing  # ψ = 0, U = ∂ψ/∂n ds/dx
    else:
        eta = channels(boundary, pol)[0][1]
        dnpsi = -1j * K * eta * psi * np.sqrt(1 + np.asarray(dh) ** 2)[:, None]
        C = (dnb.T @ psi - b.T @ dnpsi) * one.spacing
    # C[j, i] = C(a_i → b_j) with b_j the beam from θ_j: reversing a_i → b_j is a_j → b_i
    assert np.max(np.abs(C - C.T)) <= 1e-4 * np.max(np.abs(C))


@pytest.mark.parametrize("boundary", ["dirichlet", "neumann"])
def test_small_perturbation_limit(boundary):
    """kσ = 0.1, kτ = 2.8: the solver matches first-order SPM.

    Compared realisation by realisation with the deterministic SPM field of the same profiles and
    beam (no sampling noise), away from the specular beam (|θ_s − θ_i| > 5°): the angle-integrated
    incoherent power within 3 % (second-order corrections are O((kσ)²) = 1 %), 20° bins within 20 %
    (single-realisation cross terms between first- and second-order fields are O(kσ) = 10 % and
    average out only over the ensemble). The ensemble closed form agrees within the realised
    roughness spread (15 %).
    """
    sig, tau, R = 0.1 / K, 0.15, 4
    prof = synthesize_profiles(jax.random.PRNGKey(4), sig, tau, length_um=L, spacing_um=DX, num_profiles=R)
    ths = np.arange(-80.0, 80.01, 0.5)
    inc = [0.0, 30.0]
    r = solve_profiles(prof, inc, ths, boundary=boundary, control_variate=False)  # these realisations' mean, not the ensemble's
    realised = np.asarray(spm_sigma_realisation(prof, inc, ths, boundary=boundary)).mean(0)
    ensemble = np.asarray(spm_sigma(inc, ths, sig, tau, boundary=boundary))
    s = np.asarray(r.sigma)
    rad = np.radians(ths)
    for i, ti in enumerate(inc):
        m = np.abs(ths - ti) > 5.0
        total = np.trapezoid(np.where(m, s[i], 0), rad)
        assert abs(total / np.trapezoid(np.where(m, realised[i], 0), rad) - 1) <= 0.03
        assert abs(total / np.trapezoid(np.where(m, ensemble[i], 0), rad) - 1) <= 0.15
        for lo in range(-80, 80, 20):
            b = (ths >= lo) & (ths < lo + 20) & m
            assert abs(s[i, b].mean() / realised[i, b].mean() - 1) <= 0.2, (ti, lo)


def test_kirchhoff_platelet_regime():
    """kσ = 0.96, kτ = 12 (the platelet roughness), PEC TE, 16 realisations: the incoherent lobe
    core (|θ_s − θ_i| ≤ 15°) integrates to the Kirchhoff value within 8 % + 3 standard errors.

    Kirchhoff's own error here is a few % (curvature corrections O(1/(kτ)), slopes 6° so no
    shadowing); the statistical error of 16 × 10 µm profiles is ~3 % on the core integral.
    """
    R = 16
    prof = synthesize_profiles(jax.random.PRNGKey(3), 0.051, 0.64, length_um=L, spacing_um=DX, num_profiles=R)
    ths = np.arange(-35.0, 35.01, 0.5)
    inc = [0.0, 20.0]
    r = solve_profiles(prof, inc, ths, boundary="dirichlet")
    incoh = np.asarray(r.sigma_incoherent)  # the coherent part is the unbiased estimate
    ka = np.asarray(kirchhoff_sigma(inc, ths, 0.051, 0.64, boundary="pec"))
    sem = np.asarray(r.sigma_sem)
    rad = np.radians(ths)
    for i, ti in enumerate(inc):
        core = np.abs(ths - ti) <= 15.0
        got, want = np.trapezoid(incoh[i, core], rad[core]), np.trapezoid(ka[i, core], rad[core])
        # speckle ~1/(kg) = 1.2° wide: ~25 independent values in the core per realisation
        se = np.trapezoid(sem[i, core], rad[core]) / np.sqrt(core.sum() * 0.5 / 1.2)
        assert abs(got - want) <= 0.08 * want + 3 * se, (ti, got, want, se)
        assert np.asarray(r.energy)[i] == pytest.approx(1.0, abs=2e-3)


def test_convergence_points_per_wavelength():
    """The lobe of one fixed surface (PEC TM, the harder polarisation) converges as the sampling
    grows: 8 → 12 points per wavelength against 24, to 2e-3 of the peak at the default 12."""
    ths = np.arange(-60.0, 60.01, 1.0)
    lobes = {}
    for ppw in (8, 12, 24):
        p = _analytic(6.0, default_spacing(LAM, N_MED, ppw))
        lobes[ppw] = np.asarray(solve_profiles(p, [0.0, 30.0], ths, boundary="neumann").sigma)
    err = {ppw: np.max(np.abs(lobes[ppw] - lobes[24])) / lobes[24].max() for ppw in (8, 12)}
    assert err[8] > err[12]
    assert err[12] <= 2e-3, err


def test_convergence_surface_length():
    """With the beam fixed (g = 1.5 µm), central cuts 6, 8, 12 µm of one 16 µm realisation converge
    monotonically to its lobe, to 1e-4 at 12 µm (PEC TE). (For TM, waves scattered to grazing run
    along the surface and reach the ends, so its truncation error decays more slowly, ~5e-4.)"""
    full = synthesize_profiles(jax.random.PRNGKey(5), 0.051, 0.64, length_um=16.0, spacing_um=1 / 36, num_profiles=1)
    n_full = full.x.shape[0]

    def cut(n):
        sl = slice((n_full - n) // 2, (n_full + n) // 2)
        return Profiles(full.x[sl], full.h[:, sl], full.dh[:, sl], full.d2h[:, sl], full.spacing)

    ths = np.arange(-60.0, 60.01, 1.0)
    sizes = (216, 288, 432)  # 6, 8, 12 µm
    ref = np.asarray(solve_profiles(full, [0.0, 20.0], ths, boundary="dirichlet", taper_um=1.5).sigma)
    err = [np.max(np.abs(np.asarray(solve_profiles(cut(n), [0.0, 20.0], ths, boundary="dirichlet", taper_um=1.5).sigma) - ref)) / ref.max() for n in sizes]
    assert err[0] > err[1] > err[2] and err[2] <= 1e-4, err


def test_profile_averaged_lobes_contract():
    """The public entry point: shapes, symmetry of the conventions, energy ledger, coherent part."""
    inc = np.array([0.0, 20.0])
    ths = np.linspace(-80.0, 80.0, 33)
    r = paintjax.profile_averaged_lobes(0.051, 0.64, length_um=8.0, num_profiles=2, seed=1, incidence_deg=inc, theta_s_deg=ths)
    assert r.sigma.shape == (2, 33) and r.sigma_coherent.shape == (2, 33) and r.reflected.shape == (2,)
    assert np.all(np.isfinite(np.asarray(r.sigma))) and np.all(np.asarray(r.sigma) >= 0)
    assert np.all(np.asarray(r.sigma_coherent) <= np.asarray(r.sigma) + 1e-12)
    np.testing.assert_allclose(np.asarray(r.energy), 1.0, atol=2e-3)
    assert 0.8 < float(r.reflected[0]) < 0.95  # Al in the binder: ~12 % absorbed
    # the lobe of the 20° incidence peaks on the specular side
    assert ths[np.argmax(np.asarray(r.sigma[1]))] > 0


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(incidence_deg=[89.0]), "incidence_deg"),
        (dict(theta_s_deg=[95.0]), "theta_s_deg"),
        (dict(boundary="soft"), "boundary"),
        (dict(polarization="circular"), "polarization"),
        (dict(wavelength_um=-0.5), "wavelength_um"),
        (dict(points_per_wavelength=2.0), "points_per_wavelength"),
        (dict(metal_index=1.5 + 0j), "metal_index"),
        (dict(sigma_um=-1.0), "sigma_um"),
        (dict(wavelength_um=15.0), r"wavelength_um must lie in \[0.2, 12.0\] µm \(Lorentz–Drude validity\)"),
        (dict(n_medium=0.5), r"n_medium must lie in \[1.0, 5.0\]"),
        (dict(seed=-1), "seed must be an integer ≥ 0"),
        (dict(num_profiles=2.5), "num_profiles must be an integer in"),
        (dict(length_um=0.5), "length_um must be at least 1.06 µm at this wavelength_um and n_medium"),
        (dict(tau_um=0.1, points_per_wavelength=4.0), "tau_um must be at least two grid steps.*raise points_per_wavelength"),
    ],
)
def test_bad_input_raises(kwargs, match):
    args = dict(sigma_um=0.051, tau_um=0.64, length_um=8.0, num_profiles=1, incidence_deg=[0.0], theta_s_deg=[0.0]) | kwargs
    with pytest.raises(ValueError, match=match):
        paintjax.profile_averaged_lobes(args.pop("sigma_um"), args.pop("tau_um"), **args)


def test_max_incidence():
    assert 70.0 < max_incidence_deg(20.0) < 80.0
    assert max_incidence_deg(8.0) < max_incidence_deg(20.0)
    with pytest.raises(ValueError, match="taper_um must be at least"):
        max_incidence_deg(20.0, taper_um=0.05)


@pytest.mark.parametrize("pol", ["te", "tm"])
def test_flat_metal_holds_up_to_the_largest_accepted_incidence(pol):
    """At `max_incidence_deg` the beam is still a beam: flat Al of a 20 µm profile reflects within
    5e-3 of Leontovich's reflectance and conserves energy to 5e-3 (measured 2e-3; at the earlier
    limit, beam correction 0.1 and 79.5°, R was off by 3.9 % in TE and energy by 16 % in TM)."""
    theta = max_incidence_deg(20.0, LAM, N_MED)
    flat = flat_profiles(20.0, DX)
    r = solve_profiles(flat, [theta], [0.0], boundary="impedance", polarization=pol)
    m = complex(np.asarray(paintjax.aluminium_index(LAM)))
    eta = np.sqrt(m**2 / N_MED**2) if pol == "te" else 1 / np.sqrt(m**2 / N_MED**2)
    c = np.cos(np.radians(theta))
    R_leontovich = abs((c - eta) / (c + eta)) ** 2
    assert abs(float(np.ravel(r.reflected)[0]) - R_leontovich) <= 5e-3
    assert np.max(np.abs(np.asarray(r.energy) - 1.0)) <= 5e-3


def test_cli_lobe_json(tmp_path, capsys):
    """`paintjax lobe --json` on a synthesised and on a loaded (nm, CSV) profile."""
    import json

    from paintjax.cli._main import main

    rc = main(["lobe", "--profiles", "1", "--length", "6", "--step", "2", "--json", "--out", str(tmp_path / "a")])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and set(out) >= {"theta_s_deg", "sigma", "sigma_coherent", "energy"}
    assert len(out["sigma"]) == len(out["theta_s_deg"]) == 91
    assert out["energy"]["scattered"] + out["energy"]["absorbed"] == pytest.approx(1.0, abs=2e-3)
    assert (tmp_path / "a" / "lobe.png").exists()
    p = synthesize_profiles(jax.random.PRNGKey(2), 0.051, 0.64, length_um=6.0, spacing_um=0.01, num_profiles=1)
    x = np.asarray(p.x) - float(p.x[0])
    np.savetxt(tmp_path / "scan.csv", np.c_[x * 1e3, (np.asarray(p.h[0]) + 0.2 * (x / 6.0) ** 2) * 1e3], delimiter=",", header="x,z", comments="")
    rc = main(["lobe", "--profile", str(tmp_path / "scan.csv"), "--units", "nm", "--step", "2", "--json", "--out", str(tmp_path / "b")])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and out["energy"]["scattered"] + out["energy"]["absorbed"] == pytest.approx(1.0, abs=2e-3)
    assert main(["lobe", "--incidence", "89", "--profiles", "1", "--length", "6"]) == 2
    assert "--incidence" in capsys.readouterr().err


#: Shapes shared by the two chunking tests (one compilation each for 3 and 7 profiles).
CHUNK_CASE = {"sigma": 0.051, "tau": 0.64, "length": 4.0, "step": 2.0, "profiles": 7, "chunk": 3}


def test_chunked_solve_equals_one_shot_and_reports_progress(monkeypatch):
    """Profiles solved in chunks of 3 (the last padded) give the one-shot lobes, coherent part, SEs and ledger
    to rounding; the heartbeat reports between chunks, not after the last."""
    import paintjax._progress as progress

    monkeypatch.setattr(progress, "HEARTBEAT_SECONDS", 0.0)
    c = CHUNK_CASE
    dx = default_spacing(0.5, 1.5, sigma_um=c["sigma"], tau_um=c["tau"])
    p = synthesize_profiles(jax.random.PRNGKey(4), c["sigma"], c["tau"], length_um=c["length"], spacing_um=dx, num_profiles=c["profiles"])
    ths = np.clip(np.arange(-90.0, 90.0 + 1e-9, c["step"]), -90.0, 90.0)
    beats = []
    one = solve_profiles(p, [0.0], ths, chunk_size=c["profiles"])
    chunked = solve_profiles(p, [0.0], ths, chunk_size=c["chunk"], heartbeat=lambda f, s: beats.append((f, s)))
    for name in ("sigma", "sigma_coherent", "sigma_sem", "reflected", "reflected_se", "coherent_reflectance", "coherent_reflectance_se", "absorbed"):
        a, b = np.asarray(getattr(one, name)), np.asarray(getattr(chunked, name))
        np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-14 * max(np.abs(a).max(), 1e-300), err_msg=name)
    assert chunked.num_profiles == 7 and [f for f, _ in beats] == [3 / 7, 6 / 7] and all(s >= 0 for _, s in beats)


def test_cli_lobe_prints_progress_with_time_left(tmp_path, monkeypatch, capsys):
    """`paintjax lobe` prints a progress line with the time left between chunks (interval 0 here, 5 s by default)."""
    import paintjax._progress as progress
    import paintjax.wave._solver as solver
    from paintjax.cli._main import main

    monkeypatch.setattr(progress, "HEARTBEAT_SECONDS", 0.0)
    monkeypatch.setattr(solver, "PROFILE_CHUNK", CHUNK_CASE["chunk"])
    c = CHUNK_CASE
    argv = ["lobe", "--profiles", str(c["profiles"]), "--length", str(c["length"]), "--step", str(c["step"]), "--json", "--out", str(tmp_path)]
    assert main(argv) == 0
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(lines) == 2 and lines[0].startswith("  lobe: 43 % of 7 profiles solved") and " s left" in lines[0], lines
