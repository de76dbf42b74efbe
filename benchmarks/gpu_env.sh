# Shared set-up of the device checks (sourced by gpu_check.sh and gpu_lanes.sh): the repository root,
# the output folder $OUT, the package on PYTHONPATH without an install, the cache, the CUDA backend.
set -uo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
OUT="${OUT:-/tmp/paintjax_gpu}"
mkdir -p "$OUT"
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1 PAINTJAX_CACHE="${PAINTJAX_CACHE:-/tmp/paintjax_cache}"
export JAX_PLATFORMS="${JAX_PLATFORMS:-cuda}"
PY="${PYTHON:-python3}"
