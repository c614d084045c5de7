"""The rhythmic map as a scikit-learn estimator: a :class:`Map` value held.

:class:`RhythmicMap` is an unsupervised place index: ``fit(X, y=None)`` trains
on reference frames X (n_frames, d), one place per row, or per label of ``y``
(several traversals of one route sharing templates); ``predict(X)`` gives the
place of every query (-1 for no match) and ``score(X, y=None)`` its recall@1
within the ``tolerance`` (places) the command line's ``--tolerance`` gives.
Its parameters are those of :class:`~rhythmic_jax.map.config.MapConfig` (the
default decode named ``method``), the ``embedding`` and ``scale``, given by
name and kept as given (``get_params``, ``set_params``, ``sklearn.clone``,
``GridSearchCV``); they are checked by ``fit``. The fit is
:func:`rhythmic_jax.fitting.fit_map.fit`, its map ``map_``; the queries are the
pure functions of :mod:`rhythmic_jax.decoding.queries` on it, and ``save`` /
``load`` those of :mod:`rhythmic_jax.map.map_file`. The map's fields read as
attributes of a fitted estimator (``m.periods``, ``m.n``, ``m.codebook``, ...);
before a fit they raise ``NotFittedMapError``, scikit-learn's ``NotFittedError``
and this package's :class:`~rhythmic_jax.errors.InputError` at once.

The fit's preparation (settings, labels, scale) is
:func:`rhythmic_jax.fitting.prepare.fit_frames` and the queries in the map's
own terms (its scale, its labels) :mod:`rhythmic_jax.decoding.held`: the
command line's jobs call the same functions on :class:`Map` values. scikit-learn
is imported here, as any scikit-learn estimator imports it; ``import
rhythmic_jax`` does not import this module until ``RhythmicMap`` is asked for.
"""

from __future__ import annotations

import inspect
import json
from dataclasses import fields, replace

import numpy as np
from sklearn.base import BaseEstimator
from sklearn.exceptions import NotFittedError

from rhythmic_jax.decoding import held
from rhythmic_jax.errors import InputError
from rhythmic_jax.fitting.prepare import fit_frames
from rhythmic_jax.map import map_file, pytree
from rhythmic_jax.map.config import MapConfig
from rhythmic_jax.map.embedding import embedding_bytes
from rhythmic_jax.validate import check_int

__all__ = ["MapConfig", "NotFittedMapError", "RhythmicMap"]


class NotFittedMapError(InputError, NotFittedError):
    """A fitted map's value asked of an estimator before ``fit`` or ``load``:
    scikit-learn's ``NotFittedError`` and this package's one-line error."""


def _map_field(name: str, doc: str) -> property:
    """The fitted map's field ``name``; set, the map is replaced (not changed)."""

    def set_(self, value):
        self.map_ = replace(self._fitted(), **{name: value})

    return property(lambda self: getattr(self._fitted(), name), set_, doc=doc)


class RhythmicMap(BaseEstimator):
    """A place-recognition map stored as r groups of periodic linear templates.

    Parameters (by name only; checked by ``fit``): ``r``, ``level``, ``count``,
    ``c``, ``solver``, ``gap``, ``top``, ``threshold``, ``descriptor``,
    ``descriptor_settings`` (None: none), ``dtype``, ``codes``, ``fusion`` and
    ``layout`` as in :class:`~rhythmic_jax.map.config.MapConfig`, whose
    ``decode`` is ``method`` here ("hard", "soft" or "topm": what ``predict``
    does unless told); ``embedding``: an
    :class:`~rhythmic_jax.map.embedding.Embedding` applied to frames and queries
    first; ``scale``: what ``fit`` does with features that are not of order one
    (a mean frame far from the origin, as unscaled 8-bit descriptors have,
    :func:`rhythmic_jax.validate.check_fit_scale`): "refuse" them in one line
    (what the command line and :meth:`from_config` do), "standardize" every
    feature to zero mean and unit variance over the reference frames, the
    queries alike, or "auto" (the default, so scikit-learn's own checks, which
    feed features near 100, fit): standardize the frames "refuse" would refuse
    and take the others as they are, unchanged. The scaling is
    kept as ``scale_mean`` / ``scale_std`` in the map's ``extra`` (saved with
    it) and applied by this estimator's methods, not by the pure functions of
    ``map_``.

    ``tolerance`` (int >= 0, default 0): the places of slack ``score`` allows,
    as ``evaluate --tolerance`` does (a prediction within ``tolerance`` of the
    right place, by label, counts), so ``GridSearchCV`` ranks settings by the
    figure the command line prints; it does not change the fit.

    ``fit(X, y=None)``: y, when given, are the place labels of the frames
    (integers >= 0; frames of one label share a place), and ``predict`` answers
    with them; ``score(X, y=None)`` is recall@1 (within ``tolerance``) against
    y, or with y None the self-recall of reference frames X (row i is place i).
    To cross-validate (``GridSearchCV``), give y and folds that each hold every
    place, e.g. one traversal of the route per fold.

    Fitted: ``map_`` (the :class:`~rhythmic_jax.map.pytree.Map`),
    ``n_features_in_`` (d). ``RhythmicMap.from_config(config)`` builds one
    from a :class:`MapConfig`.
    """

    def __new__(cls, *args, **kwargs):
        if args:
            raise TypeError(
                f"RhythmicMap takes its settings by name, got {len(args)} positional "
                "argument(s): write RhythmicMap(r=2, level=1, ...) or "
                "RhythmicMap.from_config(config)"
            )
        return super().__new__(cls)

    def __init__(
        self,
        *,
        r=2,
        level=1,
        count=7,
        c=None,
        solver="newton",
        gap=1e-7,
        method="hard",
        top=3,
        threshold=None,
        descriptor="features",
        descriptor_settings=None,
        dtype="float32",
        codes=None,
        fusion=0.5,
        layout="periods",
        embedding=None,
        scale="auto",
        tolerance=0,
    ):
        self.r, self.level, self.count, self.c = r, level, count, c
        self.solver, self.gap, self.method, self.top = solver, gap, method, top
        self.threshold, self.descriptor = threshold, descriptor
        self.descriptor_settings, self.dtype = descriptor_settings, dtype
        self.codes, self.fusion, self.layout = codes, fusion, layout
        self.embedding, self.scale, self.tolerance = embedding, scale, tolerance

    # ------------------------------------------------------------ settings
    @classmethod
    def from_config(
        cls, config: MapConfig, *, embedding=None, scale="refuse", tolerance=0
    ):
        """An unfitted estimator whose parameters are ``config``'s fields."""
        return cls(**_params_of(config), embedding=embedding, scale=scale,
                   tolerance=tolerance)  # fmt: skip

    @property
    def config(self) -> MapConfig:
        """The fitted map's :class:`MapConfig`, before a fit the parameters' (checked
        then: a bad one raises :class:`InputError`). Set, the parameters follow it
        (and a fitted map takes it: its decode settings, not its templates)."""
        if self.__sklearn_is_fitted__():
            return self.map_.config
        return self._settings()

    def _settings(self) -> MapConfig:
        """The parameters as a :class:`MapConfig` (checked there)."""
        settings = dict(self.descriptor_settings or {})
        names = {f.name for f in fields(MapConfig)} - {"decode", "descriptor_settings"}
        given = {k: getattr(self, k) for k in names}
        return MapConfig(**given, decode=self.method, descriptor_settings=settings)

    @config.setter
    def config(self, value: MapConfig) -> None:
        self.set_params(**_params_of(value))
        if self.__sklearn_is_fitted__():
            self.map_ = replace(self.map_, config=value)

    def __sklearn_tags__(self):
        """An unsupervised place index: dense finite real features, y optional
        (place labels), deterministic."""
        tags = super().__sklearn_tags__()
        tags.estimator_type = None
        tags.target_tags.required = False
        tags.input_tags.sparse = False
        tags.input_tags.allow_nan = False
        tags.non_deterministic = False
        return tags

    def __sklearn_is_fitted__(self) -> bool:
        return "map_" in vars(self)

    # ------------------------------------------------------------ the fit
    def fit(self, X, y=None, *, verbose=0, progress=None, refine=None, plan=None):
        """Train on reference frames X (n_frames, d): one place per row, or per
        label of ``y`` (n_frames,) (integers >= 0)
        (:func:`rhythmic_jax.fitting.prepare.fit_frames`). Returns self."""
        progress = bool(verbose if progress is None else progress)
        got = fit_frames(X, self._settings(), y, scale=self.scale,
                         embedding=self.embedding, extra=self.extra,
                         reference=self._reference_text(), progress=progress,
                         refine=refine, plan=plan)  # fmt: skip
        self.map = got
        return self

    # ------------------------------------------------------------ the map held
    @property
    def map(self) -> pytree.Map | None:
        """The fitted :class:`~rhythmic_jax.map.pytree.Map` (``map_``), None before
        a fit; set, the estimator holds that map (and its d)."""
        return vars(self).get("map_")

    @map.setter
    def map(self, value: pytree.Map | None) -> None:
        if value is None:
            vars(self).pop("map_", None)
            vars(self).pop("n_features_in_", None)
        else:
            self.map_, self.n_features_in_ = value, int(value.d)

    @property
    def value(self) -> pytree.Map:
        """The fitted :class:`~rhythmic_jax.map.pytree.Map` (refused before a fit)."""
        return self._fitted()

    def _fitted(self) -> pytree.Map:
        try:
            return self.__dict__["map_"]
        except KeyError:
            raise NotFittedMapError(
                "this map is not fitted yet: call fit() or load() first"
            ) from None

    n = _map_field("n", "Number of places.")
    d = _map_field("d", "Features of a frame (the map's input).")
    periods = _map_field("periods", "The co-prime periods kept (a periods layout).")
    groups = _map_field("groups", "The layout's groups of templates.")
    candidates = _map_field("candidates", "The candidate periods trained.")
    candidate_errors = _map_field("candidate_errors", "Training error per candidate.")
    group_errors = _map_field("group_errors", "Training error per kept group.")
    codebook = _map_field("codebook", "Codes per place, or None.")
    params = property(lambda s: s._fitted().params, doc="Templates (w, b) queries use.")
    storage_bytes = property(lambda s: s.storage()["total"], doc="Bytes stored.")
    compression_ratio = property(lambda s: s.storage()["share"], doc="Of float32.")

    @property
    def embedding_bytes(self) -> int:
        """Bytes of the embedding's parameters (0 without one)."""
        return 0 if self.embedding is None else embedding_bytes(self.embedding)

    @property
    def extra(self) -> dict:
        """Arrays kept with the map (a projection, reference labels, the scale);
        before a fit, those the fit will keep."""
        if self.__sklearn_is_fitted__():
            return self.map_.extra
        return vars(self).setdefault("_extra", {})

    @property
    def reference(self) -> dict:
        """Where the reference frames came from (a fresh dict each read)."""
        return json.loads(self._reference_text())

    @reference.setter
    def reference(self, value: dict) -> None:
        text = json.dumps(value, sort_keys=True)
        self._reference = text
        if self.__sklearn_is_fitted__():
            self.map_ = replace(self.map_, reference=text)

    def _reference_text(self) -> str:
        if self.__sklearn_is_fitted__():
            return self.map_.reference
        return vars(self).get("_reference", "{}")

    # ------------------------------------------------------------ queries
    def scores(self, X):
        """Decision values of queries X (b, d) -> (b, p)."""
        return held.scores(self._fitted(), X)

    def place_scores(self, X):
        """Score of every place (b, n) for queries X (b, d); fused with codes."""
        return held.place_scores(self._fitted(), X)

    def decode(self, X, method: str | None = None, top: int | None = None):
        """Decode queries X (b, d): :class:`~rhythmic_jax.decoding.hard.Decoded`
        (index -1 for no match, score, runner-up, confidence); ``method`` "hard",
        "soft" or "topm" and ``top`` (the phases per period top-m keeps) default
        to the map's. The index is the map's place row 0 .. n-1 (``predict``
        names it by the labels ``fit`` had)."""
        return held.decode(self._fitted(), X, method, top)

    def predict(self, X, method=None, *, top=None, sequence=None, speeds=(1.0,),
                threshold=None):  # fmt: skip
        """Place of every query X (b, d): (b,) int64, -1 for no match
        (:func:`rhythmic_jax.decoding.held.predict`: ``method``, ``top``,
        ``sequence`` length, ``speeds``, ``threshold``), by the labels ``fit``
        had."""
        try:  # a query's latency: no call where the map is held
            m = self.map_
        except AttributeError:
            m = self._fitted()  # raises, in the estimator's words
        return held.predict(m, X, method, top=top, sequence=sequence,
                            speeds=speeds, threshold=threshold)  # fmt: skip

    def score(self, X, y=None) -> float:
        """Recall@1 of queries X (b, d) against their places ``y`` (b,) (-1: a
        place not in the map, right when rejected); ``y`` None: X are the
        reference frames, one per place in order (self-recall, the paper's
        Table 2 protocol). A prediction is right within ``tolerance`` places:
        ``|predict(X)[i] - y[i]| <= tolerance`` (``evaluate --tolerance``'s
        accuracy within the tolerance, of the map's default decode)."""
        msg = f"tolerance must be an integer >= 0, got {self.tolerance!r}"
        tol = check_int(self.tolerance, "tolerance", 0, msg=msg)
        pred = self.predict(X)
        truth = np.arange(len(pred)) if y is None else np.asarray(y)
        if truth.dtype.kind == "f" and np.array_equal(truth, np.round(truth)):
            truth = truth.astype(np.int64)  # whole numbers, as fit takes them
        if truth.shape != pred.shape or not np.issubdtype(truth.dtype, np.integer):
            raise InputError(
                f"y: expected {len(pred)} integer places (one per query), got "
                f"shape {truth.shape} of dtype {truth.dtype}"
            )
        near = (pred >= 0) & (np.abs(pred - truth) <= tol)
        right = np.where(truth >= 0, near, pred == -1)
        return float(np.mean(right))

    def locate(self, q) -> int:
        """Place of one descriptor q (d,), -1 for no match."""
        return held.locate(self._fitted(), q)

    def storage(self) -> dict:
        """Bytes of templates, codes and embedding (:func:`pytree.storage`)."""
        return pytree.storage(self._fitted())

    def info(self) -> dict:
        """What ``rhythmic-jax info --json`` prints."""
        return map_file.describe(self._fitted())

    # ------------------------------------------------------------ files
    def with_dtype(self, dtype: str) -> RhythmicMap:
        """A copy storing its templates as ``dtype`` (from the values stored now)."""
        return type(self).from_map(pytree.with_dtype(self._fitted(), dtype))

    def save(self, path) -> None:
        """Save to the folder ``path`` (atomic; :mod:`rhythmic_jax.map.map_file`)."""
        map_file.save(path, self._fitted())

    @classmethod
    def load(cls, path, *, descriptor=None, descriptor_settings=None, d=None):
        """Load a map; refuse it when it was built for another descriptor or d."""
        got = map_file.load(path, MapConfig, descriptor=descriptor,
                            descriptor_settings=descriptor_settings, d=d)  # fmt: skip
        return cls.from_map(got)

    @classmethod
    def from_map(cls, m: pytree.Map) -> RhythmicMap:
        """A fitted estimator holding the map ``m``, with the parameters it was
        built with."""
        scale = "standardize" if "scale_mean" in m.extra else "refuse"
        self = cls.from_config(m.config, embedding=m.embedding, scale=scale)
        self.map = m
        return self


# what inspect.signature(RhythmicMap) shows (else __new__'s *args, **kwargs)
_INIT = inspect.signature(RhythmicMap.__init__)
RhythmicMap.__signature__ = _INIT.replace(
    parameters=list(_INIT.parameters.values())[1:]
)


def _params_of(config: MapConfig) -> dict:
    """The estimator's parameters of a :class:`MapConfig`."""
    got = {f.name: getattr(config, f.name) for f in fields(MapConfig)}
    got["method"] = got.pop("decode")
    got["descriptor_settings"] = dict(got["descriptor_settings"]) or None
    return got
