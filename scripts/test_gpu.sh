#!/usr/bin/env bash
# The non-slow solver, decoder, map, codes and embedding tests on JAX's GPU backend
# (never in CI), after `pip install -e ".[test]"` and JAX's CUDA plugin:
#   bash scripts/test_gpu.sh    # WORKERS=4: four workers; JAX_PLATFORMS=cpu: rehearsal
# The GPU is JAX's default device and the CPU backend stays available (checks of a
# CPU fit's host memory compile for it); without a GPU the run stops at the start
# (JAX would fall back to the CPU). Programs compile with the GPU options of
# rhythmic_jax/jit_options.py (RHYTHMIC_JAX_GPU_AUTOTUNE=1: XLA's autotuner).
# Preallocation is off and each worker may take MEM_FRACTION of the GPU's memory
# (default 0.9 / WORKERS); products state their precision, so the float32
# tolerances hold on the GPU.
set -euo pipefail
cd "$(dirname "$0")/.."
WORKERS="${WORKERS:-1}"
NEED_GPU=$([ -z "${JAX_PLATFORMS:-}" ] && echo True || echo False)
export JAX_PLATFORMS="${JAX_PLATFORMS:-cuda,cpu}" TF_CPP_MIN_LOG_LEVEL=3
export XLA_PYTHON_CLIENT_PREALLOCATE=false
export XLA_PYTHON_CLIENT_MEM_FRACTION="${MEM_FRACTION:-$(python -c "print(round(0.9 / $WORKERS, 3))")}"
python -c "import jax, sys
print('JAX', jax.__version__, 'backend', jax.default_backend(), jax.devices())
sys.exit('no GPU found' if $NEED_GPU and jax.default_backend() != 'gpu' else 0)"
TESTS=(tests/solvers tests/decoding tests/map/test_codes.py tests/map/test_scalar_codes.py
  tests/map/test_embedding.py tests/map/test_projection.py tests/fitting/test_learn.py
  tests/fitting/test_closed_form.py tests/test_rhythmic_map.py tests/test_precision_stated.py
  tests/test_jit_options.py)
PARALLEL=()
if [ "$WORKERS" -gt 1 ]; then PARALLEL=(-n "$WORKERS" --dist loadscope); fi
timeout "${GPU_TIMEOUT:-3600}" python -m pytest -q -p no:cacheprovider -m "not slow" \
  "${PARALLEL[@]}" --durations=20 "${TESTS[@]}" "$@"
