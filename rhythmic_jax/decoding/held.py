"""A fitted map's queries in its own terms: its scale and its place labels.

A map fitted by :func:`rhythmic_jax.fitting.prepare.fit_frames` may keep, in
its ``extra`` arrays, the per-feature scaling of its frames (``scale_mean`` /
``scale_std``: queries are standardized alike before they are scored) and the
labels its places were given (``place_labels``: a place row is answered as its
label, -1 kept). The functions here are the pure query functions of
:mod:`rhythmic_jax.decoding.queries` with both applied, on a
:class:`~rhythmic_jax.map.pytree.Map` value; the command line's jobs and
:class:`rhythmic_jax.RhythmicMap` call them alike. A map without those arrays
(every map the command line fits) is queried exactly as those functions query
it.

:class:`HeldMap` is a fitted map as the reports and the command line's
printers read one (``model.n``, ``model.predict(x)``, ``model.storage_bytes``,
``model.reference`` as a dict): the :class:`Map` value and these functions,
nothing else.

Shapes: b queries, d features, p templates, n places.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

import jax
import numpy as np

from rhythmic_jax.decoding import queries
from rhythmic_jax.decoding.hard import Decoded
from rhythmic_jax.estimator_inputs import query_rows
from rhythmic_jax.map import map_file, pytree
from rhythmic_jax.map.embedding import embedding_bytes
from rhythmic_jax.map.pytree import Map

__all__ = [
    "HeldMap",
    "decode",
    "labelled",
    "locate",
    "place_scores",
    "predict",
    "rows",
    "scores",
]


def rows(m: Map, X, name: str = "queries"):
    """Queries X (b, d) of ``m`` as its decode takes them: refused in
    scikit-learn's words where their shape is wrong, standardized where the fit
    standardized the frames (:func:`rhythmic_jax.estimator_inputs.query_rows`)."""
    return query_rows(X, m.d, m.extra, name)


def labelled(m: Map, index):
    """Place rows (b,) of ``m`` as the labels its places were fitted with
    (``extra["place_labels"]``; -1 kept); without labels, ``index`` itself."""
    labels = m.extra.get("place_labels")
    if labels is None:
        return index
    labels = np.asarray(labels)
    return np.where(index >= 0, labels[np.maximum(index, 0)], -1)


def scores(m: Map, X) -> jax.Array:
    """Decision values (b, p) of queries X (b, d)."""
    return queries.scores(m, rows(m, X))


def place_scores(m: Map, X) -> jax.Array:
    """Score of every place (b, n) for queries X (b, d); fused with codes."""
    return queries.place_scores(m, rows(m, X))


def decode(m: Map, X, method: str | None = None, top: int | None = None) -> Decoded:
    """:func:`rhythmic_jax.decoding.queries.decode` of queries X (b, d): the
    index is the map's place row 0 .. n-1. Traced queries are taken as they are
    (the decode checks them at trace time)."""
    if isinstance(X, jax.core.Tracer):
        return queries.decode(m, X, method, top)
    return queries.decode(m, rows(m, X), method, top)


def predict(m: Map, X, method: str | None = None, *, top: int | None = None,
            sequence: int | None = None, speeds=(1.0,),
            threshold: float | None = None):  # fmt: skip
    """Place of every query X (b, d): (b,) int64, -1 for no match
    (:func:`rhythmic_jax.decoding.queries.predict`), named by the place labels
    the map was fitted with. Refused, in one line, inside a trace."""
    queries.refuse_trace(m, X)
    got = queries.predict(m, rows(m, X), method, top=top, sequence=sequence,
                          speeds=speeds, threshold=threshold)  # fmt: skip
    return got if "place_labels" not in m.extra else labelled(m, got)


def locate(m: Map, q) -> int:
    """Place of one descriptor q (d,), -1 for no match, by its label."""
    if "scale_mean" in m.extra:
        q = rows(m, queries.one_query(q, m.d), "query")[0]
    got = queries.locate(m, q)
    return got if "place_labels" not in m.extra else int(labelled(m, got))


@dataclass(frozen=True, eq=False)
class HeldMap:
    """A fitted :class:`~rhythmic_jax.map.pytree.Map` (``value``) read as the
    reports and printers read a model: the map's fields as attributes
    (``n``, ``d``, ``periods``, ``groups``, ``codebook``, ``config``,
    ``extra``, ``embedding``, ...), ``reference`` as a dict, its storage, and
    the queries of this module."""

    value: Map

    def __getattr__(self, name: str) -> Any:
        if name == "value":  # not set yet (a copy being made)
            raise AttributeError(name)
        return getattr(self.value, name)

    @property
    def reference(self) -> dict:
        """Where the reference frames came from (a fresh dict each read)."""
        return json.loads(self.value.reference)

    def storage(self) -> dict:
        """Bytes of templates, codes and embedding (:func:`pytree.storage`)."""
        return pytree.storage(self.value)

    @property
    def storage_bytes(self) -> int:
        """Bytes stored."""
        return self.storage()["total"]

    @property
    def compression_ratio(self) -> float:
        """Bytes stored, as a share of the float32 database's."""
        return self.storage()["share"]

    @property
    def embedding_bytes(self) -> int:
        """Bytes of the embedding's parameters (0 without one)."""
        emb = self.value.embedding
        return 0 if emb is None else embedding_bytes(emb)

    def info(self) -> dict:
        """What ``rhythmic-jax info --json`` prints."""
        return map_file.describe(self.value)

    def scores(self, X):
        """:func:`scores` of the map."""
        return scores(self.value, X)

    def place_scores(self, X):
        """:func:`place_scores` of the map."""
        return place_scores(self.value, X)

    def decode(self, X, method=None, top=None) -> Decoded:
        """:func:`decode` of the map."""
        return decode(self.value, X, method, top)

    def predict(self, X, method=None, *, top=None, sequence=None, speeds=(1.0,),
                threshold=None):  # fmt: skip
        """:func:`predict` of the map."""
        return predict(self.value, X, method, top=top, sequence=sequence,
                       speeds=speeds, threshold=threshold)  # fmt: skip

    def locate(self, q) -> int:
        """:func:`locate` of the map."""
        return locate(self.value, q)
