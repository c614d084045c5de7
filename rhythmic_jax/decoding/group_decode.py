"""Decoding any layout of groups in the place domain: all the evidence, summed.

A map whose groups are not co-prime periods (:class:`~rhythmic_jax.map.groups.Groups`:
mixed-radix digits, or segments plus fine periods) has no Chinese remainder; it
is decoded from the scores of every place,

    S(i) = sum_g s_g[label_g(i)],

the evidence of every classifier for place ``i`` (for periods, ``label_g(i) = i mod
tau_g`` and this is soft decode (:mod:`rhythmic_jax.decoding.soft`)):

- soft: ``argmax_{i < n} S(i)``, runner-up the best place more than ``exclude``
  frames away (as the periods' soft decode);
- top-m: the same argmax over the places whose label is among the ``top`` best of
  every group (``top = 1``: every group's argmax; ``top >= max(size)``: soft);
- hard (the one kernel, :func:`rhythmic_jax.decoding.hard.hard_decode`):
  mixed radix, the argmax digits give the index directly
  (``sum_g d_g prod(b_{g+1..r})``, no match when it is ``>= n``); hierarchical,
  the argmax segment, then its best place by the summed fine scores. Confidence
  is the smallest top-2 margin (of every digit; of the segment and of the place
  within it);
- every decode's confidence is the answer's score minus its rival's
  (:func:`rhythmic_jax.decoding.hard.confidence`: finite, 0 for no match); top-m
  seeks the rival among the places whose labels are among the ``max(top, 2)``
  best;
- sequences: ``A_t(i) = sum_{l < L} S_{t-l}(i - o_l)`` with ``o_l = round(l v)``
  (frames before the first left out; a place shifted off the route scores the
  mean of its frame), decoded by its argmax over places for every speed ``v``, the
  best-scoring speed kept. Memory ``O(chunk * n)`` per step.

Shapes: b queries (T frames of a sequence), p = sum of the group sizes, n places.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax.decoding.hard import Decoded, hard_decode
from rhythmic_jax.decoding.hard import check_group_scores as check_scores
from rhythmic_jax.decoding.soft import _batched, _best_two, _empty
from rhythmic_jax.errors import InputError
from rhythmic_jax.jit_options import jit
from rhythmic_jax.map.groups import Groups
from rhythmic_jax.validate import check_int as _check_int

__all__ = [
    "check_group_scores",
    "group_hard_decode",
    "group_sequence_decode",
    "group_soft_decode",
    "group_topm_decode",
    "place_scores",
]


def check_group_scores(scores, groups: Groups, n: int | None = None) -> int:
    """Validate scores (..., p) against ``groups`` and ``n`` (default: capacity)."""
    if not isinstance(groups, Groups):
        raise InputError(f"groups must be a Groups, got {groups!r}")
    n = groups.check(groups.capacity if n is None else n)
    check_scores(scores, groups)
    return n


@functools.lru_cache(maxsize=64)
def _columns(groups: Groups, n: int) -> np.ndarray:
    return groups.columns(n)


def _place_sum(scores: jax.Array, groups: Groups, n: int) -> jax.Array:
    """(..., p) -> (..., n): ``S(i) = sum_g scores[..., col_g(i)]``."""
    cols = _columns(groups, n)
    total = jnp.take(scores, cols[0], axis=-1)
    for c in cols[1:]:
        total = total + jnp.take(scores, c, axis=-1)
    return total


@functools.partial(jit, static_argnames=("groups", "n"))
def _place_jit(scores, groups, n):
    return _place_sum(scores, groups, n)


def place_scores(scores: jax.Array, groups: Groups, n: int) -> jax.Array:
    """Summed evidence of every place: scores (..., p) -> (..., n)."""
    n = check_group_scores(scores, groups, n)
    return _place_jit(jnp.asarray(scores), groups, n)


# --------------------------------------------------------------------- soft
def _soft_one(s, groups: Groups, n: int, exclude: int) -> Decoded:
    total = _place_sum(s, groups, n)
    return _best_two(
        total, jnp.arange(n, dtype=jnp.int32), jnp.ones((n,), bool), exclude
    )


def _topm_one(s, groups: Groups, n: int, top: int, exclude: int) -> Decoded:
    """The best place whose labels are among the ``top`` best of every group;
    its rival among those of the ``max(top, 2)`` best (``top = 1`` keeps one
    candidate, measured against the places one label away)."""
    cols = _columns(groups, n)
    wide = max(top, 2)
    valid = jnp.ones((n,), bool)
    rivals = jnp.ones((n,), bool)
    for g, (off, t) in enumerate(zip(groups.offsets, groups.sizes, strict=True)):
        _, best = jax.lax.top_k(s[off : off + t], min(wide, t))
        rank = jnp.full((t,), wide).at[best].set(jnp.arange(len(best)))
        label = rank[cols[g] - off]
        valid = valid & (label < top)
        rivals = rivals & (label < wide)
    total = _place_sum(s, groups, n)
    index = jnp.arange(n, dtype=jnp.int32)
    return _best_two(total, index, valid, exclude, rivals=rivals)


@functools.partial(jit, static_argnames=("groups", "n", "top", "exclude", "batch_size"))
def _decode_jit(scores, groups, n, top, exclude, batch_size):
    if top is None:
        return _batched(
            _soft_one, scores, batch_size, groups=groups, n=n, exclude=exclude
        )
    return _batched(
        _topm_one, scores, batch_size, groups=groups, n=n, top=top, exclude=exclude
    )


def group_soft_decode(
    scores: jax.Array,
    groups: Groups,
    n: int,
    *,
    exclude: int = 0,
    batch_size: int = 256,
) -> Decoded:
    """``argmax_{i < n} S(i)`` of every query: scores (..., p) -> Decoded (...)."""
    n = check_group_scores(scores, groups, n)
    exclude = _check_int(exclude, "exclude", 0)
    batch_size = _check_int(batch_size, "batch_size", 1)
    scores = jnp.asarray(scores)
    if math.prod(scores.shape[:-1]) == 0:
        return _empty(scores.shape[:-1], scores.dtype)
    return _decode_jit(scores, groups, n, None, exclude, batch_size)


def group_topm_decode(
    scores: jax.Array,
    groups: Groups,
    n: int,
    top: int,
    *,
    exclude: int = 0,
    batch_size: int = 256,
) -> Decoded:
    """Best ``S(i)`` over places whose labels are all among their group's ``top`` best.

    Index -1 (score -inf) when no place has such labels (e.g. a mixed-radix
    combination ``>= n`` at ``top = 1``).
    """
    n = check_group_scores(scores, groups, n)
    top = _check_int(top, "top", 1)
    exclude = _check_int(exclude, "exclude", 0)
    batch_size = _check_int(batch_size, "batch_size", 1)
    scores = jnp.asarray(scores)
    if math.prod(scores.shape[:-1]) == 0:
        return _empty(scores.shape[:-1], scores.dtype)
    return _decode_jit(scores, groups, n, top, exclude, batch_size)


# --------------------------------------------------------------------- hard
def group_hard_decode(scores: jax.Array, groups: Groups, n: int) -> Decoded:
    """Hard decode of a mixed or hierarchical map: scores (..., p) -> Decoded (...)
    (the one kernel, :func:`rhythmic_jax.decoding.hard.hard_decode`)."""
    n = check_group_scores(scores, groups, n)
    if groups.kind == "periods":
        raise InputError(
            "periods maps decode with rhythmic_jax.decoding.hard.hard_decode"
        )
    return hard_decode(scores, groups, n)


# ---------------------------------------------------------------- sequences
def _shifted(place: jax.Array, shift: int) -> jax.Array:
    """(F, n) -> (F, n): column i holds ``place[:, i - shift]``, the row mean where
    ``i - shift`` is off the route."""
    f, n = place.shape
    if abs(shift) >= n:
        return jnp.broadcast_to(jnp.mean(place, axis=1, keepdims=True), (f, n))
    fill = jnp.broadcast_to(jnp.mean(place, axis=1, keepdims=True), (f, abs(shift)))
    if shift >= 0:
        return jnp.concatenate([fill, place[:, : n - shift]], axis=1)
    return jnp.concatenate([place[:, -shift:], fill], axis=1)


@functools.partial(
    jit, static_argnames=("groups", "n", "offsets", "exclude", "batch_size")
)
def _sequence_chunk(window, groups, n, offsets, exclude, batch_size):
    """window (C + L - 1, p) scores, oldest first -> Decoded (C,) of its C ends."""
    length = len(offsets)
    place = _place_sum(window, groups, n)
    frames = window.shape[0] - length + 1
    acc = jnp.zeros((frames, n), place.dtype)
    for step, o in enumerate(offsets):
        rows = place[length - 1 - step : length - 1 - step + frames]
        acc = acc + _shifted(rows, o)
    index = jnp.arange(n, dtype=jnp.int32)
    valid = jnp.ones((n,), bool)
    return jax.lax.map(
        lambda a: _best_two(a, index, valid, exclude), acc, batch_size=batch_size
    )


def group_sequence_decode(
    scores: jax.Array,
    groups: Groups,
    n: int,
    offsets: Sequence[Sequence[int]],
    *,
    exclude: int = 0,
    chunk: int = 256,
) -> tuple[jax.Array, jax.Array]:
    """Sequence decode in the place domain: scores (T, p) -> index (T,), confidence.

    ``offsets`` holds, per speed ``v``, the map-frame offsets ``o_l`` of the L
    frames of a window (:func:`rhythmic_jax.decoding.sequence.frame_offsets`);
    :func:`rhythmic_jax.decoding.sequence.sequence_decode` passes them for a map's
    groups. Per speed the accumulated ``A_t`` (module docstring) is decoded by its
    argmax; per frame the speed with the highest score wins (first on ties).
    """
    n = check_group_scores(scores, groups, n)
    scores = jnp.asarray(scores)
    if scores.ndim != 2:
        raise InputError(f"scores must have shape (T, p), got {scores.shape}")
    offsets = tuple(tuple(int(o) for o in offs) for offs in offsets)
    if not offsets or len({len(offs) for offs in offsets}) != 1 or not offsets[0]:
        raise InputError(
            "offsets must hold one non-empty window per speed, all of one length"
        )
    length = len(offsets[0])
    exclude = _check_int(exclude, "exclude", 0)
    chunk = _check_int(chunk, "chunk", 1)
    frames = scores.shape[0]
    if frames == 0:
        return jnp.zeros((0,), jnp.int32), jnp.zeros((0,), scores.dtype)
    chunk = min(chunk, frames)
    pad_end = -frames % chunk
    padded = jnp.concatenate(
        [
            jnp.zeros((length - 1, groups.p), scores.dtype),
            scores,
            jnp.zeros((pad_end, groups.p), scores.dtype),
        ]
    )
    best: Decoded | None = None
    for offs in offsets:
        parts = [
            _sequence_chunk(
                padded[t0 : t0 + chunk + length - 1],
                groups,
                n,
                offs,
                exclude,
                min(chunk, 64),
            )  # fmt: skip
            for t0 in range(0, frames, chunk)
        ]
        out = Decoded(*(jnp.concatenate(x)[:frames] for x in zip(*parts, strict=True)))
        if best is None:
            best = out
        else:
            better = out.score > best.score
            best = Decoded(
                *(jnp.where(better, a, b) for a, b in zip(out, best, strict=True))
            )
    return best.index, best.confidence
