"""`paintjax lobe`: full-wave scattering lobe of rough platelet profiles (synthesised or loaded)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ._common import add_json_argument, add_output_argument, print_json


def register(sub) -> None:
    p = sub.add_parser(
        "lobe",
        help="full-wave scattering lobe of rough platelet profiles (boundary-integral solver)",
        description="Profile-averaged bistatic coefficient σ(θ_s) [1/rad] of rough 1-D profiles in the binder "
        "(θ_s > 0 on the specular side), with its coherent part and the energy ledger.",
    )
    p.add_argument("--sigma", type=float, default=0.051, help="RMS roughness σ in µm (default 0.051)")
    p.add_argument("--tau", type=float, default=0.64, help="1/e correlation length τ in µm (default 0.64)")
    p.add_argument("--correlation", default="gaussian", choices=("gaussian", "exponential"), help="correlation function (default gaussian)")
    p.add_argument("--length", type=float, default=20.0, help="synthesised profile length in µm (default 20)")
    p.add_argument("--profiles", type=int, default=10, help="number of synthesised realisations (default 10)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--profile", help="two-column text/CSV file (x, height) used instead of synthesis")
    p.add_argument("--units", default="um", help="length unit of --profile: m, mm, um or nm (default um)")
    p.add_argument("--raw", action="store_true", help="use --profile as given (skip filtering and levelling)")
    p.add_argument("--incidence", type=float, nargs="+", default=[0.0], help="incidence angle(s) in degrees (default 0)")
    p.add_argument("--bc", default="impedance", choices=("impedance", "dirichlet", "neumann"), help="boundary condition (default impedance = aluminium)")
    p.add_argument("--pol", default="unpolarized", choices=("te", "tm", "unpolarized"), help="polarisation (default unpolarized)")
    p.add_argument("--wavelength", type=float, default=0.5, help="vacuum wavelength in µm (default 0.5)")
    p.add_argument("--n", type=float, default=1.5, help="binder refractive index (default 1.5)")
    p.add_argument("--ppw", type=float, help="points per wavelength in the binder (default 12)")
    p.add_argument("--step", type=float, default=0.5, help="θ_s grid step in degrees (default 0.5)")
    add_output_argument(p, "experiments/output/lobe")
    add_json_argument(p)
    p.set_defaults(func=run)


#: API argument → flag, for error messages.
API_FLAGS = {"sigma_um": "--sigma", "tau_um": "--tau", "wavelength_um": "--wavelength", "n_medium": "--n", "length_um": "--length",
             "num_profiles": "--profiles", "points_per_wavelength": "--ppw", "incidence_deg": "--incidence",
             "seed": "--seed", "profile must": "--profile must", "units must": "--units must"}


def flag_ranges(args) -> dict:
    """The validation layer's ranges (flag → `Range`), checked before any work: the wave solver's (`LOBE_RANGES`; the
    wavelength the aluminium model's for --bc impedance) and the θ_s grid step."""
    from .._validate import Range
    from ..wave._checks import LOBE_RANGES, OTHER_WAVELENGTHS

    wave = LOBE_RANGES if args.bc == "impedance" else LOBE_RANGES | {"wavelength_um": OTHER_WAVELENGTHS}
    return {flag: wave[api] for api, flag in API_FLAGS.items() if api in wave} | {"--step": Range(0.01, 10.0, "degrees")}


def compute(args) -> dict:
    """Solve and return the lobes and the energy ledger as plain arrays (the CLI's data)."""
    from .. import profile_averaged_lobes
    from .._progress import print_progress
    from ..wave._checks import check_energy
    from ..wave._profiles import load_line_scan, process_line_scan, profile_statistics, profiles_from_heights
    from ..wave._solver import default_spacing, solve_profiles

    theta_s = np.clip(np.arange(-90.0, 90.0 + 1e-9, args.step), -90.0, 90.0)
    if args.profile:
        scan = load_line_scan(args.profile, units=args.units)
        if args.raw:
            x, h = scan.x, scan.h
        else:
            x, h = process_line_scan(scan)
        spacing = default_spacing(args.wavelength, args.n, args.ppw)
        prof = profiles_from_heights(x, h, spacing)
        stats = profile_statistics(np.asarray(prof.h[0]), prof.spacing)
        lobes = solve_profiles(prof, args.incidence, theta_s, wavelength_um=args.wavelength, n_medium=args.n, boundary=args.bc,
                               polarization=args.pol, heartbeat=print_progress("lobe", "of the profile solved"))
        source = {"file": str(args.profile), "length_um": prof.length, "sigma_um": float(stats["sigma_um"]), "tau_um": float(stats["tau_um"])}
    else:
        lobes = profile_averaged_lobes(
            args.sigma, args.tau, length_um=args.length, num_profiles=args.profiles, seed=args.seed,
            incidence_deg=args.incidence, theta_s_deg=theta_s, wavelength_um=args.wavelength, n_medium=args.n,
            boundary=args.bc, polarization=args.pol, correlation=args.correlation, points_per_wavelength=args.ppw,
            heartbeat=print_progress("lobe", f"of {args.profiles} profiles solved"),
        )
        source = {"synthesised": args.correlation, "profiles": args.profiles, "seed": args.seed, "length_um": args.length,
                  "sigma_um": args.sigma, "tau_um": args.tau}
    check_energy(lobes.reflected, lobes.absorbed, np.asarray(lobes.incidence_deg), what="the wave solution",
                 fix="more points per wavelength (--ppw), a gentler slope, or a longer --length")
    return {"lobes": lobes, "source": source}


def _squeeze(a):
    a = np.asarray(a)
    return a[0] if a.shape[0] == 1 else a


def run(args) -> int:
    r = compute(args)
    lobes = r["lobes"]
    out = {
        "theta_s_deg": np.asarray(lobes.theta_s_deg),
        "incidence_deg": _squeeze(lobes.incidence_deg),
        "sigma": _squeeze(lobes.sigma),
        "sigma_coherent": _squeeze(lobes.sigma_coherent),
        "energy": {"scattered": _squeeze(lobes.reflected), "absorbed": _squeeze(lobes.absorbed)},
    }
    path = _plot(lobes, r["source"], Path(args.out))
    if args.json:
        print_json(out)
        return 0
    print(f"Full-wave lobe ({args.bc}, {args.pol}), λ0 = {args.wavelength} µm in n = {args.n}; source: {r['source']}")
    print(f"{'θ_i':>6} {'peak σ':>9} {'at θ_s':>7} {'coherent':>9} {'scattered':>10} {'absorbed':>9} {'sum':>7}")
    th = np.asarray(lobes.theta_s_deg)
    rad = np.radians(th)
    for i, ti in enumerate(np.asarray(lobes.incidence_deg)):
        s = np.asarray(lobes.sigma[i])
        coh = float(np.trapezoid(np.asarray(lobes.sigma_coherent[i]), rad))
        print(f"{ti:>5.1f}° {s.max():>9.4f} {th[np.argmax(s)]:>6.1f}° {coh:>9.4f} {float(lobes.reflected[i]):>10.4f} "
              f"{float(lobes.absorbed[i]):>9.4f} {float(lobes.energy[i]):>7.4f}")
    print(f"plot: {path}")
    return 0


def _plot(lobes, source, folder: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .._io import atomic_savefig

    fig, ax = plt.subplots(figsize=(6, 4))
    th = np.asarray(lobes.theta_s_deg)
    for i, ti in enumerate(np.asarray(lobes.incidence_deg)):
        ax.plot(th, np.asarray(lobes.sigma[i]), label=f"θ_i = {ti:g}° total")
        ax.plot(th, np.asarray(lobes.sigma_coherent[i]), "--", lw=0.8, label=f"θ_i = {ti:g}° coherent")
    ax.set_xlabel("θ_s [deg] (> 0: specular side)")
    ax.set_ylabel("σ [1/rad]")
    ax.set_title(f"{lobes.boundary}, {lobes.polarization}: σ = {source.get('sigma_um', 0):.3g} µm, τ = {source.get('tau_um', 0):.3g} µm", fontsize=9)
    ax.legend(fontsize=7)
    path = folder / "lobe.png"
    atomic_savefig(fig, path)
    plt.close(fig)
    return path
