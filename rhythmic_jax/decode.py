"""Batch decoding: descriptors -> decision values -> phases -> place index.

The paper's decode (Sec. III-C): for every period take the argmax phase
``j_k = argmax_j (w_j . x + b_j)`` (Eq. 3), then the unique index ``i < n`` with
``i mod tau_k = j_k`` for all k, found here in O(r) by the Chinese-remainder tables
of :func:`rhythmic_jax.periods.crt_tables` (the paper intersects sorted candidate
sets; the answer is the same). When the combination is ``>= n`` no frame has those
phases and the answer is "no match" (-1).

The confidence of a hard decode is its weakest phase margin,
``min_k (top1_k - top2_k)``: a query whose phases are all clear-cut scores high,
and a threshold on it rejects queries (the paper's "lower bound of decision value").
Soft and top-m decodes (:mod:`rhythmic_jax.soft`) share the :class:`Decoded`
result and its confidence.

Shapes: b queries, d features, p = sum(periods) templates, k periods.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.objective import Templates, period_offsets
from rhythmic_jax.objective import scores as decision_values
from rhythmic_jax.periods import crt_tables
from rhythmic_jax.soft import Decoded, check_scores, soft_decode, topm_decode

__all__ = ["DECODERS", "decode", "decode_scores", "hard_decode"]

DECODERS = ("hard", "soft", "topm")


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


_hard_jit = functools.partial(jax.jit, static_argnames=("periods", "n"))(hard_decode)


def decode_scores(
    scores: jax.Array,
    periods: Sequence[int],
    n: int,
    method: str = "hard",
    m: int = 3,
) -> Decoded:
    """Decode (..., p) decision values with ``method`` in ``"hard" | "soft" | "topm"``.

    ``topm`` keeps the ``m`` best phases of every period (see
    :func:`rhythmic_jax.soft.topm_decode`). Every field of the result has the
    scores' leading shape.
    """
    if method not in DECODERS:
        raise InputError(f"unknown decode method {method!r}; choose one of {DECODERS}")
    periods, n = check_scores(scores, periods, n)
    if method == "soft":
        return soft_decode(scores, periods, n)
    if method == "topm":
        return topm_decode(scores, periods, n, m)
    scores = jnp.asarray(scores)
    lead = scores.shape[:-1]
    out = _hard_jit(scores.reshape((-1, scores.shape[-1])), periods, n)
    return Decoded(*(x.reshape(lead) for x in out))


@functools.partial(jax.jit, static_argnames=("periods", "n"))
def _localise(params: Templates, queries: jax.Array, periods, n) -> Decoded:
    return hard_decode(decision_values(params, queries), periods, n)


def decode(
    params: Templates, queries: jax.Array, periods: Sequence[int], n: int
) -> Decoded:
    """Jit-compiled batch localisation of (b, d) queries with the paper's decode.

    One ``(b, d) x (d, p)`` product, k argmaxes and k table look-ups per query.
    """
    return _localise(params, jnp.asarray(queries), tuple(int(t) for t in periods), n)
