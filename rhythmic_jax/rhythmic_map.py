"""The rhythmic map as a scikit-learn-style estimator: a :class:`Map` value held.

``fit`` is :func:`rhythmic_jax.fitting.fit_map.fit`; ``predict``, ``decode``,
``scores``, ``locate``, ``save`` and ``load`` are pure functions of the map it
holds (:mod:`rhythmic_jax.decoding.queries`, :mod:`rhythmic_jax.map.map_file`);
the map's fields read and set as attributes (``m.periods``, ``m.n``,
``m.codebook``, ...).
"""

from __future__ import annotations

import json
from dataclasses import replace

from rhythmic_jax.decoding import queries
from rhythmic_jax.errors import InputError
from rhythmic_jax.fitting.fit_map import fit as fit_map
from rhythmic_jax.map import map_file, pytree
from rhythmic_jax.map.config import MapConfig
from rhythmic_jax.map.embedding import embedding_bytes

__all__ = ["MapConfig", "RhythmicMap"]
UNFITTED = dict(n=None, d=None, periods=(), groups=None, c=None, candidates=(),
                candidate_errors=(), group_errors=(), codebook=None, extra={},
                embedding=None, config=None, reference="{}")  # fmt: skip


def _field(name: str, get=lambda v: v, put=lambda v: v) -> property:
    """The map's field ``name``; before a fit, as set on the estimator."""

    def set_(self, value):
        self._pre[name] = put(value)
        if self.map is not None:  # a new value: the map is not changed in place
            self.map = replace(self.map, **{name: put(value)})

    return property(lambda s: get(_fields(s)[name]), set_, doc=f"The map's {name}.")


def _fields(model) -> dict:
    return model._pre if model.map is None else vars(model.map)


def _pure(fn, doc: str):
    """A method calling ``fn(the fitted map, *args)``."""
    method = lambda self, *args: fn(self.value, *args)  # noqa: E731
    method.__doc__ = doc
    return method


class RhythmicMap:
    """A place-recognition map stored as r groups of periodic linear templates."""

    def __init__(self, config: MapConfig | None = None, *, embedding=None, **kw):
        self.map: pytree.Map | None = None  # the fitted value
        cfg = replace(config or MapConfig(), **kw)
        self._pre = dict(UNFITTED, extra={}, embedding=embedding, config=cfg)

    reference = _field("reference", json.loads, lambda v: json.dumps(v, sort_keys=True))
    params = property(lambda s: s.value.params, doc="Templates (w, b) queries use.")
    storage_bytes = property(lambda s: s.storage()["total"], doc="Bytes stored.")
    compression_ratio = property(lambda s: s.storage()["share"], doc="Of float32.")
    embedding_bytes = property(
        lambda s: 0 if s.embedding is None else embedding_bytes(s.embedding),
        doc="Bytes of the embedding's parameters (0 without one).",
    )

    @property
    def value(self) -> pytree.Map:
        """The fitted :class:`~rhythmic_jax.map.pytree.Map` (refused before a fit)."""
        if self.map is None:
            raise InputError("this map is not fitted yet: call fit() or load() first")
        return self.map

    def fit(self, x, labels=None, *, verbose=0, progress=None, refine=None, plan=None):
        """Train on frames x (n_frames, d): :func:`rhythmic_jax.fitting.fit_map.fit`."""
        progress = bool(verbose if progress is None else progress)
        got = fit_map(x, self.config, labels=labels, embedding=self.embedding,
                      progress=progress, refine=refine, plan=plan)  # fmt: skip
        return self._take(got)

    def _take(self, kept, d: int | None = None) -> RhythmicMap:
        """Hold a fitted map, or a fit's ``kept`` templates of d-dim frames (a fit
        from files), with this estimator's extra arrays and reference."""
        extra, ref = self.extra, _fields(self)["reference"]
        if d is not None:
            kept = pytree.Map.build(kept, d, self.config, embedding=self.embedding)
        self.map = replace(kept, extra=extra, reference=ref)
        return self

    def with_dtype(self, dtype: str) -> RhythmicMap:
        """A copy storing its templates as ``dtype`` (from the values stored now)."""
        other = RhythmicMap()
        other.map = pytree.with_dtype(self.value, dtype)
        return other

    scores = _pure(queries.scores, "Decision values of queries (b, d) -> (b, p).")
    place_scores = _pure(queries.place_scores, "Place scores (b, n) of queries.")
    decode = _pure(queries.decode, "Decode queries (b, d) (method, m): Decoded.")
    storage = _pure(pytree.storage, "Bytes of templates, codes and embedding.")
    info = _pure(map_file.describe, "What ``rhythmic-jax info --json`` prints.")

    def locate(self, q) -> int:
        """Place of one descriptor q (d,), -1 for no match."""
        return queries.locate(self.map or self.value, q)  # the map, or a refusal

    def save(self, path) -> None:
        """Save to the folder ``path`` (atomic; :mod:`rhythmic_jax.map.map_file`)."""
        map_file.save(path, self.value)

    def predict(self, q, method=None, *, m=None, sequence=None, speeds=(1.0,),
                threshold=None):  # fmt: skip
        """Place of every query (b,), -1 for no match (:func:`queries.predict`)."""
        how = dict(top=m, sequence=sequence, speeds=speeds, threshold=threshold)
        return queries.predict(self.map or self.value, q, method, **how)

    @classmethod
    def load(cls, path, *, descriptor=None, descriptor_settings=None, d=None):
        """Load a map; refuse it when it was built for another descriptor or d."""
        self, settings = cls(), descriptor_settings
        self.map = map_file.load(path, MapConfig, descriptor=descriptor,
                                 descriptor_settings=settings, d=d)  # fmt: skip
        return self


for _name in UNFITTED.keys() - {"reference"}:
    setattr(RhythmicMap, _name, _field(_name))
