#!/usr/bin/env bash
# The test suite, then the slow real-data checks in a bounded second step, each over
# two workers. Run after `pip install -c constraints.txt -e ".[test]"` (README).
set -euo pipefail
cd "$(dirname "$0")/.."
export JAX_PLATFORMS=cpu TF_CPP_MIN_LOG_LEVEL=3
# One compile cache for both steps and workers; RHYTHMIC_JAX_COMPILE_CACHE=0: none.
export RHYTHMIC_JAX_COMPILE_CACHE="${RHYTHMIC_JAX_COMPILE_CACHE:-${RHYTHMIC_JAX_CACHE:-$HOME/.cache/rhythmic_jax}/jax}"
python -m pytest -q -n 2 --dist loadscope --durations=30
timeout "${SLOW_TIMEOUT:-3600}" python -m pytest -q -n 2 --dist loadscope -m slow
