"""A fitted map as a JAX value: :class:`Map`, a registered pytree.

The arrays a decode reads are its leaves: the templates ``w`` (k, p) and biases
``b`` (p,) in float32 as queries are scored with them, the arrays as stored
(``stored``: ``w``, ``b`` in the map's dtype, ``scale`` for int8), the arrays
kept beside the map (``extra``), the codes (a
:class:`~rhythmic_jax.map.codes.CodeBook` or
:class:`~rhythmic_jax.map.scalar_codes.ScalarCodeBook`, pytrees of their
arrays, registered where they are defined) and the embedding (its arrays), None
where absent.
The fit's record (penalty, training errors) are leaves too, and so are the
decode settings the map stores as its defaults (:data:`DECODE_SETTINGS`: the
method, threshold and fusion weight, as 0-d arrays). Everything else is static
and hashable: the layout (``groups``), periods, n, d, the fit's configuration
and provenance (dtype, descriptor, the top-m count, which sets a shape) and the
candidate periods. So a map can be an argument of ``jax.jit`` (a new layout or
fit configuration compiles anew; new template values, or another stored
threshold, method or fusion weight, do not) and maps of one layout can be
stacked and ``jax.vmap``-ed. The pure functions over it live along the pipeline:
:func:`rhythmic_jax.fitting.fit_map.fit`, :mod:`rhythmic_jax.decoding.queries`
(scores, decode, sequences) and :mod:`rhythmic_jax.map.map_file` (save, load).

Names: k the templates' dimension (the embedding's output, else d), p templates,
n places.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, fields, replace
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.map.codes import CodeBook
from rhythmic_jax.map.config import DECODERS, MapConfig
from rhythmic_jax.map.embedding import Embedding, embedding_bytes
from rhythmic_jax.map.groups import Groups
from rhythmic_jax.map.quantize import requantize
from rhythmic_jax.map.scalar_codes import ScalarCodeBook
from rhythmic_jax.map.storage import map_storage

__all__ = [
    "DECODE_SETTINGS",
    "Map",
    "Templates",
    "decision_values",
    "host_templates",
    "storage",
    "with_dtype",
]


class Templates(NamedTuple):
    """Linear templates: ``w`` (d, p) weights and ``b`` (p,) biases."""

    w: jax.Array
    b: jax.Array


def decision_values(params: Templates, x: jax.Array) -> jax.Array:
    """Decision values ``x @ w + b``: (n, d) -> (n, p)."""
    return jnp.matmul(x, params.w, precision="highest") + params.b[None, :]


def host_templates(params, x) -> Templates:
    """A solve's templates as float32 host arrays ``w`` (d, p), ``b`` (p,);
    refused (InputError) when not finite, which frames x (n, d) with too large
    values give."""
    params = Templates(*(np.asarray(v, np.float32) for v in params))
    if not all(np.isfinite(v).all() for v in params):
        raise InputError(
            "reference features: the solve gave non-finite templates (largest "
            f"|feature| {float(np.abs(x).max()):.3g}); scale the features, "
            "e.g. to unit-length rows"
        )
    return params


DECODE_SETTINGS = ("decode", "threshold", "fusion")
"""The :class:`~rhythmic_jax.map.config.MapConfig` fields a map carries as
leaves: its default decode method (the index in
:data:`~rhythmic_jax.map.config.DECODERS`, int32), threshold (float64, NaN for
none) and fusion weight (float64)."""

_NONE = dict(decode="hard", threshold=None, fusion=0.5)  # the aux data's values


def _leaf(value):
    """A setting's Python value as its 0-d leaf; a value that is a leaf
    already (an array of a stacked or traced map) as it is."""
    if isinstance(value, str):  # the method
        return np.asarray(DECODERS.index(value), np.int32)
    if value is None or isinstance(value, int | float):
        return np.asarray(math.nan if value is None else value, np.float64)
    return value


def _value(name: str, leaf):
    """A concrete 0-d leaf as the setting's Python value; anything else (a
    tracer, a stacked array, a placeholder of a tree operation) as it is."""
    concrete = isinstance(leaf, np.ndarray | np.generic | jax.Array)
    if not concrete or isinstance(leaf, jax.core.Tracer) or np.ndim(leaf) != 0:
        return leaf
    if name == "decode":
        return DECODERS[int(leaf)]
    v = float(leaf)
    return None if name == "threshold" and math.isnan(v) else v


def _flatten_config(cfg: MapConfig):
    leaves = tuple(
        (jax.tree_util.GetAttrKey(name), _leaf(getattr(cfg, name)))
        for name in DECODE_SETTINGS
    )
    rest = {f.name: getattr(cfg, f.name) for f in fields(cfg)} | _NONE
    aux = object.__new__(MapConfig)  # the values are checked already
    aux.__dict__.update(rest)
    return leaves, aux


def _unflatten_config(aux: MapConfig, leaves) -> MapConfig:
    cfg = object.__new__(MapConfig)  # a leaf may be a tracer: nothing to check
    cfg.__dict__.update(vars(aux))
    for name, leaf in zip(DECODE_SETTINGS, leaves, strict=True):
        cfg.__dict__[name] = _value(name, leaf)
    return cfg


# the decode settings are leaves, the fit's configuration and provenance static
jax.tree_util.register_pytree_with_keys(MapConfig, _flatten_config, _unflatten_config)

_STATIC = dict(metadata=dict(static=True))


@jax.tree_util.register_dataclass
@dataclass(frozen=True, eq=False)
class Map:
    """A fitted map: arrays as leaves, layout and record as static fields.

    Leaves: ``w`` (k, p) and ``b`` (p,) float32 device arrays, the values
    queries are scored with; ``stored``: ``w`` (k, p), ``b`` (p,) in
    ``config.dtype`` (and ``scale`` (p,) for int8), what a map file holds;
    ``extra``: named arrays kept with the map (a projection, reference labels);
    ``codebook``: codes per place or None; ``embedding``: applied to frames and
    queries first, or None; and the fit's record, float64: the penalty ``c`` (a
    0-d array), the training error of every candidate period
    (``candidate_errors`` (count,)) and of every kept group (``group_errors``
    (r,)); ``config`` (:class:`~rhythmic_jax.map.config.MapConfig`): its
    decode settings (:data:`DECODE_SETTINGS`) as leaves, the rest static.
    Leaves that are numpy arrays are copied to the device by every jitted call
    that takes the map: ``jax.device_put(map)`` once keeps them there.

    Static: ``groups`` (:class:`~rhythmic_jax.map.groups.Groups`), ``periods`` (the
    co-prime periods; empty for another layout), ``n`` places, ``d`` input
    features, the ``candidates`` periods and ``reference`` (JSON text: where the
    reference frames came from). Maps of one layout and configuration, fitted
    on different frames, share them and stack (``jax.vmap``).
    """

    w: jax.Array
    b: jax.Array
    stored: dict[str, Any]
    extra: dict[str, Any] = field(default_factory=dict)
    codebook: CodeBook | ScalarCodeBook | None = None
    embedding: Embedding | None = None
    c: np.ndarray = field(default_factory=lambda: np.ones((), np.float64))
    candidate_errors: np.ndarray = field(default_factory=lambda: np.zeros(0))
    group_errors: np.ndarray = field(default_factory=lambda: np.zeros(0))
    config: MapConfig = field(default_factory=MapConfig)
    groups: Groups = field(default=Groups("periods", (1,)), **_STATIC)
    periods: tuple[int, ...] = field(default=(), **_STATIC)
    n: int = field(default=1, **_STATIC)
    d: int = field(default=1, **_STATIC)
    candidates: tuple[int, ...] = field(default=(), **_STATIC)
    reference: str = field(default="{}", **_STATIC)

    @classmethod
    def build(cls, kept, d: int, config: MapConfig, **arrays) -> Map:
        """A map of ``kept`` (a fit's :class:`~rhythmic_jax.fitting.fit_plan.Kept`
        or a file's contents: ``stored``, ``params``, ``groups``, ``periods``,
        ``n``, ``c``, ``candidates``, ``candidate_errors``, ``group_errors``)
        fitted on d-dim frames; ``arrays``: ``extra``, ``codebook``,
        ``embedding``, and ``reference`` (a dict)."""
        reference = json.dumps(arrays.pop("reference", None) or {}, sort_keys=True)
        w, b = (jax.device_put(np.asarray(v, np.float32)) for v in kept.params)
        return cls(
            w=w, b=b, stored=dict(kept.stored), config=config, groups=kept.groups,
            periods=tuple(int(t) for t in kept.periods), n=int(kept.n), d=int(d),
            c=np.asarray(kept.c, np.float64), candidates=tuple(kept.candidates),
            candidate_errors=np.asarray(kept.candidate_errors, np.float64),
            group_errors=np.asarray(kept.group_errors, np.float64),
            reference=reference, **arrays,
        )  # fmt: skip

    @property
    def params(self) -> Templates:
        """``Templates(w, b)``: the float32 templates queries are scored with."""
        return Templates(self.w, self.b)

    @property
    def k(self) -> int:
        """Dimension of the templates: the embedding's k, else d."""
        return self.d if self.embedding is None else self.embedding.k

    @property
    def dtype(self) -> str:
        """How the templates are stored (``config.dtype``)."""
        return self.config.dtype

    @property
    def descriptor(self) -> str:
        """The name of the descriptor the map was built from."""
        return self.config.descriptor

    def where_from(self) -> dict[str, Any]:
        """``reference`` as a dict (a fresh one each call)."""
        return json.loads(self.reference)


def storage(m: Map) -> dict[str, Any]:
    """Bytes of the map (:func:`rhythmic_jax.map.storage.map_storage`): the
    templates in their dtype, the codes, the embedding shown apart."""
    book, emb = m.codebook, m.embedding
    return map_storage(
        m.groups.kind, m.groups.sizes, m.k, m.dtype, m.n, m.d,
        book and book.storage(), 0 if emb is None else embedding_bytes(emb),
    )  # fmt: skip


def with_dtype(m: Map, dtype: str) -> Map:
    """``m`` storing its templates as ``dtype``, from the values it stores now
    (requantize a float32 map, not a float16 one)."""
    stored = {key: np.asarray(v) for key, v in m.stored.items()}
    stored, (w, b) = requantize(stored, dtype)
    return replace(
        m, w=jax.device_put(w), b=jax.device_put(b), stored=stored,
        config=replace(m.config, dtype=dtype),
    )  # fmt: skip
