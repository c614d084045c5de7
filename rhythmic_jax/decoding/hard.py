"""The hard decode: the paper's kernel, one for every layout.

The paper's decode (Sec. III-C): for every period take the argmax phase
``j_g = argmax_j (w_j . x + b_j)`` (Eq. 3), then the unique index ``i < n`` with
``i mod tau_g = j_g`` for all g, found here in O(r) by the Chinese-remainder tables
of :func:`rhythmic_jax.map.periods.crt_tables` (the paper intersects sorted candidate
sets; the answer is the same). When the combination is ``>= n`` no frame has those
phases and the answer is "no match" (-1).

A mixed-radix layout (:class:`~rhythmic_jax.map.groups.Groups`) is the same sum
of per-group tables (digit ``j`` of group g is worth ``j * prod(b_{g+1..r})``);
a hierarchical one takes the argmax segment, then its best place by the summed
fine scores. :func:`hard_decode` is that one kernel; the batch, sequence and
grouped decodes all call it, and the host lanes
(:mod:`rhythmic_jax.decoding.host`) are tested against it.

Confidence, the one definition every decode shares (:func:`confidence`): the
answer's score minus the best score of a rival place, ``score - runner_up``, in
the decode's own score units, finite and >= 0. For the hard decode the rival is
the best other phase combination, so the confidence is its weakest phase margin
``min_g (top1_g - top2_g)``: a query whose phases are all clear-cut scores high,
and a threshold on it rejects queries (the paper's "lower bound of decision
value"). A no match (-1) has confidence 0, as has an answer with no rival to
measure it against (a one-place map); a query whose scores are not finite (a NaN
or inf in it) is a no match. Soft and top-m decodes
(:mod:`rhythmic_jax.decoding.soft`) share the :class:`Decoded` result and its
confidence.

Shapes: b queries, d features, p = sum(periods) templates, r periods (or
groups), indexed by g in ``tau_g``, ``j_g``, ``off_g``.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax.decoding import buckets
from rhythmic_jax.decoding.buckets import (
    chunk_count,
    head,
    in_host_memory,
    over_chunks,
    pad_rows,
)
from rhythmic_jax.errors import InputError
from rhythmic_jax.jit_options import jit
from rhythmic_jax.map.groups import Groups
from rhythmic_jax.map.periods import crt_tables
from rhythmic_jax.map.pytree import Templates, decision_values
from rhythmic_jax.validate import check_int

__all__ = [
    "Decoded",
    "confidence",
    "check_group_scores",
    "check_scores",
    "decode",
    "hard_decode",
    "hard_kernel",
    "place_tables",
]


def confidence(index, score, runner_up, xp=jnp):
    """The confidence of decoded answers: ``score - runner_up`` where the answer
    is a place and has a rival (``runner_up > -inf``), else 0; finite always
    (a margin beyond the dtype's range is its largest number, a NaN is 0).

    One meaning for every decode: how far, in the decode's own score units
    (summed decision values; fused z-scores with codes; summed over the frames
    of a sequence), the answer beats the best place it was compared with. It
    grows with certainty, so ``confidence >= threshold`` keeps the surest
    answers. ``xp``: ``jax.numpy`` (traced or on a device) or ``numpy``.
    """
    gap = score - runner_up
    ok = (index >= 0) & (runner_up > -xp.inf) & ~xp.isnan(gap)
    big = xp.finfo(score.dtype).max
    return xp.where(ok, xp.minimum(gap, big), 0.0).astype(score.dtype)


_confidence = jit(confidence)


class Decoded(NamedTuple):
    """Result of a decode (a pytree); every field has the queries' leading shape.

    index: int32 place, -1 for no match. score: best summed score (-inf for no
    match). runner_up: best score of a rival place (-inf when there is none).
    """

    index: jax.Array
    score: jax.Array
    runner_up: jax.Array

    @property
    def confidence(self) -> jax.Array | np.ndarray:
        """:func:`confidence`: ``score - runner_up``, finite, ``0`` for no match
        and for an answer without a rival; computed where the fields lie: in
        host memory by numpy (a program per batch size would cost more than the
        subtraction), on another device or inside a trace by JAX."""
        host = [in_host_memory(f) for f in self]
        if any(f is None for f in host):
            return _confidence(*self)
        with np.errstate(invalid="ignore", over="ignore"):  # -inf - -inf
            return confidence(*host, xp=np)


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


@functools.lru_cache(maxsize=64)
def place_tables(groups: Groups) -> tuple[tuple[np.ndarray, ...], int]:
    """Per-group int32 tables whose sum (mod the modulus) is the place."""
    if groups.kind == "periods":
        tables, big_m = crt_tables(groups.sizes)
    else:  # mixed radix: digit j of group g is worth j * weight_g
        sizes, weights = groups.sizes, groups.weights()
        tables = tuple(np.arange(t) * w for t, w in zip(sizes, weights, strict=True))
        big_m = groups.capacity
    return tuple(t.astype(np.int32) for t in tables), big_m


def _top_two(block: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """(b, t) -> argmax (b,), max (b,), max - second (b,) (inf when t == 1).

    The argmax is the first column holding the maximum (or a NaN, as
    ``jnp.argmax`` takes the first NaN) by a min over the columns, and the
    second best a max with the argmax masked: plain reductions, which XLA
    vectorises on a CPU (its variadic argmax reduction and ``top_k`` it does
    not)."""
    t = block.shape[1]
    top = jnp.max(block, axis=1)
    col = jax.lax.broadcasted_iota(jnp.int32, block.shape, 1)
    hit = (block == top[:, None]) | jnp.isnan(block)
    arg = jnp.min(jnp.where(hit, col, t), axis=1)
    if t == 1:
        return arg, top, jnp.full_like(top, jnp.inf)
    second = jnp.max(jnp.where(col == arg[:, None], -jnp.inf, block), axis=1)
    return arg, top, top - second


def _hard(scores: jax.Array, groups: Groups, n: int) -> Decoded:
    """The kernel on scores (b, p)."""
    lead = scores.shape[:1]
    offs = groups.offsets
    if groups.kind == "hierarchical":  # the argmax segment, then its best place
        s = groups.segment
        seg, seg_top, seg_gap = _top_two(scores[:, : groups.sizes[0]])
        first = (seg * s).astype(jnp.int32)[:, None]
        place = first + jnp.arange(s, dtype=jnp.int32)[None, :]
        fine = jnp.zeros(place.shape, scores.dtype)
        for off, t in zip(offs[1:], groups.sizes[1:], strict=True):
            fine = fine + jnp.take_along_axis(scores, off + place % t, axis=1)
        best, fine_top, fine_gap = _top_two(jnp.where(place < n, fine, -jnp.inf))
        total = seg_top + fine_top
        gap = jnp.minimum(seg_gap, fine_gap)
        found = jnp.isfinite(total)  # a NaN or inf in the query: no match
        return Decoded(
            jnp.where(found, seg * s + best, -1).astype(jnp.int32),
            jnp.where(found, total, jnp.asarray(-jnp.inf, scores.dtype)),
            total - gap,
        )
    tables, big_m = place_tables(groups)
    index = jnp.zeros(lead, jnp.int32)
    total = jnp.zeros(lead, scores.dtype)
    gap = jnp.full(lead, jnp.inf, scores.dtype)
    for off, t, table in zip(offs, groups.sizes, tables, strict=True):
        phase, top, margin = _top_two(scores[:, off : off + t])
        index = (index + jnp.asarray(table)[phase]) % big_m
        total = total + top
        gap = jnp.minimum(gap, margin)
    found = (index < n) & jnp.isfinite(total)  # a NaN or inf: no match
    return Decoded(
        jnp.where(found, index, -1),
        jnp.where(found, total, jnp.asarray(-jnp.inf, scores.dtype)),
        total - gap,
    )


hard_kernel = functools.partial(jit, static_argnames=("groups", "n"))(_hard)
"""The kernel jitted on scores (b, p): ``hard_kernel(scores, groups, n)``."""


def hard_decode(
    scores: jax.Array, periods: Sequence[int] | Groups, n: int | None = None
) -> Decoded:
    """The hard decode of decision values (..., p): per-group argmax, then the place.

    Args:
      scores: (..., p) decision values, group g in columns ``off_g : off_g + t_g``.
      periods: pairwise co-prime periods, or a map's
        :class:`~rhythmic_jax.map.groups.Groups` (any layout).
      n: number of places (default: every combination); a combination
        ``>= n`` is no match.

    Returns:
      :class:`Decoded` with the scores' leading shape: index int32 (-1 = no
      match, also for scores that are not finite), score the sum of the
      per-group maxima (-inf for no match), and runner_up the best other phase
      combination's, so that ``confidence = min_g (top1_g - top2_g)`` (0 for
      no match). Inside a trace
      the kernel is traced in place (static layout and n); outside, one program
      per layout, n and shape.
    """
    if isinstance(periods, Groups):
        groups = periods
        if groups.kind == "periods":
            _, n = check_scores(scores, groups.sizes, n)
        else:
            n = groups.check(groups.capacity if n is None else n)
            check_group_scores(scores, groups)
    else:
        per, n = check_scores(scores, periods, n)
        groups = Groups("periods", per)
    if not isinstance(scores, jax.Array):
        scores = np.asarray(scores)
    lead = scores.shape[:-1]
    if math.prod(lead) == 0:
        neg = jnp.full(lead, -jnp.inf, scores.dtype)
        return Decoded(jnp.full(lead, -1, jnp.int32), neg, neg)
    out = hard_kernel(scores.reshape((-1, scores.shape[-1])), groups, n)
    return out if len(lead) == 1 else Decoded(*(x.reshape(lead) for x in out))


@functools.partial(jit, static_argnames=("groups", "n", "chunk"))
def _localise(
    params: Templates, queries: jax.Array, count, groups: Groups, n: int, chunk: int
):
    """Decoded (rows,) of queries (rows, d): ``count`` chunks of ``chunk`` rows
    decoded one after another
    (:func:`~rhythmic_jax.decoding.buckets.over_chunks`)."""

    def body(p, x, _):
        return _hard(decision_values(p, x), groups, n)

    return over_chunks(body, params, queries, count, chunk)


def decode(
    params: Templates,
    queries: jax.Array | np.ndarray,
    periods: Sequence[int] | Groups,
    n: int | None = None,
) -> Decoded:
    """Hard decode of queries (b, d) by templates ``params`` (``w`` (d, p), ``b``
    (p,)) on the device: Decoded (b,), one program per bucket of rows.

    The batch is padded to a power-of-two bucket
    (:func:`rhythmic_jax.decoding.buckets.pad_rows`), so a new batch size in a
    bucket compiles nothing, uploaded once, and decoded on the device in chunks
    of :data:`~rhythmic_jax.decoding.buckets.CHUNK` rows (at most CHUNK x p
    float32 scores at a time); the results are cut where they were computed and
    stay there until the caller reads them.
    """
    groups = periods
    if not isinstance(groups, Groups):
        groups = Groups("periods", tuple(int(t) for t in periods))
    n = groups.capacity if n is None else int(n)
    padded, b = pad_rows(queries)
    # a device array always: the jit cache keys a numpy argument apart from a
    # device array of the same shape, so a numpy batch compiled a second program
    padded = padded if isinstance(padded, jax.core.Tracer) else jax.device_put(padded)
    chunk = buckets.CHUNK
    count = chunk_count(b, chunk)
    return head(_localise(Templates(*params), padded, count, groups, n, chunk), b)


def check_group_scores(scores, groups: Groups) -> None:
    """Refuse scores that are not floating (..., p) for ``groups``."""
    shape = getattr(scores, "shape", np.shape(scores))
    if len(shape) < 1 or shape[-1] != groups.p:
        raise InputError(
            f"scores must have shape (..., {groups.p}) for {groups.describe()}, "
            f"got shape {shape}"
        )
    if not jnp.issubdtype(getattr(scores, "dtype", np.float64), jnp.floating):
        raise InputError(f"scores must be floating point, got dtype {scores.dtype}")
