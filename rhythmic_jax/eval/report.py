"""A map judged on queries, beside exact brute-force search on the same descriptors.

:func:`evaluate_map` gives what ``rhythmic-jax evaluate`` prints: accuracy (exact
and within a frame tolerance), recall@1/5/10 (the map ranks places by their summed
phase scores), storage and compression, single-query latency and batch throughput,
and the same for faiss ``IndexFlatIP`` when the reference descriptors are at hand.
Ground truth is index-aligned (query i is place i) unless given.
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax.eval.metrics import (
    accuracy,
    recall_at_k,
    time_batch,
    time_single_queries,
)
from rhythmic_jax.periods import database_bytes, place_columns

__all__ = ["evaluate_map", "format_evaluation", "ranked_places"]

KS = (1, 5, 10)


@functools.partial(jax.jit, static_argnames=("periods", "n", "k"))
def _ranked(scores: jax.Array, periods: tuple[int, ...], n: int, k: int) -> jax.Array:
    cols = place_columns(periods, n)
    total = jnp.sum(scores[:, cols], axis=1)  # (b, n)
    return jax.lax.top_k(total, k)[1]


def ranked_places(scores, periods, n: int, k: int = 10) -> np.ndarray:
    """The k best places by ``sum_k s_k[i mod tau_k]``: (b, p) -> (b, k) indices."""
    periods = tuple(int(t) for t in periods)
    return np.asarray(_ranked(jnp.asarray(scores), periods, int(n), min(k, n)))


def _latency(fn, queries) -> dict[str, float]:
    single = time_single_queries(fn, queries[: min(len(queries), 200)], warmup=5)
    batch = time_batch(fn, queries, repeats=3)
    return {
        "latency_median_s": single["median_s"],
        "latency_p95_s": single["p95_s"],
        "queries_per_s": batch["queries_per_s"],
    }


def evaluate_map(
    model,
    queries: np.ndarray,
    *,
    reference: np.ndarray | None = None,
    reference_labels: np.ndarray | None = None,
    gt: np.ndarray | None = None,
    tolerance: int = 0,
    method: str | None = None,
    sequence: int | None = None,
    timing: bool = True,
) -> dict[str, Any]:
    """Score a fitted :class:`~rhythmic_jax.RhythmicMap` on (b, d) queries.

    Args:
      reference: the (m, d) reference descriptors, for the brute-force line.
      reference_labels: (m,) place of each reference row (several traversals);
        default ``arange(m)``.
      gt: (b,) true place of each query (-1: not in the map); default ``arange``.
      tolerance: frames of slack for the tolerant accuracy and recall@K.
      method, sequence: decode options passed to ``predict``.
      timing: measure latency and throughput.
    """
    queries = np.asarray(queries, np.float32)
    gt = np.arange(len(queries)) if gt is None else np.asarray(gt)
    pred = model.predict(queries, method, sequence=sequence)
    ranked = ranked_places(model.scores(queries), model.periods, model.n, max(KS))
    ks = tuple(k for k in KS if k <= ranked.shape[1])
    rows: dict[str, Any] = {
        "map": {
            "accuracy": accuracy(pred, gt, 0),
            "accuracy_tol": accuracy(pred, gt, tolerance),
            **recall_at_k(ranked, gt, ks, tolerance=tolerance).as_dict(),
            "storage_bytes": model.storage_bytes,
            "periods": list(model.periods),
        }
    }
    if timing:
        rows["map"].update(_latency(lambda q: model.decode(q).index, queries))
    if reference is not None:
        from rhythmic_jax.eval.baselines import BruteForce

        flat = BruteForce().fit(reference)
        _, top = flat.search(queries, max(ks))
        if reference_labels is not None:
            top = np.asarray(reference_labels)[top]
        rows["brute force"] = {
            "accuracy": accuracy(top[:, 0], gt, 0),
            "accuracy_tol": accuracy(top[:, 0], gt, tolerance),
            **recall_at_k(top, gt, ks, tolerance=tolerance).as_dict(),
            "storage_bytes": flat.storage_bytes,
        }
        if timing:
            rows["brute force"].update(
                _latency(lambda q: flat.search(q, 1)[1], queries)
            )
    return {
        "n": model.n,
        "d": model.d,
        "n_queries": len(queries),
        "tolerance": tolerance,
        "decode": method or model.config.decode,
        "sequence": sequence,
        "database_bytes": database_bytes(model.n, model.d, 4),
        "compression_ratio": model.compression_ratio,
        "methods": rows,
    }


def format_evaluation(result: dict[str, Any]) -> str:
    """A plain-text table of :func:`evaluate_map`'s result."""
    tol = result["tolerance"]
    head = (
        f"n={result['n']} d={result['d']} queries={result['n_queries']} "
        f"decode={result['decode']} sequence={result['sequence']} "
        f"tolerance=±{tol} frames; compression ratio {result['compression_ratio']:.4f}"
    )
    cols = ["accuracy", "accuracy_tol", "recall@1", "recall@5", "recall@10"]
    cols += ["storage_bytes", "latency_median_s", "queries_per_s"]
    lines = [head, f"{'method':<12}" + "".join(f"{c:>18}" for c in cols)]
    for name, row in result["methods"].items():
        cells = []
        for c in cols:
            v = row.get(c)
            if v is None:
                cells.append(f"{'-':>18}")
            elif isinstance(v, int):
                cells.append(f"{v:>18,}")
            elif c == "latency_median_s":
                cells.append(f"{v * 1e3:>15.3f} ms")
            else:
                cells.append(f"{v:>18.4f}" if v < 100 else f"{v:>18,.0f}")
        lines.append(f"{name:<12}" + "".join(cells))
    return "\n".join(lines)
