"""Queries of a map: pure functions of a :class:`~rhythmic_jax.map.pytree.Map`.

``scores(map, q)``, ``place_scores(map, q)``, ``decode(map, q, method)``,
``decode_sequence(map, q, length)``, ``predict(map, q)`` and ``locate(map, q)``
take the map as a value. Queries (b, d) are checked and embedded (when the map
has an embedding) first; inside a trace (``jax.jit(decode)(map, q)``,
``jax.vmap`` over stacked maps) they are taken as they are. Then:

- with codes, the place scores are fused with the code similarities
  (:mod:`rhythmic_jax.decoding.fusion`; ``hard`` then scores every place, as
  ``soft``; inside a trace the queries are encoded in JAX, so such a map
  decodes under ``jax.jit`` too), the queries padded to their bucket first, so
  the scores, codes and fused decode compile once per bucket;
- the hard decode of any layout: the one kernel
  (:func:`rhythmic_jax.decoding.hard.decode`), or a host lane
  (:mod:`rhythmic_jax.decoding.host`) where the queries lie in host memory: a
  float32 numpy batch on a CPU by numpy's product, and up to
  :data:`~rhythmic_jax.decoding.host.SMALL_BATCH` float32 queries of a periods
  map by its single-query lane in ``predict`` and ``locate`` (:func:`way`
  chooses the lane for both);
- soft and top-m decodes, jitted in padded buckets of rows
  (:mod:`rhythmic_jax.decoding.buckets`: one program per bucket);
- a batch above :data:`~rhythmic_jax.decoding.buckets.CHUNK` rows, uploaded
  once and decoded on the device chunk by chunk within that program
  (:func:`~rhythmic_jax.decoding.buckets.over_chunks`: no host round trip per
  chunk, one chunk's scores at a time; a sequence's chunks each see the
  ``length - 1`` frames before them);

and a sequence of queries in the phase domain, or fused with codes
(:mod:`rhythmic_jax.decoding.sequence`). Results stay where they were computed
(a device array of a jitted decode) until ``predict`` hands back its (b,) places.

The templates-and-queries decodes under all of these, in padded buckets, are
:mod:`rhythmic_jax.decoding.batch`'s (importable from here too).

Padding rows decode to something and are dropped; every decode here is per
query (rows do not interact), and the sequence decode looks only backwards in
time, so rows appended after the last frame change no real frame's answer.

Shapes: b queries (T frames of a sequence), d features, k the templates'
dimension, p templates, n places.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.core import Tracer

from rhythmic_jax.decoding import host
from rhythmic_jax.decoding.batch import decode_queries as decode_queries
from rhythmic_jax.decoding.batch import padded_sequence
from rhythmic_jax.decoding.batch import sequence_queries as sequence_queries
from rhythmic_jax.decoding.buckets import head, pad_rows
from rhythmic_jax.decoding.fusion import (
    fused_decode,
    fused_place_scores,
    fused_sequence_decode,
)
from rhythmic_jax.decoding.hard import Decoded
from rhythmic_jax.errors import InputError
from rhythmic_jax.jit_options import jit
from rhythmic_jax.map.checks import check_decode
from rhythmic_jax.map.config import DECODERS
from rhythmic_jax.map.embedding import apply as apply_embedding
from rhythmic_jax.map.embedding import embed
from rhythmic_jax.map.pytree import Map, decision_values
from rhythmic_jax.validate import (
    check_features,
    check_number,
    check_sequence,
)

__all__ = [
    "decode",
    "decode_queries",
    "decode_sequence",
    "locate",
    "one_query",
    "place_scores",
    "predict",
    "refuse_trace",
    "scores",
    "sequence_queries",
    "traced_queries",
    "way",
]

_scores_jit = jit(decision_values)


def queries(m: Map, q) -> np.ndarray | jax.Array:
    """Checked (b, d) queries of ``m``, embedded to (b, k) when it has an
    embedding; in host memory (the bucketed decodes pad them there). Inside a
    trace the shape, rank and dtype are checked at trace time in the eager
    words (:func:`traced_queries`); their values are read by the program (a
    row holding a NaN or inf decodes to no match, -1)."""
    if isinstance(q, Tracer):
        q = traced_queries(q, m.d)
        return q if m.embedding is None else embed(m.embedding, q)
    q = check_features(q, "queries", d=m.d)
    return q if m.embedding is None else apply_embedding(m.embedding, q)


def traced_queries(q: Tracer, d: int) -> jax.Array:
    """Traced queries (b, d) as float32, their shape, rank and dtype (static
    under a trace) checked by :func:`rhythmic_jax.validate.check_features`
    itself, on a stand-in of the same dtype: zeros of the traced shape, a
    broadcast view that holds one number, cut to one row where the shape is
    right (so the eager checks' finiteness test reads one row, not b)."""
    shape = tuple(q.shape)
    if len(shape) == 2 and shape[0] > 0:
        shape = (1, shape[1])
    try:
        stand_in = np.broadcast_to(np.zeros((), q.dtype), shape)
    except TypeError:  # a dtype numpy has no zeros of (a key type)
        raise InputError(f"queries: expected numbers, got dtype {q.dtype}") from None
    check_features(stand_in, "queries", d=d)
    return q.astype(jnp.float32)


def refuse_trace(m: Map, q, name: str = "predict") -> None:
    """Refuse, in one line, a host-output face called inside a trace
    (``jax.jit``, ``jax.vmap``): its places are numpy arrays, which a trace
    cannot give; :func:`decode` is the function to trace."""
    if isinstance(q, Tracer) or isinstance(m.w, Tracer):
        raise InputError(
            f"rhythmic_jax.{name} returns places in host memory and cannot be "
            "traced (jax.jit, jax.vmap); trace rhythmic_jax.decode(map, queries)"
            ".index instead"
        )


def scores(m: Map, q) -> jax.Array:
    """Decision values of queries (b, d) -> (b, p)."""
    return _scores_jit(m.params, queries(m, q))


def place_scores(m: Map, q) -> jax.Array:
    """Score of every place for queries (b, d) -> (b, n): the map's summed phase
    scores, or with codes the fused z-scores."""
    x = queries(m, q)
    book = m.codebook
    sims = None if book is None else book.similarity(x)
    return fused_place_scores(
        _scores_jit(m.params, x), sims, m.periods, m.n, m.config.fusion
    )


def decode(m: Map, q, method: str | None = None, top: int | None = None) -> Decoded:
    """Decode queries (b, d): index (b,) (-1 no match), score, runner-up,
    confidence; ``method`` "hard", "soft" or "topm" (default: the map's), ``top``
    the phases top-m keeps (default: the map's).

    ``confidence = score - runner_up`` (:func:`rhythmic_jax.decoding.hard.confidence`):
    how far the answer beats its best rival in the decode's score units
    (summed decision values; fused z-scores for a map with codes), finite,
    0 for no match. The function to trace: under ``jax.jit`` or ``jax.vmap``
    the queries' shape, rank and dtype are refused at trace time as eagerly,
    and a query holding a NaN or inf decodes to no match (-1); eagerly such a
    query is refused in one line."""
    method, top = method or m.config.decode, top or m.config.top
    x = queries(m, q)
    return by_method(method, lambda h: _decoded(m, x, h, top))


def by_method(method, answer):
    """``answer(method)`` for a method's name. Inside a trace of the map, its
    stored method (:data:`rhythmic_jax.map.pytree.DECODE_SETTINGS`) is an
    index into :data:`~rhythmic_jax.map.config.DECODERS` traced with the map:
    every method is a branch of the one program and ``jax.lax.switch`` picks
    one, so a map with another stored method compiles nothing new."""
    if isinstance(method, Tracer):
        return jax.lax.switch(method, [lambda h=h: answer(h) for h in DECODERS])
    return answer(method)


def _decoded(m: Map, x, method: str, top: int) -> Decoded:
    """Decoded (b,) of checked, embedded queries x (b, k): with codes fused
    (padded first: every program once per bucket), else by
    :func:`decode_queries`; refused first where its largest allocation would
    not fit (:func:`rhythmic_jax.map.checks.check_decode`)."""
    check_decode(m, method, x.shape[0], top)
    if m.codebook is None:
        return decode_queries(m.params, x, m.groups, m.n, method, top)
    x, b = pad_rows(x)
    return head(fused_decode(
        _scores_jit(m.params, x), m.codebook.similarity(x), m.periods, m.n,
        m.config.fusion, "soft" if method == "hard" else method, top,
    ), b)  # fmt: skip


def decode_sequence(
    m: Map,
    q,
    length: int,
    speeds: Sequence[float] = (1.0,),
    method: str | None = None,
    top: int | None = None,
) -> tuple[jax.Array, jax.Array]:
    """``(index, confidence)`` (T,) of consecutive query frames q (T, d), each
    decoded with the ``length - 1`` before it at ``speeds`` by ``method``
    (:mod:`rhythmic_jax.decoding.sequence`). The confidence is the winning
    speed's ``score - runner_up`` over the summed evidence of the L frames
    (:func:`rhythmic_jax.decoding.hard.confidence`: finite, 0 for no match)."""
    method, top = method or m.config.decode, top or m.config.top
    x = queries(m, q)
    return by_method(method, lambda h: _sequence(m, x, length, speeds, h, top))


def _sequence(m: Map, x, length, speeds, method: str, top: int):
    """:func:`decode_sequence` of checked, embedded queries x (T, k), padded at
    the end first (a frame's answer depends on the frames before it only), so
    every program compiles once per bucket."""
    check_decode(m, method, x.shape[0], top, sequence=True)  # before it allocates
    x, b = pad_rows(x)
    if m.codebook is not None:
        out = fused_sequence_decode(
            _scores_jit(m.params, x), m.codebook.similarity(x), m.periods, m.n,
            length, speeds, m.config.fusion, method, top,
        )  # fmt: skip
    else:
        out = padded_sequence(
            m.params, x, b, m.groups, m.n, length, speeds, method, top
        )
    return head(out, b)


def predict(
    m: Map,
    q,
    method: str | None = None,
    *,
    top: int | None = None,
    sequence: int | None = None,
    speeds: tuple[float, ...] = (1.0,),
    threshold: float | None = None,
) -> np.ndarray:
    """Place index of every query (b,) int64 in host memory, -1 for no match:
    the queries answered by the lane :func:`way` chooses, then the threshold.

    Args:
      q: (b, d) queries (consecutive frames of a traversal when ``sequence``).
      method: "hard" (paper), "soft" or "topm"; default from the map's config.
      sequence: decode each frame with the L previous ones in the phase
        domain (:mod:`rhythmic_jax.decoding.sequence`; mixed-radix and
        hierarchical maps sum place scores instead); None (or 1) for single
        frames; at most b.
      speeds: map frames per query frame tried by the sequence decode.
      threshold: reject queries whose confidence is below it (finite; default
        the map's): the decode's ``score - runner_up``
        (:func:`rhythmic_jax.decoding.hard.confidence`), in its score units.

    Not traceable (its places are numpy arrays): inside ``jax.jit`` or
    ``jax.vmap`` it refuses in one line; trace :func:`decode` instead.
    """
    refuse_trace(m, q)
    method, top = method or m.config.decode, top or m.config.top
    thr = m.config.threshold
    if threshold is not None:
        thr = check_number(threshold, "{opt:threshold}")
    if sequence is not None:
        sequence = check_sequence(sequence)
    idx, conf = way(m, method, thr, sequence)(m, q, method, top, sequence, speeds)
    idx = np.asarray(idx, np.int64)  # no copy of the single-query lane's places
    if thr is not None:
        idx = np.where(np.asarray(conf, np.float64) >= thr, idx, -1)
    return idx


Lane = Callable[..., tuple[Any, Any]]
"""A way from queries to places: ``lane(m, q, method, top, sequence, speeds)`` ->
(index, confidence) (b,), where q are the caller's (b, d) queries."""


def way(
    m: Map, method: str, threshold: float | None = None, sequence: int | None = None
) -> Lane:
    """The one chooser of ``predict`` and ``locate``: the lane that answers
    queries of ``m``. Frames in a sequence (L > 1): :func:`_in_sequence`; the
    paper's hard decode without a threshold of a periods map without codes or
    embedding, outside a trace: :func:`_small` (its single-query lane,
    :func:`rhythmic_jax.decoding.host.lane`); else :func:`_one_by_one` (the
    batch decodes)."""
    if sequence is not None and sequence > 1:
        return _in_sequence
    if method == "hard" and threshold is None and host.lane(m) is not None:
        return _small
    return _one_by_one


def _small(m: Map, q, method, top, sequence, speeds):
    """Up to :data:`~rhythmic_jax.decoding.host.SMALL_BATCH` float32 queries
    by the map's single-query lane (one matrix-vector product each, the
    scores' finiteness checking the values; no confidence: no threshold
    reads it); anything else by :func:`_one_by_one`."""
    few = host.lane(m).places(q)
    if few is None:
        return _one_by_one(m, q, method, top, sequence, speeds)
    return few, None


def _one_by_one(m: Map, q, method, top, sequence, speeds):
    """Single frames (``sequence`` None or 1): the decode of every query."""
    if sequence is not None:
        check_sequence(sequence, len(q))
    out = _decoded(m, queries(m, q), method, top)
    return out.index, out.confidence


def _in_sequence(m: Map, q, method, top, sequence, speeds):
    """Frames in a sequence of L = ``sequence``, embedded once here."""
    x = queries(m, q)
    check_sequence(sequence, len(x))
    return _sequence(m, x, sequence, speeds, method, top)


def locate(m: Map, q) -> int:
    """Place of one descriptor ``q`` (d,), -1 for no match: ``predict(m,
    q[None])[0]`` with nothing around it. Where :func:`way` chooses the
    single-query lane, a float32 (d,) numpy array goes straight to one BLAS
    product (no dispatch, no copies; a NaN or inf is caught on its scores);
    anything else takes ``predict``'s checks."""
    cfg = m.config
    if (
        type(q) is np.ndarray
        and q.dtype == np.float32
        and q.shape == (m.d,)
        and way(m, cfg.decode, cfg.threshold) is _small
    ):
        found = host.lane(m).place(q)
        if found is not None:
            return found
    return int(predict(m, one_query(q, m.d))[0])


def one_query(q, d: int):
    """``q`` as a (1, d) batch for ``predict``: a (d,) descriptor gains a row
    axis, a ragged one is left to ``predict``'s checks; other shapes are refused."""
    try:
        x = np.asarray(q)
    except ValueError:  # ragged: predict's checks say so
        return [q]
    if x.ndim != 1:
        raise InputError(
            f"query: expected one descriptor of shape ({d},), got shape {x.shape}"
        )
    return x[None]
