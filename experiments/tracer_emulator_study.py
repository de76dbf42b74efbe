"""Experiment: the whole tracer-emulator study in one process (so the BRDF table version cannot change between
steps): build the emulator (`build_tracer_emulator.py`), synthetic coverage from the tracer
(`coverage.py --forward tracer-emulator`), Silver #1/#2 fits and posteriors (`fit_silver.py --forward
tracer-emulator`), and `paintjax fit --forward tracer-emulator` timings (fit twice, then with --posterior).

Writes experiments/output/tracer_forward/run_all.json plus the outputs of the three experiments.

Run from the repository root: python experiments/tracer_emulator_study.py
"""
import json
import sys
import time

sys.path.insert(0, "experiments")
import jax

jax.config.update("jax_enable_x64", True)
from pathlib import Path

from paintjax import enable_compilation_cache

enable_compilation_cache()
import build_tracer_emulator
import coverage
import fit_silver

from paintjax import atomic_write_json

L = Path("experiments/output/tracer_forward")
t = {}
t0 = time.perf_counter(); build_tracer_emulator.main(); t["build"] = time.perf_counter() - t0
t0 = time.perf_counter(); coverage.main(["--forward", "tracer-emulator", "--datasets", "20", "--walkers", "24", "--steps", "2000", "--starts", "4"]); t["coverage"] = time.perf_counter() - t0
t0 = time.perf_counter(); fit_silver.main(["--forward", "tracer-emulator", "--check-draws", "8"]); t["fit_silver"] = time.perf_counter() - t0
import contextlib
import io

from paintjax.cli import main as paintjax_cli


def fit_cli(*extra):
    """`paintjax fit --sample silver1 --forward tracer-emulator --json …` in this process: its JSON result."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        paintjax_cli(["fit", "--sample", "silver1", "--forward", "tracer-emulator", "--no-progress", "--json", *extra])
    return json.loads(out.getvalue())


for name, extra in (("cli_fit_first", ()), ("cli_fit_second", ()), ("cli_posterior", ("--posterior",))):
    c0, w0 = time.process_time(), time.perf_counter()
    r = fit_cli(*extra)
    t[name] = {"wall": time.perf_counter() - w0, "cpu": time.process_time() - c0, "seconds": r["seconds"], "params": r["params"],
               "stderr": r["stderr"], "chi2": r["chi2"], "L_star_fit": r["L_star_fit"],
               "posterior": None if r["posterior"] is None else {k: r["posterior"][k] for k in ("mean", "q05", "q95", "tau_int", "n_eff", "steps", "converged")}}
    print(name, t[name], flush=True)
atomic_write_json(L / "run_all.json", t)
print("ALL DONE", t, flush=True)
