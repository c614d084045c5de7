"""The hard decode: one JAX kernel for every layout, one numpy lane for host arrays.

The paper's decode (Sec. III-C): for every period take the argmax phase
``j_k = argmax_j (w_j . x + b_j)`` (Eq. 3), then the unique index ``i < n`` with
``i mod tau_k = j_k`` for all k, found here in O(r) by the Chinese-remainder tables
of :func:`rhythmic_jax.map.periods.crt_tables` (the paper intersects sorted candidate
sets; the answer is the same). When the combination is ``>= n`` no frame has those
phases and the answer is "no match" (-1).

A mixed-radix layout (:class:`~rhythmic_jax.map.groups.Groups`) is the same sum
of per-group tables (digit ``j`` of group k is worth ``j * prod(b_{k+1..r})``);
a hierarchical one takes the argmax segment, then its best place by the summed
fine scores. :func:`hard_decode` is that one kernel; the batch, sequence and
grouped decodes all call it.

The confidence of a hard decode is its weakest phase margin,
``min_k (top1_k - top2_k)``: a query whose phases are all clear-cut scores high,
and a threshold on it rejects queries (the paper's "lower bound of decision value").
Soft and top-m decodes (:mod:`rhythmic_jax.decoding.soft`) share the :class:`Decoded`
result and its confidence.

A jitted call pays a dispatch however small its work, and one query's work is
only a (p, d) matrix-vector product, k argmaxes and k look-ups.
:class:`SmallDecoder` is the numpy lane for such queries: the templates
transposed (rows, d), C-contiguous, so the product streams rows; the CRT
tables as Python ints (for two periods, one table of every phase pair's
place). It gives the kernel's index up to float32 rounding of the
product (a phase can differ only where two phases tie to ~1e-6). OpenBLAS runs
``sgemv`` on one thread below ``rows * cols`` = :data:`GEMV_THREADED` elements
and on its thread pool from there, so the matrix gets zero rows up to that size
when that costs at most :data:`PAD_AT_MOST` more bytes and there are cores to
share it. Where the periods are near-equal every period's templates start a
block of the same number of rows (:func:`block_rows`), its spare rows zero with
a ``-inf`` bias: one ``argmax`` over the (k, block) view of the scores then finds
every phase at once. The spare rows never win a phase. A float32 batch in host
memory on a CPU is multiplied by numpy's ``sgemm`` where it lies and its scores
decoded by the lane's batch form, :func:`host_decode`; both forms are tested
against the kernel.

Shapes: b queries, d features, p = sum(periods) templates, k periods.
"""

from __future__ import annotations

import functools
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
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
from rhythmic_jax.map.periods import crt_tables, period_offsets
from rhythmic_jax.map.pytree import Templates, decision_values
from rhythmic_jax.validate import check_int

__all__ = [
    "GEMV_THREADED",
    "SMALL_BATCH",
    "Decoded",
    "SmallDecoder",
    "block_rows",
    "check_scores",
    "decode",
    "gemv_rows",
    "hard_decode",
    "host_decode",
]

SMALL_BATCH = 8  # up to this many queries numpy beats a jitted call on 2 cores
GEMV_THREADED = 460_800  # OpenBLAS's sgemv uses its thread pool from this size
PAD_AT_MOST = 1.25  # row padding allowed to reach it (x the template bytes)
PAIR_TABLE = 1 << 20  # two periods: one place table up to this many pairs


@jit
def _confidence(index, score, runner_up):
    return jnp.where(index >= 0, score - runner_up, 0.0).astype(score.dtype)


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
        """``score - runner_up`` (``inf`` without a rival, ``0`` for no match),
        computed where the fields lie: in host memory by numpy (a program per
        batch size would cost more than the subtraction), on another device or
        inside a trace by JAX."""
        host = [in_host_memory(f) for f in self]
        if any(f is None for f in host):
            return _confidence(*self)
        index, score, runner = host
        with np.errstate(invalid="ignore"):  # -inf - -inf of a no match
            return np.where(index >= 0, score - runner, 0.0).astype(score.dtype)


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
def _tables(groups: Groups) -> tuple[tuple[np.ndarray, ...], int]:
    """Per-group int32 tables whose sum (mod the modulus) is the place."""
    if groups.kind == "periods":
        tables, big_m = crt_tables(groups.sizes)
    else:  # mixed radix: digit j of group k is worth j * weight_k
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
        return Decoded((seg * s + best).astype(jnp.int32), total, total - gap)
    tables, big_m = _tables(groups)
    index = jnp.zeros(lead, jnp.int32)
    total = jnp.zeros(lead, scores.dtype)
    gap = jnp.full(lead, jnp.inf, scores.dtype)
    for off, t, table in zip(offs, groups.sizes, tables, strict=True):
        phase, top, margin = _top_two(scores[:, off : off + t])
        index = (index + jnp.asarray(table)[phase]) % big_m
        total = total + top
        gap = jnp.minimum(gap, margin)
    found = index < n
    return Decoded(
        jnp.where(found, index, -1),
        jnp.where(found, total, jnp.asarray(-jnp.inf, scores.dtype)),
        total - gap,
    )


_hard_jit = functools.partial(jit, static_argnames=("groups", "n"))(_hard)


def hard_decode(
    scores: jax.Array, periods: Sequence[int] | Groups, n: int | None = None
) -> Decoded:
    """The hard decode of decision values (..., p): per-group argmax, then the place.

    Args:
      scores: (..., p) decision values, group k in columns ``off_k : off_k + t_k``.
      periods: pairwise co-prime periods, or a map's
        :class:`~rhythmic_jax.map.groups.Groups` (any layout).
      n: number of places (default: every combination); a combination
        ``>= n`` is no match.

    Returns:
      :class:`Decoded` with the scores' leading shape: index int32 (-1 = no
      match), score the sum of the per-group maxima (-inf for no match), and
      runner_up such that ``confidence = min_k (top1_k - top2_k)``. Inside a trace
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
    out = _hard_jit(scores.reshape((-1, scores.shape[-1])), groups, n)
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
    (p,)): Decoded (b,), one program per bucket of rows.

    The batch is padded to a power-of-two bucket
    (:func:`rhythmic_jax.decoding.buckets.pad_rows`), so a new batch size in a
    bucket compiles nothing, uploaded once, and decoded on the device in chunks
    of :data:`~rhythmic_jax.decoding.buckets.CHUNK` rows (at most CHUNK x p
    float32 scores at a time); the results are cut where they were computed and
    stay there until the caller reads them. A float32 numpy batch on a CPU is
    multiplied where it lies, by numpy's BLAS ``sgemm`` (handing a large
    unaligned batch to XLA copies it first, which costs more than the product),
    and its (b, p) scores are decoded there by the numpy lane
    (:func:`host_decode`; a hierarchical layout's by the kernel).
    """
    if not isinstance(periods, Groups):
        periods = Groups("periods", tuple(int(t) for t in periods))
    groups = periods
    n = groups.capacity if n is None else int(n)
    if (
        isinstance(queries, np.ndarray)
        and queries.dtype == np.float32
        and queries.ndim == 2
        and not any(isinstance(v, jax.core.Tracer) for v in params)
        and jax.default_backend() == "cpu"
    ):
        s = queries @ np.asarray(params[0])
        s += np.asarray(params[1], s.dtype)
        if groups.kind != "hierarchical":
            return host_decode(s, groups, n)
        b = len(s)
        return head(_hard_jit(pad_rows(s)[0], groups, n), b)
    padded, b = pad_rows(queries)
    # a device array always: the jit cache keys a numpy argument apart from a
    # device array of the same shape, so a numpy batch compiled a second program
    padded = padded if isinstance(padded, jax.core.Tracer) else jax.device_put(padded)
    chunk = buckets.CHUNK
    count = chunk_count(b, chunk)
    return head(_localise(Templates(*params), padded, count, groups, n, chunk), b)


def host_decode(s: np.ndarray, groups: Groups, n: int) -> Decoded:
    """The kernel's Decoded (b,) of a host batch's scores s (b, p) (a periods
    or mixed-radix layout) in numpy, where they lie: the numpy lane's batch
    form. ``s`` is the caller's scratch and is overwritten (each group's best
    phase is masked to find the runner-up).

    On a CPU the kernel's strided reductions over a group's columns cost as
    much as a tenth of the product before them (``reports/decode.md``); numpy's
    argmax and max over the same columns cost a fraction of that. An argmax
    is the first maximal phase, as the kernel's. The scores are finite (the
    queries are checked before): a row with a NaN is not answered as the
    kernel answers it.
    """
    tables, big_m = _tables(groups)
    b = len(s)
    rows = np.arange(b)
    index = np.zeros(b, np.int64)
    total = np.zeros(b, s.dtype)
    gap = np.full(b, np.inf, s.dtype)
    for off, t, table in zip(groups.offsets, groups.sizes, tables, strict=True):
        block = s[:, off : off + t]
        phase = block.argmax(axis=1)
        top = block[rows, phase]
        if t > 1:
            block[rows, phase] = -np.inf
            np.minimum(gap, top - block.max(axis=1), out=gap)
        index += table[phase]
        total += top
    index %= big_m
    found = index < n
    return Decoded(
        np.where(found, index, -1).astype(np.int32),
        np.where(found, total, np.asarray(-np.inf, s.dtype)),
        total - gap,
    )


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


# ------------------------------------------------------------ the numpy lane
def gemv_rows(p: int, d: int, cores: int | None = None) -> int:
    """Rows to store p templates of d numbers with: p, or the fewest rows that
    put a (rows, d) ``sgemv`` on OpenBLAS's thread pool when that is at most
    :data:`PAD_AT_MOST` x p and ``cores`` (default: this process's) >= 2."""
    cores = len(os.sched_getaffinity(0)) if cores is None else cores
    need = -(-GEMV_THREADED // max(d, 1))
    return need if cores >= 2 and p < need <= PAD_AT_MOST * p else p


def block_rows(periods: Sequence[int], d: int, cores: int | None = None) -> int | None:
    """Rows of every period's block in :class:`SmallDecoder`: the longest period,
    or more where k blocks reach :func:`gemv_rows` of the templates; None where k
    blocks of the longest period would hold more than :data:`PAD_AT_MOST` x the
    templates (very unequal periods keep one contiguous run of rows)."""
    k, p = len(periods), sum(periods)
    block = max(periods)
    if k * block > PAD_AT_MOST * p:
        return None
    return max(block, -(-gemv_rows(p, d, cores) // k))


@dataclass(frozen=True, eq=False)
class SmallDecoder:
    """The hard decode's index of one query in numpy: ``wt`` (rows, d) and ``b``
    (rows,) float32 (rows >= p: :func:`gemv_rows`' zero padding), the periods'
    column ``slices``, CRT ``tables`` (k tuples of ints), their modulus ``big_m``,
    the place count ``n`` (an index >= n is no match, -1), for two periods
    ``pairs``: the place of every phase pair (lists of ints, -1 no match), or
    None, and ``block``: the rows of every period's block (:func:`block_rows`),
    or None."""

    wt: np.ndarray
    b: np.ndarray
    slices: tuple[slice, ...]
    tables: tuple[tuple[int, ...], ...]
    big_m: int
    n: int
    pairs: tuple[list[int], ...] | None = None
    block: int | None = None

    @classmethod
    def build(cls, params, periods: Sequence[int], n: int) -> SmallDecoder:
        """From a map's templates ``w`` (d, p), ``b`` (p,) and its periods."""
        periods = tuple(int(t) for t in periods)
        tables, big_m = crt_tables(periods)
        offs = period_offsets(periods)
        w = np.asarray(params[0], np.float32)
        bias = np.asarray(params[1], np.float32)
        d, p = w.shape
        block = block_rows(periods, d)
        if block is None:  # one run of rows, zero-padded for the thread pool
            starts = offs
            wt = np.zeros((gemv_rows(p, d), d), np.float32)
            b = np.zeros(len(wt), np.float32)
        else:  # a block per period; the spare rows never win a phase
            starts = tuple(i * block for i in range(len(periods)))
            wt = np.zeros((len(periods) * block, d), np.float32)
            b = np.full(len(wt), -np.inf, np.float32)
        for o, start, t in zip(offs, starts, periods, strict=True):
            wt[start : start + t] = w[:, o : o + t].T
            b[start : start + t] = bias[o : o + t]
        pairs = None
        if len(periods) == 2 and big_m <= PAIR_TABLE:
            place = (tables[0][:, None] + tables[1][None, :]) % big_m
            pairs = tuple(np.where(place < n, place, -1).tolist())
        slices = tuple(slice(o, o + t) for o, t in zip(starts, periods, strict=True))
        tables = tuple(tuple(int(v) for v in t) for t in tables)
        return cls(wt, b, slices, tables, big_m, int(n), pairs, block)

    def place(self, q: np.ndarray) -> int | None:
        """Place of one query ``q`` (d,) float32 (-1 for no match), or None when
        a period's top score is not finite (``q`` holds a NaN or an inf: every
        score is then NaN or infinite, so this checks the whole query)."""
        s = self.wt @ q
        s += self.b
        if self.pairs is not None and self.block is not None:  # the fast lane
            j, k = s.reshape(2, self.block).argmax(1).tolist()
            if math.isfinite(s[j]) and math.isfinite(s[self.block + k]):
                return self.pairs[j][k]
            return None
        if self.block is not None:
            phases = s.reshape(len(self.slices), self.block).argmax(1).tolist()
        else:
            phases = [int(s[sl].argmax()) for sl in self.slices]
        i = 0
        for sl, table, j in zip(self.slices, self.tables, phases, strict=True):
            if not math.isfinite(s[sl.start + j]):  # a NaN wins any argmax
                return None
            i += table[j]
        i %= self.big_m
        return i if i < self.n else -1
