"""Benchmark: the tracer emulator's design on Dask — local clusters of 1 and 2 workers.

The design of a small tracer emulator over the wide box (`tracer_emulator` with
`WIDE_TRACER_SETTINGS`: the hybrid wave BRDF grid from the array cache, 65,536 rays per run),
`--train` + `--test` tracer runs, one task each, no emulator cache (every run is evaluated), no
seed-spread measurement. A warm-up run in this process first fills the persistent XLA compilation
cache, so both timed clusters start from the same state; each timed build includes starting the
cluster, the workers' imports, their BRDF grid and their compilation (from that cache). Reports wall
times, the speed-up of 2 workers over 1 and the machine's load. Writes
benchmarks/output/emulator_dask.json (emulator_dask_pinned.json with --pin).

One tracer run already keeps more than one core busy (XLA's threads), so on a machine with as many cores as
workers the speed-up over one unpinned worker is capped by that. `--pin` gives each worker one core of its own
(worker i → core i, all its threads), as a worker on its own node of a cluster has its own cores; the run
also measures, in this process, one design point on all cores and on one core (their ratio is the tracer's
own use of the second core, and 2 / that ratio the cap on an unpinned 2-worker speed-up).
Run: python benchmarks/emulator_dask.py [--train 96] [--test 24] [--pin]  (the sizes of the shipped wide emulator)
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from paintjax import atomic_write_json, enable_compilation_cache  # noqa: E402
from paintjax.inverse import WIDE_TRACER_BOX, WIDE_TRACER_SETTINGS, TracerLStar, tracer_emulator  # noqa: E402

#: The cores this process may use when it starts (a container may allow fewer than `os.cpu_count()`).
CORES = sorted(os.sched_getaffinity(0))


def pin_threads(core: int | None) -> None:
    """Every thread of this process on `core` (None: on all of `CORES`)."""
    cores = {core} if core is not None else set(CORES)
    for tid in os.listdir("/proc/self/task"):
        try:
            os.sched_setaffinity(int(tid), cores)
        except OSError:  # a thread that ended meanwhile
            pass


def build(workers: int, n_train: int, n_test: int, pin: bool) -> float:
    from distributed import Client, LocalCluster, WorkerPlugin

    class PinToCore(WorkerPlugin):  # worker i on core i, before it imports JAX's runtime threads
        def setup(self, worker):
            pin_threads(CORES[int(worker.name) % len(CORES)])

    t0 = time.perf_counter()
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster, Client(cluster) as client:
        if pin:
            client.register_plugin(PinToCore())
        tracer_emulator(bounds=WIDE_TRACER_BOX, settings=WIDE_TRACER_SETTINGS, cache_dir=None, n_train=n_train, n_test=n_test, batch=1,
                        spread_theta=None, client=client)
    return time.perf_counter() - t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--train", type=int, default=96)
    ap.add_argument("--test", type=int, default=24)
    ap.add_argument("--pin", action="store_true", help="each worker on one core of its own (and the tracer's own use of two cores measured)")
    args = ap.parse_args(argv)
    enable_compilation_cache()
    out = {"train": args.train, "test": args.test, "tracer_runs": args.train + args.test, "rays_per_run": WIDE_TRACER_SETTINGS.rays,
           "cpu_count": os.cpu_count(), "machine": platform.platform(), "load_before": os.getloadavg()[0],
           "date": time.strftime("%Y-%m-%d")}
    t0 = time.perf_counter()
    tracer = TracerLStar(WIDE_TRACER_SETTINGS)
    tracer(np.array([[2.3, 2.2, 0.05, 0.64]]))  # warm-up: fills the compilation cache (and the BRDF tables, if missing)
    out["warm_up_s"] = time.perf_counter() - t0
    out["pinned"] = bool(args.pin)
    if args.pin:  # one design point's run on every core, then on one (the same θ, cached BRDF grid, compiled)
        theta = np.array([[3.0, 1.5, 0.04, 0.5]])
        for label, core in (("all_cores", None), ("one_core", CORES[0])):
            pin_threads(core)
            t0 = time.perf_counter()
            tracer(theta)
            out[f"one_run_{label}_s"] = time.perf_counter() - t0
        pin_threads(None)
        out["one_run_core_ratio"] = out["one_run_one_core_s"] / out["one_run_all_cores_s"]
        print(f"one tracer run: {out['one_run_all_cores_s']:.1f} s on all cores, {out['one_run_one_core_s']:.1f} s on one", flush=True)
    for workers in (1, 2):
        out[f"workers_{workers}_s"] = build(workers, args.train, args.test, args.pin)
        print(f"{workers} worker(s): {out[f'workers_{workers}_s']:.1f} s", flush=True)
    out["speedup_2_vs_1"] = out["workers_1_s"] / out["workers_2_s"]
    out["load_after"] = os.getloadavg()[0]
    print({k: round(v, 2) if isinstance(v, float) else v for k, v in out.items()})
    atomic_write_json(Path(__file__).parent / "output" / f"emulator_dask{'_pinned' if args.pin else ''}.json", out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
