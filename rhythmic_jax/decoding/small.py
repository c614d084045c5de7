"""The paper's hard decode for one or a few queries, in numpy (no dispatch).

A jitted JAX call costs about a hundred microseconds of dispatch on CPU however
small its work; one query's work is a (p, d) matrix-vector product (BLAS
``sgemv``), k argmaxes and k Chinese-remainder table look-ups, a few tens of
microseconds. :class:`SmallDecoder` holds the templates transposed (p, d),
C-contiguous, so the product streams rows, and the CRT tables as Python ints
(for two periods, one table of every phase pair's place).
It gives the same :class:`~rhythmic_jax.decoding.hard.Decoded` as
:func:`rhythmic_jax.decoding.hard.decode` (the batch decode) up to float32 rounding of
the product (a phase can differ only where two phases tie to ~1e-6).

The product is the whole cost of one query (the 201 x 2048 float32 templates of
a 10^4-place map are 1.6 MB, read once per query). OpenBLAS, numpy's BLAS, runs
``sgemv`` on one thread below ``rows * cols`` = :data:`GEMV_THREADED` elements
and on its thread pool from there; such a map sits just below, so its matrix
gets zero rows up to that size when that costs at most
:data:`PAD_AT_MOST` more bytes and there are cores to share it
(``reports/single_query.md``: 28 -> 21 us on 2 cores). The price is the tail on
a busy machine: the call waits for the pool's other thread, which the scheduler
may hold back for milliseconds (the report's p95 under load).

Where the periods are near-equal (the paper's), every period's templates start
a block of the same number of rows (:func:`block_rows`), its spare rows zero
with a ``-inf`` bias: one ``argmax`` over the (k, block) view of the scores then
finds every phase at once, a numpy call per period less on every query. The
spare rows never win a phase and no period's columns reach them.

Names: b queries, d features, p = sum(periods) templates, k periods.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from rhythmic_jax.decoding.hard import Decoded
from rhythmic_jax.map.periods import crt_tables, period_offsets
from rhythmic_jax.solvers.objective import Templates
from rhythmic_jax.validate import check_features

__all__ = ["GEMV_THREADED", "SMALL_BATCH", "SmallDecoder", "block_rows", "gemv_rows"]

SMALL_BATCH = 8  # up to this many queries numpy beats a jitted call on 2 cores
GEMV_THREADED = 460_800  # OpenBLAS's sgemv uses its thread pool from this size
PAD_AT_MOST = 1.25  # row padding allowed to reach it (x the template bytes)
PAIR_TABLE = 1 << 20  # two periods: one place table up to this many pairs


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
    """Hard decode in numpy: ``wt`` (rows, d) and ``b`` (rows,) float32 (rows >=
    p: :func:`gemv_rows`' zero padding), the periods' column ``slices``, CRT
    ``tables`` (k lists of ints), their modulus ``big_m``, the place count ``n``
    (an index >= n is no match, -1), for two periods ``pairs``: the place of
    every phase pair (lists of ints, -1 no match), or None, and ``block``: the
    rows of every period's block (:func:`block_rows`), or None."""

    wt: np.ndarray
    b: np.ndarray
    slices: tuple[slice, ...]
    tables: tuple[tuple[int, ...], ...]
    big_m: int
    n: int
    params: Templates | None = None  # what it was built from (identity check)
    pairs: tuple[list[int], ...] | None = None
    block: int | None = None

    @classmethod
    def build(cls, params: Templates, periods: Sequence[int], n: int):
        """From a map's templates ``w`` (d, p), ``b`` (p,) and its periods."""
        periods = tuple(int(t) for t in periods)
        tables, big_m = crt_tables(periods)
        offs = period_offsets(periods)
        w = np.asarray(params.w, np.float32)
        bias = np.asarray(params.b, np.float32)
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
        return cls(
            wt=wt,
            b=b,
            slices=tuple(slice(o, o + t) for o, t in zip(starts, periods, strict=True)),
            tables=tuple(tuple(int(v) for v in t) for t in tables),
            big_m=big_m,
            n=int(n),
            params=params,
            pairs=pairs,
            block=block,
        )

    def _phases(self, s: np.ndarray) -> list[int]:
        """Argmax phase of every period in the scores ``s`` (rows,)."""
        if self.block is not None:
            return s.reshape(len(self.slices), self.block).argmax(1).tolist()
        return [int(s[sl].argmax()) for sl in self.slices]

    def index(self, q: np.ndarray) -> int:
        """Place of one query ``q`` (d,) float32; -1 for no match."""
        s = self.wt @ q
        s += self.b
        phases = self._phases(s)
        if self.pairs is not None:
            return self.pairs[phases[0]][phases[1]]
        i = sum(table[j] for table, j in zip(self.tables, phases, strict=True))
        i %= self.big_m
        return i if i < self.n else -1

    def place(self, q: np.ndarray) -> int | None:
        """:meth:`index` of one query ``q`` (d,) float32, or None when a
        period's top score is not finite (``q`` holds a NaN or an inf: every
        score is then NaN or infinite, so this checks the whole query)."""
        s = self.wt @ q
        s += self.b
        if self.pairs is not None and self.block is not None:  # the fast lane
            j, k = s.reshape(2, self.block).argmax(1).tolist()
            if math.isfinite(s[j]) and math.isfinite(s[self.block + k]):
                return self.pairs[j][k]
            return None
        i = 0
        for sl, table, j in zip(self.slices, self.tables, self._phases(s), strict=True):
            if not math.isfinite(s[sl.start + j]):  # a NaN wins any argmax
                return None
            i += table[j]
        i %= self.big_m
        return i if i < self.n else -1

    def places(self, q, d: int, embed=None) -> np.ndarray | None:
        """Places (b,) int64 of up to :data:`SMALL_BATCH` queries (b, d), one
        matrix-vector product each and nothing else (no runner-up, no dispatch);
        None for more queries. ``embed``: applied to checked queries first (an
        embedding's (b, d) -> (b, k)). A float32 (b, d) array without ``embed``
        takes the fast lane: the scores' finiteness checks the values."""
        if (
            embed is None
            and type(q) is np.ndarray
            and q.dtype == np.float32
            and q.ndim == 2
            and 0 < len(q) <= SMALL_BATCH
            and q.shape[1] == d
        ):
            found = [self.place(row) for row in q]
            if None not in found:
                return np.array(found, np.int64)
        x = check_features(q, "queries", d=d)
        if len(x) > SMALL_BATCH:
            return None
        if embed is not None:
            x = np.asarray(embed(x), np.float32)
        return np.array([self.index(row) for row in x], np.int64)

    def __call__(self, q: np.ndarray) -> Decoded:
        """Decode queries (b, d) float32: index (b,) int32 (-1 no match), score
        (b,) (sum of the per-period maxima, -inf for no match) and runner_up
        (score minus the smallest top-1 / top-2 margin), as numpy arrays."""
        # one matrix-vector product per row: OpenBLAS's gemm on a single row
        # wakes its thread pool, which costs milliseconds on a busy machine
        s = (
            np.stack([self.wt @ row for row in q])
            if len(q)
            else np.zeros((0, len(self.b)), np.float32)
        )
        s += self.b
        rows = np.arange(len(s))
        index = np.zeros(len(s), np.int64)
        total = np.zeros(len(s), np.float32)
        gap = np.full(len(s), np.inf, np.float32)
        for sl, table in zip(self.slices, self.tables, strict=True):
            block = s[:, sl]
            phase = block.argmax(axis=1)
            top = block[rows, phase]
            index = (index + np.asarray(table, np.int64)[phase]) % self.big_m
            total += top
            if block.shape[1] > 1:
                second = block.copy()
                second[rows, phase] = -np.inf
                gap = np.minimum(gap, top - second.max(axis=1))
        found = index < self.n
        return Decoded(
            np.where(found, index, -1).astype(np.int32),
            np.where(found, total, np.float32(-np.inf)),
            total - gap,
        )
