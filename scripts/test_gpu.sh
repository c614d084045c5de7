#!/usr/bin/env bash
# The non-slow solver, decoder, map, codes and embedding tests on JAX's GPU backend
# (never in CI), after `pip install -e ".[test]"` and JAX's CUDA plugin:
#   bash scripts/test_gpu.sh    # WORKERS=4: four workers; JAX_PLATFORMS=cpu: rehearsal
# Preallocation is off and each worker may take MEM_FRACTION of the GPU's memory
# (default 0.9 / WORKERS); products state their precision, so the float32
# tolerances hold on the GPU.
set -euo pipefail
cd "$(dirname "$0")/.."
WORKERS="${WORKERS:-1}"
export JAX_PLATFORMS="${JAX_PLATFORMS:-cuda}" TF_CPP_MIN_LOG_LEVEL=3
export XLA_PYTHON_CLIENT_PREALLOCATE=false
export XLA_PYTHON_CLIENT_MEM_FRACTION="${MEM_FRACTION:-$(python -c "print(round(0.9 / $WORKERS, 3))")}"
python -c 'import jax; print("JAX", jax.__version__, "backend", jax.default_backend(), jax.devices())'
TESTS=(tests/solvers tests/decoding tests/test_rhythmic_map.py tests/test_codes.py
  tests/test_scalar_codes.py tests/test_embedding.py tests/test_learn.py
  tests/test_objective.py tests/test_closed_form.py tests/test_projection.py
  tests/test_precision_stated.py)
PARALLEL=()
if [ "$WORKERS" -gt 1 ]; then PARALLEL=(-n "$WORKERS" --dist loadscope); fi
timeout "${GPU_TIMEOUT:-3600}" python -m pytest -q -p no:cacheprovider -m "not slow" \
  "${PARALLEL[@]}" --durations=20 "${TESTS[@]}" "$@"
