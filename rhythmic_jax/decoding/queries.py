"""Which decode answers a fitted map's queries.

A map (:class:`rhythmic_jax.RhythmicMap`) decodes its checked queries ``x``
(b, k) (embedded when it has an embedding) in one of these lanes:

- with codes, its place scores fused with the code similarities
  (:mod:`rhythmic_jax.decoding.fusion`; ``hard`` then scores every place, as
  ``soft``);
- the paper's hard decode of a periods map: numpy for up to
  :data:`~rhythmic_jax.decoding.small.SMALL_BATCH` queries
  (:mod:`rhythmic_jax.decoding.small`), else a host BLAS product with jitted
  argmaxes and look-ups (:mod:`rhythmic_jax.decoding.hard`);
- any other decode or layout, jitted in padded buckets
  (:mod:`rhythmic_jax.decoding.batch`);

and a sequence of queries in the phase domain, or fused with codes
(:mod:`rhythmic_jax.decoding.sequence`). The functions read the map's params,
groups, periods, n, codebook, fusion weight and numpy decoder.
"""

from __future__ import annotations

import functools

import jax
import numpy as np

from rhythmic_jax.decoding.batch import decode_queries, sequence_queries
from rhythmic_jax.decoding.fusion import (
    fused_decode,
    fused_place_scores,
    fused_sequence_decode,
)
from rhythmic_jax.decoding.hard import Decoded
from rhythmic_jax.decoding.hard import decode as localise
from rhythmic_jax.decoding.small import SMALL_BATCH
from rhythmic_jax.errors import InputError
from rhythmic_jax.jit_options import jit
from rhythmic_jax.map.embedding import apply as apply_embedding
from rhythmic_jax.solvers.objective import Templates, scores

__all__ = [
    "decode_map",
    "few_places",
    "locate_fast",
    "map_scores",
    "one_query",
    "place_scores_map",
    "sequence_map",
]


@jit
def map_scores(params: Templates, q: jax.Array) -> jax.Array:
    """Decision values ``q @ w + b`` (b, p) of queries (b, k), jitted."""
    return scores(params, q)


def decode_map(model, x, method: str, m: int) -> Decoded:
    """Decode the map's checked queries x (b, k) with ``method`` (top-``m``)."""
    if model.codebook is not None:
        return fused_decode(
            map_scores(model.params, x), model.codebook.similarity(x),
            model.periods, model.n, model.config.fusion,
            "soft" if method == "hard" else method, m,
        )  # fmt: skip
    if method == "hard" and model.groups.kind == "periods":
        x = np.asarray(x, np.float32)
        if len(x) <= SMALL_BATCH:  # numpy: no dispatch for a single query
            return model._small_decoder()(x)
        # host BLAS product, jitted argmaxes and look-ups
        return localise(model.params, x, model.periods, model.n)
    return decode_queries(model.params, x, model.groups, model.n, method, m)


def place_scores_map(model, x) -> jax.Array:
    """Score of every place (b, n) for the map's checked queries x (b, k): its
    summed phase scores, or with codes the fused z-scores."""
    book = model.codebook
    sims = None if book is None else book.similarity(x)
    return fused_place_scores(
        map_scores(model.params, x), sims, model.periods, model.n, model.config.fusion
    )


def few_places(model, q, method: str) -> np.ndarray | None:
    """Places (b,) int64 of up to :data:`SMALL_BATCH` raw queries q (b, d) of the
    map by the numpy hard decode (:meth:`SmallDecoder.places`); None where that
    decode does not apply (codes, another decode or layout, more queries)."""
    if model.codebook is not None or method != "hard":
        return None
    model._check_fitted()
    if model.groups.kind != "periods":
        return None
    emb = model.embedding
    embed = None if emb is None else functools.partial(apply_embedding, emb)
    return model._small_decoder().places(q, model.d, embed)


def sequence_map(model, x, sequence: int, speeds, method: str, m: int):
    """``(index, confidence)`` (b,) of the map's checked queries x (b, k), each
    decoded with the ``sequence - 1`` before it at ``speeds``."""
    if model.codebook is not None:
        return fused_sequence_decode(
            map_scores(model.params, x), model.codebook.similarity(x),
            model.periods, model.n, sequence, speeds, model.config.fusion, method, m,
        )  # fmt: skip
    return sequence_queries(
        model.params, x, model.groups, model.n, sequence, speeds, method, m
    )


def locate_fast(model, q) -> int | None:
    """The place of one float32 (d,) numpy descriptor ``q`` by one BLAS product
    (no dispatch, no copies), for the paper's hard decode of a map without
    threshold, codes or embedding whose numpy decoder is built; None where that
    does not apply (or a NaN or inf shows in the scores)."""
    small = model._small
    if (
        small is not None
        and small.params is model.params
        and type(q) is np.ndarray
        and q.dtype == np.float32
        and q.shape == (model.d,)
        and model.embedding is None
        and model.codebook is None
        and model.config.decode == "hard"
        and model.config.threshold is None
    ):
        return small.place(q)
    return None


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
