#!/usr/bin/env bash
# One prepared device check of the tracer's width on a GPU: time to L* SE <= 0.3 at all five angles
# (three seeds) with 2 048 (the default), 16 384 and 65 536 rays in flight (TracerOptions.lanes), then
# a paint's gonio table (`paintjax gonio`'s tabulation, benchmarks/gonio.py) at 16 384 lanes.
#
# Run from the repository root on the GPU machine, e.g. through the device tool:
#     PAINTJAX_CACHE=.devcache bash benchmarks/gpu_lanes.sh   (results under $OUT, or /tmp/paintjax_gpu)
# It needs no install (as benchmarks/gpu_check.sh). Each step has its own time limit so the whole
# check ends within about 7 minutes.
source "$(dirname "$0")/gpu_env.sh"
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader | tee "$OUT/devices.txt"

for LANES in 2048 16384 65536; do
  timeout 100 "$PY" benchmarks/tracer.py --ttp-seeds 2,3,4 --lanes "$LANES" --rays "$((LANES > 65536 ? LANES : 65536))" \
      --plain-rays 0 --forward-max-rays 0 --json > "$OUT/tracer_lanes_$LANES.json" 2> "$OUT/tracer_lanes_$LANES.log"
  echo "lanes $LANES exit $?" >> "$OUT/tracer_lanes_$LANES.log"
  cat "$OUT/tracer_lanes_$LANES.log"
done

timeout 150 "$PY" benchmarks/gonio.py --lanes 16384 > "$OUT/gonio_gpu.json" 2> "$OUT/gonio_gpu.log"
echo "benchmarks/gonio.py exit $?" >> "$OUT/gonio_gpu.log"
tail -c 3000 "$OUT/gonio_gpu.log"
cat "$OUT/gonio_gpu.json"
