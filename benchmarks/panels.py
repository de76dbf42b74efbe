"""Benchmark: many panels on Dask — serial in-process against local clusters of 1 and 2 workers.

20 synthetic panels (the model's curves for Silver #1's published inputs and 19 nearby ones, with
0.3 L* noise), fitted with `paintjax fit`'s defaults (shipped tracer emulator, 8 starts). Reports
wall time of the serial loop (`fit_panel` in this process, one compilation), of `fit_panels` on
1 and 2 worker processes (cluster start, worker imports and compilation included), and the 2-worker
scaling efficiency against 1 worker. Writes benchmarks/output/panels.json.
Run: python benchmarks/panels.py [--panels 20]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from paintjax import atomic_write_json  # noqa: E402
from paintjax.inverse import fit_panel, fit_panels, make_forward, read_panels  # noqa: E402

FREE = ("shape", "scale", "sigma", "tau")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--panels", type=int, default=20)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    forward = make_forward("tracer-emulator-wide", FREE, {})
    theta = np.array([2.29, 2.18, 0.051, 0.64]) * np.exp(0.15 * rng.standard_normal((args.panels, 4)))
    L = np.asarray(forward(theta)) + 0.3 * rng.standard_normal((args.panels, 5))
    folder = Path(tempfile.mkdtemp())
    data = folder / "panels.csv"
    data.write_text("id,L15,L25,L45,L75,L110\n" + "".join(f"p{i},{','.join(f'{v:.2f}' for v in row)}\n" for i, row in enumerate(L)))
    panels, _ = read_panels(data)
    out = {"panels": args.panels, "cpu_count": os.cpu_count(), "load_before": os.getloadavg()[0]}
    t0 = time.perf_counter()
    for p in panels:
        fit_panel(p, "tracer-emulator-wide", FREE, 8, 0)
    out["serial_s"] = time.perf_counter() - t0
    for workers in (1, 2):
        t0 = time.perf_counter()
        fit_panels(data, folder / f"results_{workers}.csv", workers=workers)
        out[f"workers_{workers}_s"] = time.perf_counter() - t0
    out["efficiency_2_vs_1"] = out["workers_1_s"] / (2 * out["workers_2_s"])
    out["load_after"] = os.getloadavg()[0]
    print({k: round(v, 2) if isinstance(v, float) else v for k, v in out.items()})
    atomic_write_json(Path(__file__).parent / "output" / "panels.json", out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
