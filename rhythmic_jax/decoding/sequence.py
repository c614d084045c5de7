"""Sequence decoding in the phase domain: evidence of the last L frames, summed.

The paper leaves sequence matching (SeqSLAM-style) as future work. With rhythmic
templates it needs no descriptors: a query frame seen ``l`` steps ago at phase
``j`` of period ``g`` predicts phase ``(j + o_l) mod tau_g`` now, where
``o_l = round(l * v)`` is how many map frames the traversal moved in ``l`` query
frames at speed ``v`` (map frames per query frame). The accumulated scores at end
frame ``t`` are

    A_g^t[j] = sum_{l=0}^{L-1} s_g^{t-l}[(j - o_l) mod tau_g],

with frames before the start of the query left out (``t < L - 1`` sums ``t + 1``
frames). ``A`` has the layout of a single frame's scores (b, p), so it is decoded
with :func:`rhythmic_jax.decoding.soft.soft_decode`,
:func:`~rhythmic_jax.decoding.soft.topm_decode` or the hard per-period argmax. Cost
``O(L * sum(tau))`` per query frame, independent of ``n``. Over a grid of speeds
(negative: reverse traversal) each speed is decoded and the best-scoring one is kept.

``round`` here rounds half away from zero: ``o_l = sign(v) * floor(|l v| + 1/2)``.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax.decoding.group_decode import group_sequence_decode
from rhythmic_jax.decoding.hard import Decoded, check_scores, hard_decode
from rhythmic_jax.decoding.soft import soft_decode, topm_decode
from rhythmic_jax.errors import InputError
from rhythmic_jax.jit_options import jit
from rhythmic_jax.map.groups import Groups
from rhythmic_jax.validate import check_int

__all__ = [
    "SPEEDS",
    "frame_offsets",
    "sequence_decode",
    "sequence_scores",
]

SPEEDS: tuple[float, ...] = (0.8, 0.9, 1.0, 1.1, 1.2)
"""A grid of traversal speeds (map frames per query frame) around 1."""

METHODS = ("soft", "topm", "hard")


def frame_offsets(length: int, speed: float) -> tuple[int, ...]:
    """Map-frame offsets ``o_l = round(l * speed)`` for ``l = 0 .. length-1``.

    Rounds half away from zero, e.g. ``frame_offsets(5, 1.2) == (0, 1, 2, 4, 5)``.
    """
    out = []
    for step in range(length):
        x = step * float(speed)
        out.append(int(math.copysign(math.floor(abs(x) + 0.5), x)))
    return tuple(out)


def _check_length(length: int) -> int:
    return check_int(length, "length", 1)


def _check_speeds(speeds: Sequence[float] | float) -> tuple[float, ...]:
    if isinstance(speeds, int | float | np.number):
        speeds = (speeds,)
    try:
        out = tuple(float(v) for v in speeds)
    except (TypeError, ValueError):
        raise InputError(
            f"speeds must be a sequence of numbers, got {speeds!r}"
        ) from None
    if not out or not all(math.isfinite(v) for v in out):
        raise InputError(
            f"speeds must be a non-empty sequence of finite numbers: {out}"
        )
    return out


@functools.lru_cache(maxsize=128)
def _shift_columns(periods: tuple[int, ...], length: int, speed: float) -> np.ndarray:
    """(L, p) int32: ``G[l, off_g + j] = off_g + (j - o_l) mod tau_g``."""
    offs = frame_offsets(length, speed)
    out = np.empty((length, sum(periods)), np.int32)
    start = 0
    for t in periods:
        j = np.arange(t)
        for step, o in enumerate(offs):
            out[step, start : start + t] = start + (j - o) % t
        start += t
    return out


def _accumulate(scores: jax.Array, columns: np.ndarray) -> jax.Array:
    """scores (T, p), columns (L, p) -> (T, p): sum_l shift_l(scores[t - l])."""
    length, (frames, p) = columns.shape[0], scores.shape
    padded = jnp.concatenate([jnp.zeros((length - 1, p), scores.dtype), scores])
    table = jnp.asarray(columns)

    def add(step, acc):
        rows = jax.lax.dynamic_slice_in_dim(padded, length - 1 - step, frames, axis=0)
        return acc + jnp.take(rows, table[step], axis=1)

    return jax.lax.fori_loop(0, length, add, jnp.zeros_like(scores))


@functools.partial(jit, static_argnames=("periods", "length", "speed"))
def _sequence_scores_jit(scores, periods, length, speed):
    return _accumulate(scores, _shift_columns(periods, length, speed))


def _check_frames(scores, periods, n=None) -> tuple[jax.Array, tuple[int, ...], int]:
    scores = jnp.asarray(scores)
    per, n = check_scores(scores, periods, n)
    if scores.ndim != 2:
        raise InputError(
            f"scores must have shape (T, p) for T query frames, got {scores.shape}"
        )
    return scores, per, n


def sequence_scores(
    scores: jax.Array, periods: Sequence[int], length: int, speed: float = 1.0
) -> jax.Array:
    """Accumulated phase scores of every end frame: scores (T, p) -> A (T, p).

    ``A[t]`` at column ``off_g + j`` is ``sum_{l=0}^{min(t, L-1)}
    scores[t-l, off_g + (j - o_l) mod tau_g]`` with ``o_l = round(l * speed)``.
    """
    scores, per, _ = _check_frames(scores, periods)
    length = _check_length(length)
    (speed,) = _check_speeds(speed)
    return _sequence_scores_jit(scores, per, length, speed)


@functools.partial(
    jit,
    static_argnames=("periods", "n", "length", "speeds", "method", "top", "exclude"),
)
def _decode_jit(scores, periods, n, length, speeds, method, top, exclude):
    results = []
    for v in speeds:
        acc = _accumulate(scores, _shift_columns(periods, length, v))
        if method == "soft":
            results.append(soft_decode(acc, periods, n, exclude=exclude))
        elif method == "topm":
            results.append(topm_decode(acc, periods, n, top, exclude=exclude))
        else:
            results.append(hard_decode(acc, periods, n))
    # (S, T) per field: one row per speed
    stacked = Decoded(*(jnp.stack(x) for x in zip(*results, strict=True)))
    pick = jnp.argmax(stacked.score, axis=0)[None, :]
    best = Decoded(*(jnp.take_along_axis(x, pick, axis=0)[0] for x in stacked))
    return best.index, best.confidence


def sequence_decode(
    scores: jax.Array,
    periods: Sequence[int] | Groups,
    n: int,
    length: int,
    speeds: Sequence[float] = (1.0,),
    method: str = "soft",
    top: int = 3,
    *,
    exclude: int = 0,
) -> tuple[jax.Array, jax.Array]:
    """Decode every end frame of a query sequence: scores (T, p) -> index, confidence.

    For each speed ``v`` the accumulated scores ``A_v = sequence_scores(scores,
    periods, length, v)`` are decoded with ``method`` ("soft": exact score sum,
    "topm": combinations of the ``top`` best phases, "hard": per-period argmax +
    CRT); per frame the speed with the highest decoded score wins (first in
    ``speeds`` on ties).

    ``periods`` may be a map's :class:`~rhythmic_jax.map.groups.Groups`; a
    mixed-radix or hierarchical map sums its evidence in the place domain and
    takes the argmax whatever the method
    (:func:`rhythmic_jax.decoding.group_decode.group_sequence_decode`).

    Returns:
      index: (T,) int32, -1 for no match; confidence: (T,) best minus runner-up
      score of the winning speed (for "hard" the smallest per-period top-2 gap).
    """
    if method not in METHODS:
        raise InputError(f"method must be one of {METHODS}, got method={method!r}")
    length = _check_length(length)
    speeds = _check_speeds(speeds)
    if isinstance(periods, Groups) and periods.kind != "periods":
        offsets = [frame_offsets(length, v) for v in speeds]
        return group_sequence_decode(scores, periods, n, offsets, exclude=exclude)
    scores, per, n = _check_frames(scores, getattr(periods, "sizes", periods), n)
    check_int(top, "top", 1)
    check_int(exclude, "exclude", 0)
    if method != "soft" and math.prod(per) >= 2**30:
        raise InputError(f"prod(periods)={math.prod(per)} too large for {method!r}")
    if scores.shape[0] == 0:
        return jnp.zeros((0,), jnp.int32), jnp.zeros((0,), scores.dtype)
    return _decode_jit(scores, per, n, length, speeds, method, int(top), int(exclude))
