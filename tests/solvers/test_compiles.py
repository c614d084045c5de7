"""A fit compiles a few XLA programs, once: the Newton step once per problem shape
whichever templates are still running, and no eager program for the glue."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from rhythmic_jax.map.periods import candidate_periods
from rhythmic_jax.solvers import newton
from rhythmic_jax.solvers.newton import chunk_width, chunks, newton_fit
from rhythmic_jax.solvers.objective import default_c, targets

REPO = Path(__file__).resolve().parents[2]


def test_a_default_fit_compiles_at_most_20_programs_in_a_fresh_process():
    """1000 x 256 route-like frames, a fresh process, no persistent cache: the
    count of JAX's backend-compile events (before: 92, four of them the step)."""
    env = dict(os.environ, PYTHONPATH=str(REPO), JAX_PLATFORMS="cpu")
    harness = [sys.executable, str(REPO / "scripts" / "_harness.py"), "bench_compile"]
    out = subprocess.run(
        [*harness, "count_fit", "[1000, 256]"],
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    record = json.loads(out.stdout.splitlines()[-1])
    assert 1 <= record["programs"] <= 20, record
    assert record["names"].get("jit(_newton_step)") == 1, record["names"]
    assert len(record["periods"]) == 2


def _rhythm(n: int, d: int, seed: int, noise: float) -> np.ndarray:
    rng = np.random.default_rng(seed)
    base = rng.standard_normal((29, d))
    x = base[np.arange(n) % 29] + noise * rng.standard_normal((n, d))
    return (x / np.linalg.norm(x, axis=1, keepdims=True)).astype(np.float32)


def test_two_fits_with_different_active_sets_compile_the_step_once():
    n, d = 203, 37  # a shape of its own: no other test compiled the step for it
    cands = candidate_periods(n, 2, 1, 7)
    y, c = targets(np.arange(n), cands), default_c(n)
    before = newton._newton_step._cache_size()
    _, a = newton_fit(_rhythm(n, d, 0, 0.3), y, c, newton.FAST)
    _, b = newton_fit(_rhythm(n, d, 1, 2.0), y, c, newton.FAST)
    # the templates still running differed from step to step and between fits
    assert len(set(a.columns + b.columns)) > 1, (a.columns, b.columns)
    assert a.columns != b.columns
    assert newton._newton_step._cache_size() - before == 1


def test_chunks_cover_the_live_templates_in_one_width():
    for p in (5, 8, 30, 245, 441):
        width = chunk_width(p)
        assert width <= p and (width == p or width % 8 == 0)
        assert -(-p // width) <= 4 or width == 8
        for live in sorted({1, min(7, p), max(p // 2, 1), p}):
            todo = np.sort(np.random.default_rng(p).choice(p, live, replace=False))
            parts = chunks(todo, width)
            assert all(part.shape == (width,) for part in parts)
            assert len(parts) == -(-live // width)
            np.testing.assert_array_equal(np.unique(np.concatenate(parts)), todo)
