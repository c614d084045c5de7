#!/usr/bin/env bash
# The test suite: the default run, then the slow real-data checks in a second,
# bounded step, each over two worker processes (most tests wait on one core:
# tracing, compiling, starting the installed command). Run after
# `pip install -e ".[test]"`.
set -euo pipefail
cd "$(dirname "$0")/.."
export JAX_PLATFORMS=cpu TF_CPP_MIN_LOG_LEVEL=3
# One compile cache for both steps, both workers and the commands tests start
# (tests/conftest.py turns it on); RHYTHMIC_JAX_COMPILE_CACHE=0 runs without it.
export RHYTHMIC_JAX_COMPILE_CACHE="${RHYTHMIC_JAX_COMPILE_CACHE:-${RHYTHMIC_JAX_CACHE:-$HOME/.cache/rhythmic_jax}/jax}"
python -m pytest -q -n 2 --dist loadscope --durations=30
timeout "${SLOW_TIMEOUT:-3600}" python -m pytest -q -n 2 --dist loadscope -m slow
