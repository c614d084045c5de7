"""Query batches in power-of-two buckets: one compiled program per bucket.

XLA compiles a program per input shape. A map that answers batches of 3, then
5, then 7 queries would compile the product and the decode three times (on a
GPU seconds each). Here a batch of b queries is padded with zero rows to
:func:`~rhythmic_jax.decoding.buckets.bucket` ``(b)`` rows, the next power of
two from :data:`~rhythmic_jax.decoding.buckets.MIN_BUCKET` on, so batches of 3,
5 and 7 share one program and a batch of 10^5 queries shares one with every
batch of 65,537-131,072. The padding is added where the queries lie (numpy on
the host: no program at all) and the (b,) results are cut on the host, so no
shape-specific program runs around the decode; the queries and their (b, p)
scores stay on the default device.

Padding rows decode to something and are dropped; every decode here is per
query (rows do not interact), and the sequence decode looks only backwards in
time, so rows appended after the last frame change no real frame's answer.

Shapes: b queries (T frames of a sequence), d features, p templates, n places.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import jax

from rhythmic_jax.decoding.buckets import head, pad_rows
from rhythmic_jax.decoding.dispatch import decode_scores
from rhythmic_jax.decoding.hard import Decoded
from rhythmic_jax.jit_options import jit
from rhythmic_jax.map.groups import Groups
from rhythmic_jax.solvers.objective import Templates
from rhythmic_jax.solvers.objective import scores as decision_values

__all__ = ["decode_queries", "sequence_queries"]


@functools.partial(jit, static_argnames=("groups", "n", "method", "m"))
def _decode_jit(params, queries, groups, n, method, m):
    return decode_scores(decision_values(params, queries), groups, n, method, m)


def decode_queries(
    params: Templates,
    queries,
    groups: Groups,
    n: int,
    method: str = "hard",
    m: int = 3,
) -> Decoded:
    """Scores and decode of queries (b, d) in one program per bucket: Decoded (b,).

    ``decode_scores(scores(params, queries), groups, n, method, m)``
    (:func:`rhythmic_jax.decoding.dispatch.decode_scores`) with the batch padded
    to :func:`~rhythmic_jax.decoding.buckets.bucket` ``(b)`` rows.
    """
    padded, b = pad_rows(queries)
    return head(_decode_jit(params, padded, groups, n, method, int(m)), b)


_scores_jit = jit(decision_values)


def sequence_queries(
    params: Templates,
    queries,
    groups: Groups,
    n: int,
    length: int,
    speeds: Sequence[float] = (1.0,),
    method: str = "soft",
    m: int = 3,
) -> tuple[jax.Array, jax.Array]:
    """Sequence decode of T consecutive query frames (T, d), every program
    compiled once per bucket: index (T,), confidence (T,)
    (:func:`rhythmic_jax.decoding.sequence.sequence_decode` of their scores).

    The frames are padded at the end; a frame's answer depends on the frames
    before it only.
    """
    from rhythmic_jax.decoding.sequence import sequence_decode  # deferred: startup

    padded, b = pad_rows(queries)
    s = _scores_jit(params, padded)
    return head(sequence_decode(s, groups, n, length, speeds, method, m), b)
