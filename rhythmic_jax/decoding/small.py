"""The paper's hard decode for one or a few queries, in numpy (no dispatch).

A jitted JAX call costs about a hundred microseconds of dispatch on CPU however
small its work; one query's work is a (p, d) matrix-vector product (BLAS
``sgemv``), k argmaxes and k Chinese-remainder table look-ups, a few tens of
microseconds. :class:`SmallDecoder` holds the templates transposed (p, d),
C-contiguous, so the product streams rows, and the CRT tables as Python ints.
It gives the same :class:`~rhythmic_jax.soft.Decoded` as
:func:`rhythmic_jax.decode.decode` (the batch decode) up to float32 rounding of
the product (a phase can differ only where two phases tie to ~1e-6).

Names: b queries, d features, p = sum(periods) templates, k periods.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from rhythmic_jax.decoding.hard import Decoded
from rhythmic_jax.objective import Templates
from rhythmic_jax.periods import crt_tables, period_offsets

__all__ = ["SMALL_BATCH", "SmallDecoder"]

SMALL_BATCH = 8  # up to this many queries numpy beats a jitted call on 2 cores


@dataclass(frozen=True, eq=False)
class SmallDecoder:
    """Hard decode in numpy: ``wt`` (p, d) and ``b`` (p,) float32, the periods'
    column ``slices``, CRT ``tables`` (k lists of ints), their modulus ``big_m``
    and the place count ``n`` (an index >= n is no match, -1)."""

    wt: np.ndarray
    b: np.ndarray
    slices: tuple[slice, ...]
    tables: tuple[tuple[int, ...], ...]
    big_m: int
    n: int
    params: Templates | None = None  # what it was built from (identity check)

    @classmethod
    def build(cls, params: Templates, periods: Sequence[int], n: int):
        """From a map's templates ``w`` (d, p), ``b`` (p,) and its periods."""
        periods = tuple(int(t) for t in periods)
        tables, big_m = crt_tables(periods)
        offs = period_offsets(periods)
        return cls(
            wt=np.ascontiguousarray(np.asarray(params.w, np.float32).T),
            b=np.asarray(params.b, np.float32),
            slices=tuple(slice(o, o + t) for o, t in zip(offs, periods, strict=True)),
            tables=tuple(tuple(int(v) for v in t) for t in tables),
            big_m=big_m,
            n=int(n),
            params=params,
        )

    def index(self, q: np.ndarray) -> int:
        """Place of one query ``q`` (d,) float32; -1 for no match."""
        s = self.wt @ q
        s += self.b
        i = 0
        for sl, table in zip(self.slices, self.tables, strict=True):
            i += table[int(s[sl].argmax())]
        i %= self.big_m
        return i if i < self.n else -1

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
