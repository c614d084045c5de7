"""Templates and queries decoded in padded buckets: one program per bucket.

:func:`decode_queries` and :func:`sequence_queries` take the templates and the
(already checked, embedded) queries as arrays: the batch is padded to
:func:`~rhythmic_jax.decoding.buckets.bucket` ``(b)`` rows, uploaded once and
decoded on the device in chunks of :data:`~rhythmic_jax.decoding.buckets.CHUNK`
rows (:func:`~rhythmic_jax.decoding.buckets.over_chunks`), so every program
compiles once per bucket; the hard decode takes the kernel
(:func:`rhythmic_jax.decoding.hard.decode`) or the host batch lane
(:mod:`rhythmic_jax.decoding.host`). The queries of a
:class:`~rhythmic_jax.map.pytree.Map` reach them through
:mod:`rhythmic_jax.decoding.queries`.

Shapes: b queries (T frames of a sequence), d features, p templates, n places.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import jax
import jax.numpy as jnp

from rhythmic_jax.decoding import buckets, hard, host
from rhythmic_jax.decoding.buckets import chunk_count, head, over_chunks, pad_rows
from rhythmic_jax.decoding.dispatch import decode_scores
from rhythmic_jax.decoding.hard import Decoded
from rhythmic_jax.decoding.sequence import METHODS, _check_speeds, sequence_decode
from rhythmic_jax.errors import InputError
from rhythmic_jax.jit_options import jit
from rhythmic_jax.map.groups import Groups
from rhythmic_jax.map.pytree import Templates, decision_values
from rhythmic_jax.validate import check_int

__all__ = ["decode_queries", "padded_sequence", "sequence_queries"]


@functools.partial(jit, static_argnames=("groups", "n", "method", "top", "chunk"))
def _decode_jit(params, queries, count, groups, n, method, top, chunk):
    def body(p, x, _):
        return decode_scores(decision_values(p, x), groups, n, method, top)

    return over_chunks(body, params, queries, count, chunk)


def decode_queries(
    params: Templates,
    queries,
    groups: Groups | Sequence[int],
    n: int,
    method: str = "hard",
    top: int = 3,
) -> Decoded:
    """Scores and decode of queries (b, d) by templates ``params``: Decoded (b,).

    The hard decode by the kernel (:func:`rhythmic_jax.decoding.hard.decode`),
    or the host batch lane where it takes the queries
    (:func:`rhythmic_jax.decoding.host.takes`: a float32 numpy batch on a CPU);
    soft and top-m by ``decode_scores(decision_values(params, queries), groups,
    n, method, top)`` (:func:`rhythmic_jax.decoding.dispatch.decode_scores`) in
    one program per bucket: the batch padded to
    :func:`~rhythmic_jax.decoding.buckets.bucket` ``(b)`` rows, uploaded once
    and decoded on the device in chunks of
    :data:`~rhythmic_jax.decoding.buckets.CHUNK` rows
    (:func:`~rhythmic_jax.decoding.buckets.over_chunks`).
    """
    if not isinstance(groups, Groups):
        groups = Groups("periods", tuple(int(t) for t in groups))
    if method == "hard":
        if host.takes(params, queries):
            return host.decode(params, queries, groups, n)
        return hard.decode(params, queries, groups, n)
    padded, b = pad_rows(queries)
    chunk = buckets.CHUNK
    count = chunk_count(b, chunk)
    out = _decode_jit(params, padded, count, groups, n, method, int(top), chunk)
    return head(out, b)


@functools.partial(
    jit,
    static_argnames=("groups", "n", "length", "speeds", "method", "top", "chunk"),
)
def _sequence_jit(
    params, queries, count, groups, n, length, speeds, method, top, chunk
):
    history = length - 1

    def body(p, window, start):
        # rows before the first frame are left out: zero scores, as the
        # unchunked decode pads them
        frame = start - history + jnp.arange(window.shape[0])
        s = jnp.where((frame >= 0)[:, None], decision_values(p, window), 0.0)
        idx, conf = sequence_decode(s, groups, n, length, speeds, method, top)
        return idx[history:], conf[history:]

    return over_chunks(body, params, queries, count, chunk, history)


def sequence_queries(
    params: Templates,
    queries,
    groups: Groups,
    n: int,
    length: int,
    speeds: Sequence[float] = (1.0,),
    method: str = "soft",
    top: int = 3,
) -> tuple[jax.Array, jax.Array]:
    """Sequence decode of T consecutive query frames (T, d), one program per
    bucket: index (T,), confidence (T,)
    (:func:`rhythmic_jax.decoding.sequence.sequence_decode` of their scores).

    The frames are padded at the end (a frame's answer depends on the frames
    before it only) and decoded on the device in chunks of
    :data:`~rhythmic_jax.decoding.buckets.CHUNK` frames, each with the
    ``length - 1`` frames before it.
    """
    padded, b = pad_rows(queries)
    out = padded_sequence(params, padded, b, groups, n, length, speeds, method, top)
    return head(out, b)


def padded_sequence(params, padded, b, groups, n, length, speeds, method, top):
    """:func:`sequence_queries` of queries already padded to their bucket,
    ``b`` of them real: (bucket,) index and confidence."""
    length = check_int(length, "length", 1)
    speeds = _check_speeds(speeds)
    if method not in METHODS:
        raise InputError(f"method must be one of {METHODS}, got method={method!r}")
    top = check_int(top, "top", 1)
    chunk = buckets.CHUNK
    count = chunk_count(b, chunk)
    return _sequence_jit(
        params, padded, count, groups, n, length, speeds, method, top, chunk
    )
