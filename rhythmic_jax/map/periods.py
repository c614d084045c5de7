"""Integer maths of periods: candidates, co-primality, choice, storage (no JAX).

A map of ``n`` frames keeps ``r`` periods ``tau_1 .. tau_r``. Frame ``i`` has phase
``i mod tau_g`` in period ``g``; with pairwise co-prime periods whose product is at
least ``n`` the phases identify the frame uniquely (Chinese remainder theorem,
paper Sec. III-B, Eq. 5). The map stores ``sum(tau) * (d + 1)`` numbers (weights
and a bias per template), so storage grows as ``r * n ** (1 / r)``.

Integer maths in plain Python; the functions that return arrays import numpy
when they run (the command line checks a layout without it).
"""

from __future__ import annotations

import functools
import itertools
import math
import numbers
from collections.abc import Sequence
from typing import TYPE_CHECKING

from rhythmic_jax.errors import InputError

if TYPE_CHECKING:
    import numpy as np

__all__ = [
    "candidate_periods",
    "choose_periods",
    "compression_ratio",
    "crt_tables",
    "database_bytes",
    "nominal_periods",
    "pairwise_coprime",
    "period_offsets",
    "phases",
    "place_columns",
    "storage_bytes",
]


def _whole(value, low: int) -> bool:
    """Whether ``value`` is a Python or numpy integer (not a bool) >= ``low``:
    the arguments are checked here, in plain Python, before any maths."""
    integral = isinstance(value, numbers.Integral) and not isinstance(value, bool)
    return integral and value >= low


def _iroot_ceil(n: int, r: int) -> int:
    """Smallest integer t with t ** r >= n (exact, no float rounding)."""
    t = max(1, round(n ** (1.0 / r)))
    while t**r < n:
        t += 1
    while t > 1 and (t - 1) ** r >= n:
        t -= 1
    return t


def candidate_periods(
    n: int, r: int = 2, level: int = 1, count: int = 7
) -> tuple[int, ...]:
    """Candidate periods ``level * ceil(n ** (1/r)) + {0 .. count-1}``.

    The paper samples candidates from ``ceil(n ** (1/r))`` upwards (Sec. III-B);
    ``level`` c = 2, 3, 4 gives the longer periods of its "T = c sqrt N" runs
    (Table 2, Fig. 8). E.g. ``candidate_periods(7403)`` is 87 .. 93.
    """
    if not _whole(n, 2):
        raise InputError(f"a map needs at least 2 frames, got n={n!r}")
    if not _whole(r, 2):
        raise InputError(f"r (number of periods) must be an integer >= 2, got r={r!r}")
    if not _whole(level, 1):
        raise InputError(f"level must be an integer >= 1, got level={level!r}")
    if not _whole(count, r):
        raise InputError(f"count must be an integer >= r={r}, got count={count!r}")
    base = int(level) * _iroot_ceil(int(n), int(r))
    if base < 2:
        raise InputError(f"n={n} is too small for r={r} periods at level {level}")
    return tuple(base + j for j in range(int(count)))


def pairwise_coprime(periods: Sequence[int]) -> bool:
    """True when every pair of periods has greatest common divisor 1."""
    return all(math.gcd(a, b) == 1 for a, b in itertools.combinations(periods, 2))


def storage_bytes(periods: Sequence[int], d: int, itemsize: int = 4) -> int:
    """Bytes of a map: ``sum(tau) * (d + 1) * itemsize`` (weights plus a bias).

    Paper Table 1: N = 7403 with periods summing to 181 at d = 4096, float32, is
    ``181 * 4097 * 4 = 2,966,228`` bytes.
    """
    return int(sum(int(t) for t in periods)) * (int(d) + 1) * int(itemsize)


def database_bytes(n: int, d: int, itemsize: int = 4) -> int:
    """Bytes of the uncompressed database of ``n`` descriptors: ``n * d * itemsize``."""
    return int(n) * int(d) * int(itemsize)


def compression_ratio(periods: Sequence[int], n: int, d: int) -> float:
    """Map bytes over database bytes (same itemsize): ``sum(tau) (d+1) / (n d)``."""
    return storage_bytes(periods, d, 1) / database_bytes(n, d, 1)


def choose_periods(
    candidates: Sequence[int],
    errors: Sequence[float],
    n: int,
    r: int = 2,
) -> tuple[int, ...]:
    """Choose ``r`` pairwise co-prime candidates with product >= ``n``.

    Among all valid sets the one with the least summed training error wins; ties go
    to the least storage (smallest sum), then to the lexicographically smallest set.
    Returns the periods in increasing order.

    Raises:
      InputError: on bad arguments, or when no subset of ``r`` candidates is
        pairwise co-prime with a product of at least ``n``.
    """
    if len(candidates) != len(errors):
        raise InputError(
            f"{len(candidates)} candidate periods but {len(errors)} training errors"
        )
    for name, value in (("n", n), ("r", r), *(("candidate", t) for t in candidates)):
        if not _whole(value, 1):
            raise InputError(f"{name} must be a positive integer, got {value!r}")
    if len(set(int(t) for t in candidates)) != len(candidates):
        raise InputError(f"candidate periods {tuple(candidates)} repeat a period")
    if not all(math.isfinite(float(e)) for e in errors):
        raise InputError(f"training errors {tuple(errors)} must all be finite")
    err = {int(t): float(e) for t, e in zip(candidates, errors, strict=True)}
    best: tuple[float, int, tuple[int, ...]] | None = None
    for combo in itertools.combinations(sorted(err), r):
        if math.prod(combo) < n or not pairwise_coprime(combo):
            continue
        key = (round(sum(err[t] for t in combo), 12), sum(combo), combo)
        if best is None or key < best:
            best = key
    if best is None:
        raise InputError(
            f"no {r} pairwise co-prime periods among {tuple(sorted(err))} have a "
            f"product >= n={n}; use more candidates or a higher level"
        )
    return best[2]


def phases(index: np.ndarray | int, periods: Sequence[int]) -> np.ndarray:
    """Phase of frame ``index`` in every period: ``index mod tau_g``, shape (..., r)."""
    import numpy as np

    idx = np.asarray(index, dtype=np.int64)
    return np.stack([idx % int(t) for t in periods], axis=-1)


def crt_tables(periods: Sequence[int]) -> tuple[tuple[np.ndarray, ...], int]:
    """Chinese-remainder lookup tables for pairwise co-prime ``periods``.

    With ``M = prod(tau)``, ``M_g = M / tau_g`` and ``u_g = M_g^{-1} mod tau_g``,
    the index with phases ``j_g`` is ``(sum_g T_g[j_g]) mod M`` where
    ``T_g[j] = j * M_g * u_g mod M``. Each table entry is below M, so a running sum
    reduced mod M after every addition stays below 2M (no overflow for M < 2**30
    in int32).

    Returns:
      tables: one int64 array of shape (tau_g,) per period; and M.
    """
    import numpy as np

    periods = tuple(int(t) for t in periods)
    if len(periods) < 1 or min(periods) < 1:
        raise InputError(f"periods must be positive integers, got {periods}")
    if not pairwise_coprime(periods):
        raise InputError(f"periods {periods} are not pairwise co-prime")
    m = math.prod(periods)
    tables = []
    for t in periods:
        mk = m // t
        coef = (mk * pow(mk, -1, t)) % m if t > 1 else 0
        tables.append(np.array([(j * coef) % m for j in range(t)], dtype=np.int64))
    return tuple(tables), m


def nominal_periods(
    n: int, r: int = 2, level: int = 1, count: int = 7
) -> tuple[int, ...]:
    """The periods a map of ``n`` frames takes before any training error is known.

    :func:`choose_periods` over :func:`candidate_periods` with equal errors: the
    least-storage pairwise co-prime set (raises InputError when there is none).
    """
    cands = candidate_periods(n, r, level, count)
    return choose_periods(cands, [0.0] * len(cands), n, r)


def period_offsets(periods: Sequence[int]) -> tuple[int, ...]:
    """Column offset of each period's templates: ``(0, tau_1, tau_1 + tau_2, ...)``."""
    return tuple(int(v) for v in itertools.accumulate((0, *periods[:-1])))


@functools.lru_cache(maxsize=64)
def place_columns(periods: tuple[int, ...], n: int) -> np.ndarray:
    """(r, n) int32: column of place i in period g, ``off_g + i mod tau_g``."""
    import numpy as np

    i = np.arange(n)
    return np.stack(
        [o + i % t for o, t in zip(period_offsets(periods), periods, strict=True)]
    ).astype(np.int32)
