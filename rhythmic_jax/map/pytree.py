"""A fitted map as a JAX value: :class:`Map`, a registered pytree.

The arrays a decode reads are its leaves: the templates ``w`` (k, p) and biases
``b`` (p,) in float32 as queries are scored with them, the arrays as stored
(``stored``: ``w``, ``b`` in the map's dtype, ``scale`` for int8), the arrays
kept beside the map (``extra``), the codes (a
:class:`~rhythmic_jax.map.codes.CodeBook` or
:class:`~rhythmic_jax.map.scalar_codes.ScalarCodeBook`, registered here as
pytrees of their arrays) and the embedding (its arrays), None where absent.
The fit's record (penalty, training errors) are leaves too. Everything else is
static and hashable: the layout (``groups``), periods, n, d, the configuration
(dtype, descriptor, decode settings) and the candidate periods. So
a map can be an argument of ``jax.jit`` (a new layout or configuration compiles
anew, new template values do not) and maps of one layout can be stacked and
``jax.vmap``-ed. The pure functions over it live along the pipeline:
:func:`rhythmic_jax.fitting.fit_map.fit`, :mod:`rhythmic_jax.decoding.queries`
(scores, decode, sequences) and :mod:`rhythmic_jax.map.map_file` (save, load).

Names: k the templates' dimension (the embedding's output, else d), p templates,
n places.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.map.codes import CodeBook, CodeTransform
from rhythmic_jax.map.config import MapConfig
from rhythmic_jax.map.embedding import Embedding, embedding_bytes
from rhythmic_jax.map.groups import Groups
from rhythmic_jax.map.quantize import requantize
from rhythmic_jax.map.scalar_codes import ScalarCodeBook
from rhythmic_jax.map.storage import map_storage

__all__ = [
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


# the code books are pytrees of their arrays (nothing static: kind is a class name)
jax.tree_util.register_dataclass(CodeTransform, ["mean", "projection"], [])
jax.tree_util.register_dataclass(CodeBook, ["transform", "codes"], [])
jax.tree_util.register_dataclass(ScalarCodeBook, ["vmin", "vdiff", "codes"], [])

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
    (``candidate_errors`` (k,)) and of every kept group (``group_errors``
    (r,)). Leaves that are numpy arrays are copied to the device by every jitted
    call that takes the map: ``jax.device_put(map)`` once keeps them there.

    Static: ``config`` (:class:`~rhythmic_jax.map.config.MapConfig`),
    ``groups`` (:class:`~rhythmic_jax.map.groups.Groups`), ``periods`` (the
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
    config: MapConfig = field(default_factory=MapConfig, **_STATIC)
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
    stored, (w, b) = requantize({k: np.asarray(v) for k, v in m.stored.items()}, dtype)
    return replace(
        m, w=jax.device_put(w), b=jax.device_put(b), stored=stored,
        config=replace(m.config, dtype=dtype),
    )  # fmt: skip
