#!/usr/bin/env bash
# One prepared device check for a machine with a GPU (the project never needs one):
# benchmarks/tracer.py on the accelerator (rays/s, time to L* SE <= 0.3 at all five angles over three
# seeds, forward-alone and plain vmap(while_loop) ratios), benchmarks/brdf_table.py (the wave stage:
# one default table against the LAPACK floor on the host), then the tracer's and the wave solver's
# validation tests there.
#
# Run from the repository root on the GPU machine, e.g. through the device tool:
#     bash benchmarks/gpu_check.sh            (results under $OUT, or /tmp/paintjax_gpu without it)
# It needs no install: paintjax imports colour-science, emcee and ArviZ lazily, and the tracer path
# uses only jax, equinox, jaxtyping, numpy and scipy, which the CUDA image has. Each step has its
# own time limit so the whole check ends within about 8.5 minutes of a 15-minute device budget (on
# an H200 on 2026-12-04 the tracer step took about 70 s, and the BRDF table more than 100 s with its
# compilation). On the 2-core CPU (JAX_PLATFORMS=cpu) the steps run into their limits; that is
# expected there. Results of that H200 run: BENCHMARKS.md and benchmarks/output/tracer_gpu.json.
source "$(dirname "$0")/gpu_env.sh"

"$PY" - <<'EOF' 2>&1 | tee "$OUT/devices.txt"
import jax, platform
print("jax", jax.__version__, "backend", jax.default_backend(), "devices", jax.devices(), platform.python_version())
EOF

# Speed: builds the Silver #1 wave table and array on first use (cached under $PAINTJAX_CACHE).
timeout 150 "$PY" benchmarks/tracer.py --ttp-seeds 2,3,4 --json > "$OUT/tracer_gpu.json" 2> "$OUT/tracer_gpu.log"
echo "benchmarks/tracer.py exit $?" >> "$OUT/tracer_gpu.log"
cat "$OUT/tracer_gpu.log"  # stage-by-stage progress, kept even when the time limit cuts the run

# The wave stage: a default BRDF table from scratch on the accelerator, against the host's LAPACK floor.
timeout 150 "$PY" benchmarks/brdf_table.py > "$OUT/brdf_table_gpu.md" 2>&1
echo "benchmarks/brdf_table.py exit $?" >> "$OUT/brdf_table_gpu.md"
cat "$OUT/brdf_table_gpu.md"

# Validation on the accelerator: the tracer's closed-form tests (white furnace, energy, single
# scatter vs the analytic models, estimator agreement, reciprocity, determinism) and the wave
# solver's (Fresnel, energy ledger, reciprocity, perturbation theory, Kirchhoff).
timeout 150 "$PY" -m pytest tests/test_tracer.py tests/test_tracer_single_scatter.py -q -p no:cacheprovider 2>&1 | tee "$OUT/test_tracer.log"
echo "test_tracer exit ${PIPESTATUS[0]}" | tee -a "$OUT/test_tracer.log"
timeout 60 "$PY" -m pytest tests/test_wave.py -q -p no:cacheprovider 2>&1 | tee "$OUT/test_wave.log"
echo "test_wave exit ${PIPESTATUS[0]}" | tee -a "$OUT/test_wave.log"

tail -c 4000 "$OUT/tracer_gpu.json"
