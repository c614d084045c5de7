"""The host lanes of the hard decode: numpy where the queries lie, as the kernel.

A jitted call pays a dispatch however small its work, and one query's work is
only a (p, d) matrix-vector product, r argmaxes and r look-ups; a large float32
batch in host memory on a CPU is copied before XLA multiplies it, which costs
more than the product. Two lanes answer such queries in numpy, each tested
against the kernel (:func:`rhythmic_jax.decoding.hard.hard_decode`):

- the batch lane, :func:`decode`: the scores ``q @ w + b`` by numpy's BLAS
  ``sgemm`` where the batch lies, decoded by :func:`host_decode` (a
  hierarchical layout's scores by the kernel);
- the single-query lane, :class:`SmallDecoder` (built once per map by
  :func:`lane`): the templates transposed (rows, d), C-contiguous, so the
  product streams rows; the CRT tables as Python ints (for two periods, one
  table of every phase pair's place). It gives the kernel's index up to
  float32 rounding of the product (a phase can differ only where two phases
  tie to ~1e-6).

OpenBLAS runs ``sgemv`` on one thread below ``rows * cols`` =
:data:`GEMV_THREADED` elements and on its thread pool from there, so the
single-query matrix gets zero rows up to that size when that costs at most
:data:`PAD_AT_MOST` more bytes and there are cores to share it. Where the
periods are near-equal every period's templates start a block of the same
number of rows (:func:`block_rows`), its spare rows zero with a ``-inf`` bias:
one ``argmax`` over the (r, block) view of the scores then finds every phase at
once. The spare rows never win a phase.

Shapes: b queries, d features, p = sum(periods) templates, r periods.
"""

from __future__ import annotations

import math
import os
import weakref
from collections.abc import Sequence
from dataclasses import dataclass

import jax
import numpy as np

from rhythmic_jax.decoding.buckets import head, pad_rows
from rhythmic_jax.decoding.hard import Decoded, hard_kernel, place_tables
from rhythmic_jax.map.groups import Groups
from rhythmic_jax.map.periods import crt_tables, period_offsets
from rhythmic_jax.map.pytree import Map

__all__ = [
    "GEMV_THREADED",
    "SMALL_BATCH",
    "SmallDecoder",
    "block_rows",
    "decode",
    "gemv_rows",
    "host_decode",
    "lane",
    "takes",
]

SMALL_BATCH = 8  # up to this many queries numpy beats a jitted call on 2 cores
GEMV_THREADED = 460_800  # OpenBLAS's sgemv uses its thread pool from this size
PAD_AT_MOST = 1.25  # row padding allowed to reach it (x the template bytes)
PAIR_TABLE = 1 << 20  # two periods: one place table up to this many pairs


# ------------------------------------------------------------ the batch lane
def takes(params, queries) -> bool:
    """Whether the batch lane answers queries (b, d) by templates ``params``: a
    float32 numpy batch, concrete templates, on a CPU."""
    return (
        isinstance(queries, np.ndarray)
        and queries.dtype == np.float32
        and queries.ndim == 2
        and not any(isinstance(v, jax.core.Tracer) for v in params)
        and jax.default_backend() == "cpu"
    )


def decode(params, queries: np.ndarray, groups: Groups, n: int) -> Decoded:
    """The kernel's Decoded (b,) of a float32 host batch (b, d) by templates
    ``params`` (``w`` (d, p), ``b`` (p,)): numpy's ``sgemm`` where the batch
    lies, then :func:`host_decode` (a hierarchical layout: the kernel, on the
    scores padded to their bucket)."""
    s = queries @ np.asarray(params[0])
    s += np.asarray(params[1], s.dtype)
    if groups.kind != "hierarchical":
        return host_decode(s, groups, n)
    return head(hard_kernel(pad_rows(s)[0], groups, n), len(s))


def host_decode(s: np.ndarray, groups: Groups, n: int) -> Decoded:
    """The kernel's Decoded (b,) of a host batch's scores s (b, p) (a periods
    or mixed-radix layout) in numpy, where they lie. ``s`` is the caller's
    scratch and is overwritten (each group's best phase is masked to find the
    runner-up).

    On a CPU the kernel's strided reductions over a group's columns cost as
    much as a tenth of the product before them (``reports/decode.md``); numpy's
    argmax and max over the same columns cost a fraction of that. An argmax
    is the first maximal phase, as the kernel's; a row whose summed top
    score is not finite (a NaN or inf in its query) is no match, as in the
    kernel.
    """
    tables, big_m = place_tables(groups)
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
    found = (index < n) & np.isfinite(total)
    return Decoded(
        np.where(found, index, -1).astype(np.int32),
        np.where(found, total, np.asarray(-np.inf, s.dtype)),
        total - gap,
    )


# ----------------------------------------------------- the single-query lane
def gemv_rows(p: int, d: int, cores: int | None = None) -> int:
    """Rows to store p templates of d numbers with: p, or the fewest rows that
    put a (rows, d) ``sgemv`` on OpenBLAS's thread pool when that is at most
    :data:`PAD_AT_MOST` x p and ``cores`` (default: this process's) >= 2."""
    cores = len(os.sched_getaffinity(0)) if cores is None else cores
    need = -(-GEMV_THREADED // max(d, 1))
    return need if cores >= 2 and p < need <= PAD_AT_MOST * p else p


def block_rows(periods: Sequence[int], d: int, cores: int | None = None) -> int | None:
    """Rows of every period's block in :class:`SmallDecoder`: the longest period,
    or more where r blocks reach :func:`gemv_rows` of the templates; None where r
    blocks of the longest period would hold more than :data:`PAD_AT_MOST` x the
    templates (very unequal periods keep one contiguous run of rows)."""
    r, p = len(periods), sum(periods)
    block = max(periods)
    if r * block > PAD_AT_MOST * p:
        return None
    return max(block, -(-gemv_rows(p, d, cores) // r))


@dataclass(frozen=True, eq=False)
class SmallDecoder:
    """The hard decode's index of one query in numpy: ``wt`` (rows, d) and ``b``
    (rows,) float32 (rows >= p: :func:`gemv_rows`' zero padding), the periods'
    column ``slices``, CRT ``tables`` (r tuples of ints), their modulus ``big_m``,
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
            j0, j1 = s.reshape(2, self.block).argmax(1).tolist()
            if math.isfinite(s[j0]) and math.isfinite(s[self.block + j1]):
                return self.pairs[j0][j1]
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

    def places(self, q) -> np.ndarray | None:
        """Places (b,) int64 of up to :data:`SMALL_BATCH` float32 queries q (b,
        d) (one matrix-vector product each, the scores' finiteness checking
        the values); None for anything else, or a query that is not finite."""
        if (
            type(q) is np.ndarray
            and q.dtype == np.float32
            and q.ndim == 2
            and 0 < len(q) <= SMALL_BATCH
            and q.shape[1] == self.wt.shape[1]
        ):
            found = [self.place(row) for row in q]
            if None not in found:
                return np.array(found, np.int64)
        return None


_LANES: dict[int, SmallDecoder | None] = {}


def lane(m: Map) -> SmallDecoder | None:
    """The single-query lane of the map value ``m`` where the hard decode may
    answer by it alone (a periods map without codes or embedding, outside a
    trace), else None. Built on first use and kept beside the value, keyed by
    its identity until it is collected (the map is frozen: its templates never
    change under the key), so a query pays one look-up."""
    key = id(m)
    got = _LANES.get(key, False)
    if got is False:
        if isinstance(m.w, jax.core.Tracer):
            return None
        plain = m.embedding is None and m.codebook is None
        got = None
        if plain and m.groups.kind == "periods":
            got = SmallDecoder.build(m.params, m.periods, m.n)
        _LANES[key] = got
        weakref.finalize(m, _LANES.pop, key, None)
    return got
