"""Query timing: the helpers' records hold what they measured, and bad input is
refused."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from rhythmic_jax.eval.timing import time_batch, time_single_queries


def test_timing_helpers_return_sane_structure():
    Q = np.random.default_rng(8).standard_normal((6, 4)).astype(np.float32)
    W = jnp.ones((4, 3))
    calls = []

    def fn(q):
        calls.append(q.shape)
        return jnp.argmax(q @ W, axis=1)

    single = time_single_queries(fn, Q, warmup=2, repeats=2)
    assert single["n_calls"] == 12 and all(s == (1, 4) for s in calls)
    assert 0 < single["min_s"] <= single["median_s"] <= single["p95_s"]
    batch = time_batch(lambda q: (q @ np.ones((4, 2)), q), Q, repeats=3)
    assert batch["batch_size"] == 6 and batch["repeats"] == 3
    assert batch["queries_per_s"] == pytest.approx(6 / batch["median_s"])



def test_timing_refuses_empty_queries_and_bad_counts():
    from rhythmic_jax.errors import InputError

    Q = np.ones((3, 2), np.float32)
    with pytest.raises(InputError, match=r"non-empty \(b, d\) array, got \(0, 2\)"):
        time_single_queries(lambda q: q, Q[:0])
    with pytest.raises(InputError, match="warmup >= 0 and repeats >= 1, got -1, 1"):
        time_single_queries(lambda q: q, Q, warmup=-1)
    with pytest.raises(InputError, match=r"non-empty \(b, d\) array, got \(3,\)"):
        time_batch(lambda q: q, Q[:, 0])
    with pytest.raises(InputError, match="repeats must be >= 1, got 0"):
        time_batch(lambda q: q, Q, repeats=0)
