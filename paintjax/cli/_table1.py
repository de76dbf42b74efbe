"""`paintjax table1` (the main job): five-angle L* of Silver #1 and #2 from their measured microstructure.

Columns: the measurement; the hybrid model (wave-based platelet BRDF from σ, τ through the ray
tracer); mirror platelets through the same tracer (finite aperture, see `simulate`); the analytic
single-scatter model of mirror platelets, with the entry and exit paths correlated over the
sample's platelet widths (`paintjax.instrument._hot_spot`). Nothing is tuned to the measurement.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from .._cache import enable_compilation_cache
from .._pipeline import DEFAULT_TARGET_SE, MIRROR_APERTURE_DEG, check_adaptive, flop_index_or_none, simulate
from .._validate import SEED, Range
from ..optics._interface import MAX_WAVINESS_DEG
from ..tracer._trace import MAX_RAYS
from ._common import add_json_argument, add_output_argument, format_optional, print_json

SAMPLES = ("silver1", "silver2")
#: The validation layer's ranges (flag → `Range`), checked before any work (also `paintjax demo`'s).
RANGES = {"--target-se": Range(0.0, 10.0, "L*", lo_open=True), "--max-rays": Range(32, MAX_RAYS, integer=True),
          "--mirror-rays": Range(32, MAX_RAYS, integer=True), "--seed": SEED, "--waviness": Range(0.0, MAX_WAVINESS_DEG, "degrees")}
#: Ray ceiling per sample of the hybrid column (all passes). The narrow coherent lobe of the platelets
#: makes 75°/110° spiky: SE ≤ 0.5 took 1.48 M rays for Silver #1 with the forward tracer alone and
#: 131 k with bidirectional MIS (seed 0); the ceiling guards against the heavy tail.
DEFAULT_MAX_RAYS = 1_500_000


def register(sub) -> None:
    p = sub.add_parser(
        "table1",
        help="the main job: measured vs hybrid, mirror and analytic five-angle L* of Silver #1 and #2",
        description="Five-angle lightness of both reference samples from their measured microstructure: "
        "measured, hybrid ray-wave model, mirror platelets through the same tracer, analytic single scatter.",
    )
    add_arguments(p)


def add_arguments(p) -> None:
    """The options of table1 (shared with `paintjax demo`, which runs the same job)."""
    p.add_argument("--target-se", type=float, default=DEFAULT_TARGET_SE,
                   help=f"L* standard error to reach at every angle for the hybrid column (default {DEFAULT_TARGET_SE})")
    p.add_argument("--max-rays", type=int, default=DEFAULT_MAX_RAYS,
                   help=f"ray ceiling per sample of the hybrid column (default {DEFAULT_MAX_RAYS}; SE ≤ 0.5 at every angle "
                   "takes 130-160 k rays for both samples, about 1 minute for the table on a quiet 2-core CPU)")
    p.add_argument("--mirror-rays", type=int, default=131072, help="rays of the mirror column (default 131072)")
    p.add_argument("--seed", type=int, default=0, help="seed of the platelet arrays and the rays (default 0)")
    p.add_argument("--waviness", type=float, default=0.0,
                   help="clearcoat RMS slope angle [deg] for every model column (default 0 = flat, as measured samples are not characterised)")
    p.add_argument("--spectral", action="store_true",
                   help="hybrid column traced at 400-700 nm and integrated under D65 / CIE 1964 10° as the instrument does "
                   "(about 7x the time, adds a* and b*); default: one wavelength, 0.5 µm")
    add_output_argument(p, "results/table1")
    add_json_argument(p)
    p.set_defaults(func=run)


def _rms(a, b):
    return float(np.sqrt(np.mean((np.asarray(a) - np.asarray(b)) ** 2)))


def compute(target_se: float = DEFAULT_TARGET_SE, mirror_rays: int = 131072, seed: int = 0, max_rays: int = DEFAULT_MAX_RAYS,
            waviness: float = 0.0, spectral: bool = False, progress: bool = False) -> dict:
    """All columns for both samples (plain dict; `None` where a column is unavailable).

    `progress` prints to stderr a line per column as it starts and finishes and, from `simulate`, one
    per round of tracer rays (stdout stays the table or JSON).
    """
    from .._samples import load_sample
    from ..brdf._platelet import MirrorBRDF
    from ..instrument._geometry import ma98_geometry
    from ..instrument._hot_spot import HotSpot
    from ..instrument._lightness import reflectance_factor_to_lightness
    from ..instrument._single_scatter import microfacet_reflectance_factor
    from ..microstructure._tilt import GammaTilt

    check_adaptive(target_se, max_rays)
    if int(mirror_rays) < 1:
        raise ValueError(f"mirror_rays must be a positive integer, got {mirror_rays!r}")
    from ..optics._interface import check_waviness

    waviness = check_waviness(waviness)
    out = {"samples": {}, "notes": []}
    def report(text):
        if progress:
            print(f"[table1] {text}", file=sys.stderr, flush=True)

    for name in SAMPLES:
        s = load_sample(name)
        t0 = time.perf_counter()
        report(f"{name}: hybrid column (wave-based platelet BRDF through the tracer, until SE ≤ {target_se:g} L*) …")
        row = {"measured": np.asarray(s.L_star)}
        hybrid = None
        try:
            hybrid = simulate(name, brdf="wave", seed=seed, target_se=target_se, max_rays=max_rays, waviness=waviness, spectral=spectral,
                              progress=progress)
        except (ValueError, ImportError, OSError) as err:
            out["notes"].append(f"hybrid column unavailable for {name}: {err}")
        if hybrid is not None and float(np.max(hybrid["L_star_se"])) > target_se:
            out["notes"].append(f"{name}: the hybrid column stopped at the ray ceiling ({hybrid['rays']} rays, max_rays {max_rays}) with "
                                f"an L* standard error of {float(np.max(hybrid['L_star_se'])):.2f}, above the target {target_se:g}")
        if hybrid is not None:
            report(f"{name}: hybrid done, {hybrid['rays']} rays, largest SE {float(np.max(hybrid['L_star_se'])):.2f} L*, "
                   f"{time.perf_counter() - t0:.0f} s; mirror column ({mirror_rays} rays) …")
        mirror = simulate(name, brdf="mirror", seed=seed, rays=mirror_rays, waviness=waviness, progress=progress)
        geo = ma98_geometry(45.0)
        tilt = GammaTilt(s.tilt_shape.value, s.tilt_scale.value)
        analytic = np.asarray(reflectance_factor_to_lightness(microfacet_reflectance_factor(
            geo, tilt, n=s.binder_index, platelet=MirrorBRDF(n_binder=s.binder_index), hot_spot=HotSpot.for_sample(s), waviness_deg=waviness)))
        row["hybrid"] = None if hybrid is None else np.asarray(hybrid["L_star"])
        row["hybrid_se"] = None if hybrid is None else np.asarray(hybrid["L_star_se"])
        if spectral and hybrid is not None:
            row["hybrid_Lab"], row["hybrid_Lab_se"] = np.asarray(hybrid["Lab"]), np.asarray(hybrid["Lab_se"])
        row["mirror"] = np.asarray(mirror["L_star"])
        row["mirror_se"] = np.asarray(mirror["L_star_se"])
        row["analytic"] = analytic
        fi = lambda L: None if L is None else flop_index_or_none(L[0], L[2], L[4])  # noqa: E731
        row["rms_hybrid"] = None if hybrid is None else _rms(row["hybrid"], row["measured"])
        row["rms_mirror"] = _rms(row["mirror"], row["measured"])
        row["rms_analytic"] = _rms(row["analytic"], row["measured"])
        row["flop"] = {"measured": fi(row["measured"]), "hybrid": fi(row["hybrid"]), "mirror": fi(row["mirror"]), "analytic": fi(row["analytic"])}
        row["rays"] = {"hybrid": None if hybrid is None else hybrid["rays"], "mirror": mirror["rays"]}
        row["resolved"] = {"hybrid": None if hybrid is None else np.asarray(hybrid["resolved"]), "mirror": np.asarray(mirror["resolved"])}
        if not np.all(row["resolved"]["mirror"]) or (hybrid is not None and not np.all(row["resolved"]["hybrid"])):
            out["notes"].append(f"{name}: some detectors are not resolved (light reached them in fewer than half the "
                                f"batches; see table1.json 'resolved'): their L* and SE rest on a few rare paths")
        row["energy_hybrid"] = None if hybrid is None else hybrid["energy"]
        row["seconds"] = time.perf_counter() - t0
        out["samples"][name] = row
    out["aspecular_deg"] = list(load_sample("silver1").aspecular_deg)
    out["waviness_deg"] = waviness
    out["spectral"] = bool(spectral)
    return out


_JSON_KEYS = ("measured", "hybrid", "hybrid_se", "mirror", "analytic", "rms_hybrid")  # the schema
_JSON_EXTRA = ("mirror_se", "rms_mirror", "rms_analytic", "flop", "resolved")  # and what the table shows


def _plot(result: dict, folder) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .._io import atomic_savefig

    gamma = np.asarray(result["aspecular_deg"])
    fig, axes = plt.subplots(1, len(result["samples"]), figsize=(11, 4.2), sharey=True)
    for ax, (name, r) in zip(np.atleast_1d(axes), result["samples"].items()):
        ax.errorbar(gamma, r["measured"], yerr=0.3, fmt="ko", label="measured", zorder=5)
        if r["hybrid"] is not None:
            ax.errorbar(gamma, r["hybrid"], yerr=r["hybrid_se"], fmt="s-", color="C0", label="hybrid (wave BRDF, tracer)")
        ax.errorbar(gamma, r["mirror"], yerr=r["mirror_se"], fmt="^--", color="C1", label=f"mirror platelets (tracer, {MIRROR_APERTURE_DEG:g}° aperture)")
        ax.plot(gamma, r["analytic"], "v:", color="C2", label="analytic single scatter")
        ax.set_title(name)
        ax.set_xlabel("aspecular angle [deg]")
        ax.grid(alpha=0.3)
    np.atleast_1d(axes)[0].set_ylabel("L*")
    np.atleast_1d(axes)[0].legend(fontsize=8)
    path = atomic_savefig(fig, f"{folder}/table1.png")
    plt.close(fig)
    return str(path)


def run(args) -> int:
    from .._io import atomic_write_json

    enable_compilation_cache()
    t0 = time.perf_counter()
    r = compute(args.target_se, args.mirror_rays, args.seed, args.max_rays, waviness=args.waviness, spectral=args.spectral, progress=True)
    r["seconds"] = time.perf_counter() - t0
    atomic_write_json(f"{args.out}/table1.json", r)
    png = _plot(r, args.out)
    # the hybrid column is the main job: without it the run has failed, whatever else it shows
    status = 1 if any(row["hybrid"] is None for row in r["samples"].values()) else 0
    if args.json:
        for note in r["notes"]:
            print(f"NOTE: {note}", file=sys.stderr)
        keys = _JSON_KEYS + _JSON_EXTRA + (("hybrid_Lab", "hybrid_Lab_se") if args.spectral else ())
        print_json({"samples": {k: {key: v[key] for key in keys if key in v} for k, v in r["samples"].items()}, "notes": r["notes"]})
        return status
    gamma = r["aspecular_deg"]
    for note in r["notes"]:
        print(f"NOTE: {note}")
    for name, row in r["samples"].items():
        print(f"\n{name}: L* at 45° illumination (Δ = model − measured)")
        print(f"{'aspecular':>10} {'measured':>9} {'hybrid':>15} {'Δ':>6} {'mirror':>15} {'Δ':>6} {'analytic':>9} {'Δ':>6}")
        for j, g in enumerate(gamma):
            m = row["measured"][j]
            hy = "unavailable" if row["hybrid"] is None else f"{row['hybrid'][j]:.1f} ± {row['hybrid_se'][j]:.2f}"
            dh = "" if row["hybrid"] is None else f"{row['hybrid'][j] - m:+.1f}"
            print(f"{g:>9.0f}° {m:>9.1f} {hy:>15} {dh:>6} {row['mirror'][j]:>7.1f} ± {row['mirror_se'][j]:<5.2f} "
                  f"{row['mirror'][j] - m:>+6.1f} {row['analytic'][j]:>9.1f} {row['analytic'][j] - m:>+6.1f}")
        rh = "—" if row["rms_hybrid"] is None else f"{row['rms_hybrid']:.1f}"
        print(f"{'RMS ΔL*':>10} {'':>9} {rh:>15} {'':>6} {row['rms_mirror']:>15.1f} {'':>6} {row['rms_analytic']:>9.1f}")
        f = row["flop"]
        fm, fh, fr, fa = (format_optional(f[k]) for k in ("measured", "hybrid", "mirror", "analytic"))
        print(f"flop index: measured {fm}, hybrid {fh}, mirror {fr}, analytic {fa}"
              f"   ({row['seconds']:.0f} s)")
        if "hybrid_Lab" in row:
            print("hybrid a*, b* (D65, 10°): " + ", ".join(f"{g:.0f}° {lab[1]:+.2f}/{lab[2]:+.2f} (± {se[1]:.2f}/{se[2]:.2f})"
                                                       for g, lab, se in zip(gamma, row["hybrid_Lab"], row["hybrid_Lab_se"])))
    print(f"\nhybrid column: {'spectral, 400-700 nm under D65 and the CIE 1964 10° observer' if r['spectral'] else 'one wavelength, 0.5 µm'}; "
          f"mirror column: delta platelets scored into a {MIRROR_APERTURE_DEG:g}° detector aperture; "
          f"analytic: mirror platelets, exit occlusion correlated over the platelet widths (hot spot), zero aperture. Plot: {png}; data: {args.out}/table1.json; {r['seconds']:.0f} s in all")
    return status
