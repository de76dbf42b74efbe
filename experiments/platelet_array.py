"""Experiment: platelet arrays of the reference samples, and how hard overlap removal gets with PVC.

Writes into experiments/output/platelet_array/ (atomic writes):

* `{sample}_array.npz`: the array of each reference sample (default tile, seed 0);
* `{sample}_cross_section.png`, `{sample}_tilt_histogram.png`: the two pictures;
* `pvc_sweep.json` / `pvc_sweep.png`: Silver #1 statistics on a 200 µm tile at PVC 5 … 30 %:
  re-placements per platelet, failures, residual overlaps under both tests, time; plus the
  mid-plane (original study) removal at 20 %, which leaves exact overlaps behind;
* `summary.json`: the statistics of the reference arrays.

Run: python experiments/platelet_array.py [--tile 400]
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from paintjax import GammaTilt, array_statistics, atomic_savefig, atomic_savez, atomic_write_json, load_sample, platelet_array_for_sample  # noqa: E402
from paintjax.microstructure import plot_cross_section, plot_tilt_histogram  # noqa: E402

OUT = Path(__file__).parent / "output" / "platelet_array"


def reference_arrays(tile) -> dict:
    summary = {}
    for name in ("silver1", "silver2"):
        s = load_sample(name)
        tilt = GammaTilt(s.tilt_shape.value, s.tilt_scale.value)
        kw = {} if tile is None else {"tile": tile}
        array, log = platelet_array_for_sample(name, 0, return_log=True, **kw)
        st = array_statistics(array, tilt)
        st.update(seconds=log.seconds, replacements=log.total_replacements, max_replacements=log.max_replacements, failed=log.n_failed)
        summary[name] = st
        atomic_savez(
            OUT / f"{name}_array.npz",
            centers=array.centers,
            normals=array.normals,
            axes_u=array.axes_u,
            widths=array.widths,
            thickness=array.thickness,
            tile=np.asarray(array.tile),
            basecoat_thickness=array.basecoat_thickness,
        )
        plot_cross_section(array, OUT / f"{name}_cross_section.png", title=f"{s.description}: vertical cross-section (true scale)")
        plot_tilt_histogram(array, tilt, OUT / f"{name}_tilt_histogram.png", (st["tilt_ks"], st["tilt_ks_pvalue"]))
        print(f"{name}: {st['count']} platelets, PVC {100 * st['pvc']:.2f} %, overlaps {st['overlaps_exact']}/{st['overlaps_midplane']}, "
              f"KS D {st['tilt_ks']:.4f} (p {st['tilt_ks_pvalue']:.2f}), {log.seconds:.1f} s")
    return summary


def pvc_sweep() -> dict:
    rows = []
    for pvc in (0.05, 0.10, 0.15, 0.20, 0.25, 0.30):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            array, log = platelet_array_for_sample("silver1", 0, tile=200.0, pvc=pvc, return_log=True)
        st = array_statistics(array)
        rows.append(dict(pvc_target=pvc, pvc=st["pvc"], count=log.count, mean_replacements=log.total_replacements / log.count,
                         max_replacements=log.max_replacements, failed=log.n_failed, overlaps_exact=st["overlaps_exact"],
                         overlaps_midplane=st["overlaps_midplane"], seconds=log.seconds))
        print(f"PVC {100 * pvc:4.0f} %: {rows[-1]['mean_replacements']:7.1f} re-placements/platelet, {log.n_failed} failed, {log.seconds:.1f} s")
    array, log = platelet_array_for_sample("silver1", 0, tile=200.0, overlap_test="midplane", return_log=True)
    st = array_statistics(array)
    midplane = dict(pvc=st["pvc"], overlaps_exact=st["overlaps_exact"], overlaps_midplane=st["overlaps_midplane"], seconds=log.seconds)
    print(f"mid-plane removal at 20 %: residual exact overlaps {st['overlaps_exact']}, mid-plane {st['overlaps_midplane']}")
    return dict(tile=200.0, sample="silver1", rows=rows, midplane_removal_at_20=midplane)


def plot_sweep(sweep) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    r = sweep["rows"]
    p = 100 * np.array([x["pvc_target"] for x in r])
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.6))
    ax[0].semilogy(p, [x["mean_replacements"] for x in r], "o-", label="mean")
    ax[0].semilogy(p, [max(x["max_replacements"], 1) for x in r], "s--", label="most (placed platelets)")
    ax[0].axhline(1000, color="k", lw=0.8, ls=":", label="attempt limit")
    ax[0].set_xlabel("PVC [%]")
    ax[0].set_ylabel("re-placements per platelet")
    ax[0].legend(fontsize=8)
    ax[1].plot(p, [100 * x["failed"] / x["count"] for x in r], "o-", color="#b5332e")
    ax[1].set_xlabel("PVC [%]")
    ax[1].set_ylabel("platelets left overlapping [%]")
    fig.suptitle("Silver #1 statistics, 200 µm tile: overlap removal by random sequential addition", fontsize=10)
    fig.tight_layout()
    atomic_savefig(fig, OUT / "pvc_sweep.png")
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description="platelet arrays of the reference samples")
    ap.add_argument("--tile", type=float, default=None, help="tile side [µm] (default: 10 × the largest platelet)")
    args = ap.parse_args()
    summary = reference_arrays(args.tile)
    atomic_write_json(OUT / "summary.json", summary)
    sweep = pvc_sweep()
    atomic_write_json(OUT / "pvc_sweep.json", sweep)
    plot_sweep(sweep)
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
