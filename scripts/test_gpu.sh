#!/usr/bin/env bash
# The non-slow tests of the solvers, decoders, map, codes and embedding on JAX's
# GPU backend. Never part of CI (CI has no GPU; the project needs none). Run on
# a machine with a CUDA GPU after `pip install -e ".[test]"` and JAX's CUDA
# plugin:
#
#   bash scripts/test_gpu.sh                  # one process
#   WORKERS=4 bash scripts/test_gpu.sh        # 4 workers sharing the GPU
#   JAX_PLATFORMS=cpu bash scripts/test_gpu.sh  # rehearsal without a GPU
#
# By default every JAX process preallocates 75 % of the GPU's memory, so a
# second worker finds no memory ("no supported devices found"): preallocation
# is turned off and each worker may take MEM_FRACTION of the memory (default
# 0.9 / WORKERS). Products state their precision (tests/test_precision_stated.py),
# so the CPU's float32 tolerances hold on the GPU; a GPU sums in another order,
# which the tolerances of the solver tests (relative 1e-6 objectives, 3e-3
# templates) already allow for.
set -euo pipefail
cd "$(dirname "$0")/.."
WORKERS="${WORKERS:-1}"
export JAX_PLATFORMS="${JAX_PLATFORMS:-cuda}" TF_CPP_MIN_LOG_LEVEL=3
export XLA_PYTHON_CLIENT_PREALLOCATE=false
export XLA_PYTHON_CLIENT_MEM_FRACTION="${MEM_FRACTION:-$(python -c "print(round(0.9 / $WORKERS, 3))")}"
python - <<'PY'
import jax
print("JAX", jax.__version__, "backend", jax.default_backend(), jax.devices())
PY
TESTS=(
  tests/solvers
  tests/decoding
  tests/test_rhythmic_map.py
  tests/test_codes.py
  tests/test_scalar_codes.py
  tests/test_embedding.py
  tests/test_learn.py
  tests/test_objective.py
  tests/test_closed_form.py
  tests/test_projection.py
  tests/test_precision_stated.py
)
PARALLEL=()
if [ "$WORKERS" -gt 1 ]; then PARALLEL=(-n "$WORKERS" --dist loadscope); fi
timeout "${GPU_TIMEOUT:-3600}" python -m pytest -q -p no:cacheprovider -m "not slow" \
  "${PARALLEL[@]}" --durations=20 "${TESTS[@]}" "$@"
