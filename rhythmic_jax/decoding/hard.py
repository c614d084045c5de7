"""Batch decoding: descriptors -> decision values -> phases -> place index.

The paper's decode (Sec. III-C): for every period take the argmax phase
``j_k = argmax_j (w_j . x + b_j)`` (Eq. 3), then the unique index ``i < n`` with
``i mod tau_k = j_k`` for all k, found here in O(r) by the Chinese-remainder tables
of :func:`rhythmic_jax.map.periods.crt_tables` (the paper intersects sorted candidate
sets; the answer is the same). When the combination is ``>= n`` no frame has those
phases and the answer is "no match" (-1).

The confidence of a hard decode is its weakest phase margin,
``min_k (top1_k - top2_k)``: a query whose phases are all clear-cut scores high,
and a threshold on it rejects queries (the paper's "lower bound of decision value").
Soft and top-m decodes (:mod:`rhythmic_jax.decoding.soft`) share the :class:`Decoded`
result and its confidence.

Shapes: b queries, d features, p = sum(periods) templates, k periods.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax.decoding.buckets import head, pad_rows
from rhythmic_jax.errors import InputError
from rhythmic_jax.jit_options import jit
from rhythmic_jax.map.periods import crt_tables, period_offsets
from rhythmic_jax.solvers.objective import Templates
from rhythmic_jax.solvers.objective import scores as decision_values
from rhythmic_jax.validate import check_int

__all__ = ["Decoded", "check_scores", "decode", "hard_decode", "host_decode"]


class Decoded(NamedTuple):
    """Result of a batch decode; every field has the queries' leading shape (b,).

    index: int32 place, -1 for no match. score: best summed score (-inf for no
    match). runner_up: best score of a rival place (-inf when there is none).
    """

    index: jax.Array
    score: jax.Array
    runner_up: jax.Array

    @property
    def confidence(self) -> jax.Array:
        """``score - runner_up`` (``inf`` without a rival, ``0`` for no match).

        Outside a trace it is computed on the host from the (b,) fields: a
        device-side ``where`` would compile a program for every batch size."""
        if any(isinstance(f, jax.core.Tracer) for f in self):
            return jnp.where(self.index >= 0, self.score - self.runner_up, 0.0)
        index, score, runner = (np.asarray(f) for f in self)
        with np.errstate(invalid="ignore"):  # -inf - -inf of a no match
            gap = np.where(index >= 0, score - runner, 0.0).astype(score.dtype)
        return jax.device_put(gap)


def check_scores(
    scores: jax.Array | np.ndarray, periods: Sequence[int], n: int | None = None
) -> tuple[tuple[int, ...], int]:
    """Validate ``scores`` (..., p) against ``periods`` and ``n``.

    Returns the periods as a tuple of Python ints and ``n`` (``prod(periods)`` when
    ``n`` is None). Raises InputError with one line on any mismatch.
    """
    try:
        per = tuple(int(t) for t in periods)
    except (TypeError, ValueError):
        raise InputError(
            f"periods must be a sequence of integers, got {periods!r}"
        ) from None
    if not per or min(per) < 1:
        raise InputError(f"periods must be positive integers, got {per}")
    crt_tables(per)  # raises InputError when not pairwise co-prime
    total = math.prod(per)
    n = total if n is None else n
    msg = f"n={n!r} must be an integer in [1, prod(periods)={total}]"
    check_int(n, "n", 1, total, msg=msg)
    if not hasattr(scores, "shape"):
        scores = np.asarray(scores)
    shape = scores.shape
    if len(shape) < 1 or shape[-1] != sum(per):
        raise InputError(
            f"scores must have shape (..., sum(periods)={sum(per)}) for periods {per}, "
            f"got shape {shape}"
        )
    if not jnp.issubdtype(scores.dtype, jnp.floating):
        raise InputError(f"scores must be floating point, got dtype {scores.dtype}")
    return per, int(n)


def hard_decode(scores: jax.Array, periods: tuple[int, ...], n: int) -> Decoded:
    """The paper's decode of decision values: per-period argmax, then CRT.

    Args:
      scores: (b, p) decision values, period k in columns ``off_k : off_k + tau_k``.
      periods: static tuple of pairwise co-prime periods.
      n: number of places; a combination ``>= n`` is no match.

    Returns:
      :class:`Decoded` with index (b,) int32 (-1 = no match), score (b,) the sum of
      the per-period maxima (-inf for no match), and runner_up such that
      ``confidence = score - runner_up = min_k (top1_k - top2_k)``.
    """
    tables, big_m = crt_tables(periods)
    lead = scores.shape[:1]
    index = jnp.zeros(lead, jnp.int32)
    total = jnp.zeros(lead, scores.dtype)
    gap = jnp.full(lead, jnp.inf, scores.dtype)
    for off, t, table in zip(period_offsets(periods), periods, tables, strict=True):
        block = scores[:, off : off + t]
        phase = jnp.argmax(block, axis=1)
        top = jnp.max(block, axis=1)
        index = (index + jnp.asarray(table.astype(np.int32))[phase]) % big_m
        total = total + top
        if t > 1:  # second best by masking the argmax (cheaper than top_k on CPU)
            hit = jnp.arange(t)[None, :] == phase[:, None]
            gap = jnp.minimum(gap, top - jnp.max(jnp.where(hit, -jnp.inf, block), 1))
    found = index < n
    return Decoded(
        jnp.where(found, index, -1),
        jnp.where(found, total, jnp.asarray(-jnp.inf, scores.dtype)),
        total - gap,
    )


@functools.partial(jit, static_argnames=("periods", "n"))
def _localise(params: Templates, queries: jax.Array, periods, n) -> Decoded:
    return hard_decode(decision_values(params, queries), periods, n)


def host_decode(scores: np.ndarray, periods: tuple[int, ...], n: int) -> Decoded:
    """:func:`hard_decode` in numpy, of scores (b, p) already in host memory,
    with numpy arrays in the result (the same values; a query whose scores hold
    a NaN decodes as in JAX, its argmax at the first NaN). ``scores`` is
    overwritten (each period's top score masked for the runner-up).

    A batch's (b, p) scores are small and in host memory after the product:
    handing them to a jitted decode costs a copy and a dispatch, three times
    the argmaxes themselves for 1000 queries and 201 templates.
    """
    tables, big_m = crt_tables(periods)
    b = scores.shape[0]
    rows = np.arange(b)
    index = np.zeros(b, np.int64)
    total = np.zeros(b, scores.dtype)
    gap = np.full(b, np.inf, scores.dtype)
    for off, t, table in zip(period_offsets(periods), periods, tables, strict=True):
        block = scores[:, off : off + t]
        phase = block.argmax(axis=1)
        top = block[rows, phase]
        index += table[phase]
        total += top
        if t > 1:  # second best by masking the argmax, as hard_decode does
            block[rows, phase] = -np.inf
            with np.errstate(invalid="ignore"):  # inf - inf: NaN, as in JAX
                gap = np.minimum(gap, top - block.max(axis=1))
    index %= big_m
    found = index < n
    return Decoded(
        np.where(found, index, -1).astype(np.int32),
        np.where(found, total, scores.dtype.type(-np.inf)),
        total - gap,
    )


def decode(
    params: Templates, queries: jax.Array | np.ndarray, periods: Sequence[int], n: int
) -> Decoded:
    """Jit-compiled batch localisation of (b, d) queries with the paper's decode.

    One ``(b, d) x (d, p)`` product, k argmaxes and k table look-ups per query.
    Queries in host memory (a float32 numpy array, what a user's batch usually
    is) are multiplied where they lie, by numpy's BLAS ``sgemm``: handing a large
    numpy batch to XLA copies it first (an unaligned 16 MB batch costs more than
    the product), and the small (b, p) products are decoded by numpy where they
    lie (:func:`host_decode`), the (b,) results handed back as JAX arrays.
    Device arrays, and every batch on a GPU, take one jitted call, the batch
    padded to a power-of-two bucket of rows
    (:func:`rhythmic_jax.decoding.buckets.pad_rows`): a new batch size in a
    bucket compiles nothing.
    """
    periods = tuple(int(t) for t in periods)
    if (
        isinstance(queries, np.ndarray)
        and queries.dtype == np.float32
        and queries.ndim == 2
        and jax.default_backend() == "cpu"
    ):
        products = queries @ np.asarray(params.w)
        products += np.asarray(params.b, products.dtype)
        return Decoded(*(jax.device_put(f) for f in host_decode(products, periods, n)))
    padded, b = pad_rows(queries)
    return head(_localise(params, jax.device_put(padded), periods, n), b)
