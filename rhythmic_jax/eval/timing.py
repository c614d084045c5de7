"""Query timing: one-query latency and whole-batch throughput, and the one
timing every method's row of a report uses (:func:`query_latency`).

Every timed function maps query descriptors (b, d) to an answer; jax results are
waited for with ``jax.block_until_ready`` and every clock is
``time.perf_counter``.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import jax
import numpy as np

from rhythmic_jax.errors import InputError

__all__ = ["WARMUP", "query_latency", "time_batch", "time_single_queries"]


def _summary(seconds: np.ndarray) -> dict[str, float]:
    return {
        "median_s": float(np.median(seconds)),
        "p95_s": float(np.percentile(seconds, 95)),
        "mean_s": float(seconds.mean()),
        "min_s": float(seconds.min()),
    }


def time_single_queries(
    fn: Callable, queries, warmup: int = 10, repeats: int = 1
) -> dict[str, float | int]:
    """Latency of one-query calls ``fn(queries[i : i + 1])``.

    ``warmup`` untimed calls first (compilation, caches), then every query is
    timed ``repeats`` times with ``time.perf_counter``; jax results are waited
    for with ``jax.block_until_ready``. For benchmark scripts.

    Args:
      fn: maps a (1, d) batch to a result (numpy, jax array or a tuple of them).
      queries: (b, d) queries.

    Returns:
      ``median_s``, ``p95_s``, ``mean_s``, ``min_s`` seconds per call and
      ``n_calls`` timed.
    """
    queries = np.asarray(queries)
    if queries.ndim != 2 or queries.shape[0] == 0:
        raise InputError(
            f"queries must be a non-empty (b, d) array, got {queries.shape}"
        )
    if warmup < 0 or repeats < 1:
        raise InputError(f"need warmup >= 0 and repeats >= 1, got {warmup}, {repeats}")
    b = queries.shape[0]
    for i in range(warmup):
        jax.block_until_ready(fn(queries[i % b : i % b + 1]))
    times = []
    for _ in range(repeats):
        for i in range(b):
            q = queries[i : i + 1]
            t0 = time.perf_counter()
            jax.block_until_ready(fn(q))
            times.append(time.perf_counter() - t0)
    return {**_summary(np.asarray(times)), "n_calls": len(times)}


def time_batch(fn: Callable, queries, repeats: int = 5) -> dict[str, float | int]:
    """Throughput of whole-batch calls ``fn(queries)``, one untimed call first.

    Returns:
      ``queries_per_s`` (batch size over the median call time), the call time
      summary (``median_s``, ``p95_s``, ``mean_s``, ``min_s``), ``batch_size``
      and ``repeats``.
    """
    queries = np.asarray(queries)
    if queries.ndim != 2 or queries.shape[0] == 0:
        raise InputError(
            f"queries must be a non-empty (b, d) array, got {queries.shape}"
        )
    if repeats < 1:
        raise InputError(f"repeats must be >= 1, got {repeats}")
    jax.block_until_ready(fn(queries))
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(queries))
        times.append(time.perf_counter() - t0)
    summary = _summary(np.asarray(times))
    return {
        "queries_per_s": queries.shape[0] / max(summary["median_s"], 1e-12),
        **summary,
        "batch_size": int(queries.shape[0]),
        "repeats": int(repeats),
    }


WARMUP = 20  # untimed calls of one query before the latency is timed


def query_latency(fn: Callable, queries) -> dict[str, float]:
    """The one timing every method's row uses: ``fn`` maps query descriptors
    (b, d) to places, so a map's time includes its template product (and any
    dequantisation), a code's its encoding.

    One query alone (the median of up to 200 calls, after :data:`WARMUP`
    untimed ones) and the whole batch in one call (its throughput, median of
    3), timed on a warm program: both shapes are compiled before any clock
    starts.

    Returns:
      ``latency_median_s``, ``latency_p95_s`` (seconds per single-query call),
      ``queries_per_s`` and ``batch_s`` (the whole batch's call).
    """
    jax.block_until_ready(fn(queries[:1]))
    jax.block_until_ready(fn(queries))  # compiled (or loaded) here, not timed
    single = time_single_queries(fn, queries[: min(len(queries), 200)], WARMUP)
    batch = time_batch(fn, queries, repeats=3)
    return {
        "latency_median_s": single["median_s"],
        "latency_p95_s": single["p95_s"],
        "queries_per_s": batch["queries_per_s"],
        "batch_s": batch["median_s"],
    }
