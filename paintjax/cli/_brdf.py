"""`paintjax brdf`: build (or load from the cache) a platelet BRDF table and plot it."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from .._progress import print_progress
from .._validate import SEED
from ..wave._checks import LOBE_RANGES
from ._common import add_json_argument, add_output_argument, print_json

CUT_INCIDENCE_DEG = (0.0, 20.0, 40.0, 60.0)
THETA_O_DEG = np.arange(-89.0, 90.0, 1.0)


#: API argument → flag, for error messages.
API_FLAGS = {"sigma_um": "--sigma", "tau_um": "--tau", "wavelength_um": "--wavelength", "n_medium": "--n", "length_um": "--length", "num_profiles": "--profiles", "cache_dir": "--cache-dir"}


#: The validation layer's ranges (flag → `Range`), checked before any work: the wave solver's (the tables' too, either source).
RANGES = {"--sigma": LOBE_RANGES["sigma_um"], "--tau": LOBE_RANGES["tau_um"], "--wavelength": LOBE_RANGES["wavelength_um"],
          "--n": LOBE_RANGES["n_medium"], "--profiles": LOBE_RANGES["num_profiles"], "--length": LOBE_RANGES["length_um"], "--seed": SEED}


def register(sub) -> None:
    p = sub.add_parser(
        "brdf",
        help="platelet BRDF table from wave lobes (cached): in-plane cuts and a plot",
        description="Tabulated platelet BRDF (inverse-Abel 2-D → 3-D of profile-averaged wave lobes), cached on disk.",
    )
    p.add_argument("--sigma", type=float, default=0.051, help="rms roughness σ in µm (default 0.051)")
    p.add_argument("--tau", type=float, default=0.64, help="correlation length τ in µm (default 0.64)")
    p.add_argument("--wavelength", type=float, default=0.5, help="vacuum wavelength in µm (default 0.5)")
    p.add_argument("--n", type=float, default=1.5, help="binder index (default 1.5)")
    p.add_argument("--profiles", type=int, default=None, help="number of profiles averaged (default 40, the tables' default)")
    p.add_argument("--length", type=float, default=20.0, help="profile length in µm (default 20)")
    p.add_argument("--seed", type=int, default=0, help="profile seed (default 0)")
    p.add_argument("--source", choices=("wave", "kirchhoff"), default="wave", help="lobe source (default wave)")
    p.add_argument("--method", choices=("abel", "rotate"), default="abel", help="2-D → 3-D step (default abel)")
    p.add_argument("--cache-dir", default=None, help="cache folder (default $PAINTJAX_CACHE or ~/.cache/paintjax)")
    p.add_argument("--no-cache", action="store_true", help="build without reading or writing the cache")
    add_output_argument(p, "experiments/output/brdf")
    add_json_argument(p)
    p.set_defaults(func=run)


def compute(sigma=0.051, tau=0.64, wavelength=0.5, n=1.5, profiles=None, length=20.0, seed=0, source="wave", method="abel", cache_dir=None, cache=True) -> dict:
    """Table, in-plane cuts and reflectances as a plain dict (the CLI's JSON plus extras)."""
    import jax.numpy as jnp

    from ..brdf._analytic import coherent_lobe_width
    from ..brdf._in_plane import DEFAULT_NUM_PROFILES
    from ..brdf._table import TabulatedBRDF, platelet_table_arrays

    profiles = DEFAULT_NUM_PROFILES if profiles is None else profiles
    t0 = time.perf_counter()
    arrays, info = platelet_table_arrays(
        sigma, tau, source=source, wavelength_um=wavelength, n_medium=n, num_profiles=profiles, length_um=length,
        seed=seed, method=method, cache=cache, cache_dir=cache_dir, heartbeat=print_progress("brdf", f"of {profiles} profiles solved"),
    )
    table = TabulatedBRDF.from_arrays(arrays, coherent_width=coherent_lobe_width(wavelength, n, 16.0), n_medium=n)
    inc = np.asarray(CUT_INCIDENCE_DEG)
    cuts = np.asarray(table.in_plane(inc, THETA_O_DEG))
    refl = np.asarray(table.albedo(jnp.cos(jnp.deg2rad(inc))))
    return {
        "incidence_deg": inc,
        "theta_o_deg": THETA_O_DEG,
        "brdf": cuts,
        "reflectance": refl,
        "table": table,
        "arrays": arrays,
        "cache_hit": info["cache_hit"],
        "seconds": time.perf_counter() - t0,
    }


def plot(result: dict, path: Path, title: str) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import jax.numpy as jnp
    import matplotlib.pyplot as plt

    from .._io import atomic_savefig

    table = result["table"]
    g = np.linspace(-0.8, 0.8, 161)
    bx, by = np.meshgrid(g, g, indexing="ij")
    inside = bx**2 + by**2 < 1.0
    wo = np.stack([bx, by, np.sqrt(np.clip(1 - bx**2 - by**2, 1e-12, 1))], -1)
    f0 = np.asarray(table.incoherent(jnp.asarray([0.0, 0.0, 1.0]), jnp.asarray(wo))) * inside
    fig, ax = plt.subplots(1, 2, figsize=(11, 4.4))
    im = ax[0].imshow(np.where(inside, f0 / f0.max(), np.nan).T, origin="lower", extent=(g[0], g[-1], g[0], g[-1]), cmap="magma")
    fig.colorbar(im, ax=ax[0], label="f / max f (incoherent)")
    ax[0].set(xlabel="β_x", ylabel="β_y", title="normal incidence, direction cosines")
    for i, th in enumerate(result["incidence_deg"]):
        ax[1].semilogy(result["theta_o_deg"], np.maximum(result["brdf"][i], 1e-6), label=f"θ_i = {th:g}°, R = {result['reflectance'][i]:.3f}")
    ax[1].set(xlabel="θ_o (° , > 0 specular side)", ylabel="f [1/sr]", title="in-plane cuts", ylim=(1e-3, None))
    ax[1].legend(fontsize=8)
    fig.suptitle(title)
    atomic_savefig(fig, path)
    plt.close(fig)
    return path


def run(args) -> int:
    from .._io import atomic_write_json

    r = compute(args.sigma, args.tau, args.wavelength, args.n, args.profiles, args.length, args.seed, args.source, args.method, args.cache_dir, not args.no_cache)
    out = Path(args.out)  # the files are written with --json too, as by simulate and table1
    png = plot(r, out / "brdf.png", f"platelet BRDF σ = {args.sigma:g} µm, τ = {args.tau:g} µm ({args.source}, {args.method})")
    data = {k: r[k] for k in ("incidence_deg", "theta_o_deg", "brdf", "reflectance")}
    a = r["arrays"]
    data["table"] = {k: np.asarray(a[k]) for k in ("incidence_deg", "reflectance", "reflectance_se", "coherent_reflectance",
                                                   "coherent_reflectance_se", "lobe_relative_se", "absorbed")}
    atomic_write_json(out / "brdf.json", data)
    if args.json:
        print_json(data)
        return 0
    print(f"platelet BRDF table σ = {args.sigma:g} µm, τ = {args.tau:g} µm, λ0 = {args.wavelength:g} µm, n = {args.n:g} "
          f"({args.source}, {args.method}; {'loaded from cache' if r['cache_hit'] else 'built'} in {r['seconds']:.1f} s)")
    print(f"{'θ_i':>6} {'reflected ± SE':>17} {'coherent ± SE':>19} {'absorbed':>9} {'outside':>8} {'lobe SE':>8}")
    for row in zip(a["incidence_deg"], a["reflectance"], a["reflectance_se"], a["coherent_reflectance"], a["coherent_reflectance_se"],
                   a["absorbed"], a["outside_fraction"], a["lobe_relative_se"]):
        print(f"{row[0]:>5.0f}° {row[1]:>8.4f} ± {row[2]:.4f} {row[3]:>9.2e} ± {row[4]:.1e} {row[5]:>9.4f} {row[6]:>8.4f} {row[7]:>7.2%}")
    print(f"plot: {png}")
    return 0
