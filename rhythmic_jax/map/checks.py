"""A map checked for meaning, not only bytes: what a loaded map must hold.

A map folder's digests say its bytes are those its save wrote, not that they
make sense: a map from someone else may carry NaN templates, a layout that
tells apart more places than a decode can index, or reference labels naming a
place it does not have, all with digests recomputed. :func:`check_map` refuses
such a :class:`~rhythmic_jax.map.pytree.Map` in one line
(:class:`~rhythmic_jax.errors.InputError`), and :func:`check_decode` refuses a
decode whose largest allocation would not fit in memory, before it is made:

- every floating-point leaf is finite (templates and their scale, the fit's
  record, the codes' transform, the embedding, arrays kept beside the map);
- the configuration names a descriptor, its settings (a mapping) and the
  phases top-m keeps (an integer >= 1);
- shapes agree with the layout and n: ``w`` (k, p), ``b`` and ``scale`` (p,)
  for the ``p = sum(sizes)`` classes of the groups, a periods map's periods
  equal to its groups' sizes, the codes (n, ...) over k, the embedding (d, k)
  with consistent layers;
- n lies in [1, capacity] (:meth:`~rhythmic_jax.map.groups.Groups.check`, which
  also holds the layouts' own rules, co-prime periods among them) and the
  capacity below :data:`MAX_PLACES`, since every decode indexes places and sums
  Chinese-remainder tables in int32;
- ``reference_labels`` are integers in [0, n), one per row of
  ``reference_positions`` when both are kept, which are (rows, 2).

A place-domain decode (soft or top-m of a mixed or hierarchical layout, soft of
periods, any decode fused with codes) holds a score per place for up to
:data:`DECODE_BATCH` queries at a time, so its memory grows as ``n`` times the
batch (:func:`decode_bytes`), and ``evaluate``'s ranking of every place
(recall@K) holds one for every query at once; the hard decode's memory does
not grow with n.

Shapes: n places, d input features, k the templates' dimension, p templates.
"""

from __future__ import annotations

import math
import os
from typing import TYPE_CHECKING

import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.io.reader import available_memory

if TYPE_CHECKING:
    from rhythmic_jax.map.pytree import Map

__all__ = [
    "DECODE_BATCH",
    "MAX_PLACES",
    "check_decode",
    "check_map",
    "decode_bytes",
    "memory_budget",
]

MAX_PLACES = 2**30
"""Places a map's layout may tell apart (its capacity): decodes index places in
int32 and sum Chinese-remainder table entries below the capacity M, which stay
below 2 M < 2**31 (:func:`rhythmic_jax.map.periods.crt_tables`)."""

DECODE_BATCH = 256
"""Queries a place-domain decode scores at a time (the ``batch_size`` of
:func:`rhythmic_jax.decoding.soft.soft_decode` and its kin)."""

# a place-domain decode's bytes: compiling its program, then per place (its
# columns) and per place and query of a batch (measured with
# rhythmic_jax.solvers.memory.peak_growth, r = 2: at n = 10**6 soft 249 B a
# place at 16 queries, 2,205 at 256, top-m of a mixed layout 4,808 at 256; at
# n = 250,000 soft 103 MiB at 16 queries, 522 MiB at 256), rounded up
_COMPILE = 64 * 2**20
_PER_PLACE = 128
_PER_QUERY = {"soft": 10, "topm": 20}
# a decode below this is not checked against the budget (reading it costs more
# than a small decode's scores): any machine that runs JAX has it to spare
_SMALL = 128 * 2**20


def check_map(m: Map, where: str | os.PathLike = "map") -> Map:
    """``m`` when it makes sense, else :class:`InputError` naming ``where``
    (the map's folder) and the first thing wrong (module docstring)."""
    try:
        _check_layout(m)
        _check_config(m.config)
        _check_shapes(m)
        _check_finite(m)
        _check_labels(m)
    except InputError as err:
        raise InputError(f"{where}: {err}", err.option) from None
    return m


def _check_layout(m: Map) -> None:
    groups = m.groups
    if groups.kind == "periods" and tuple(m.periods) != groups.sizes:
        raise InputError(f"periods {m.periods} differ from the layout's {groups.sizes}")
    if groups.capacity >= MAX_PLACES:
        raise InputError(
            f"{groups.describe()} tells apart {groups.capacity:,} places; a decode "
            f"indexes fewer than {MAX_PLACES:,}"
        )
    groups.check(m.n)


def _check_config(cfg) -> None:
    """What a query reads of the configuration that its own checks leave: the
    descriptor's name and settings, and the phases top-m keeps."""
    if not isinstance(cfg.descriptor, str) or not cfg.descriptor:
        raise InputError(f"descriptor must be a name, got {cfg.descriptor!r}")
    if not isinstance(cfg.descriptor_settings, dict):
        raise InputError(
            f"descriptor_settings must be a mapping, got {cfg.descriptor_settings!r}"
        )
    if type(cfg.top) is not int or cfg.top < 1:
        raise InputError(
            f"top (phases top-m keeps) must be an integer >= 1, got {cfg.top!r}"
        )


def _check_shapes(m: Map) -> None:
    p, k = m.groups.p, m.k
    want = {"w": (k, p), "b": (p,), "scale": (p,)}
    arrays = {"w": m.w, "b": m.b} | {f"stored {n}": v for n, v in m.stored.items()}
    for name, value in arrays.items():
        shape = tuple(np.shape(value))
        if shape != want[name.split()[-1]]:
            raise InputError(
                f"{name} of shape {shape} does not fit {m.groups.describe()} with "
                f"k={k} (want {want[name.split()[-1]]})"
            )
    emb = m.embedding
    if emb is not None:
        h = np.shape(emb.b1)[0] if np.ndim(emb.b1) == 1 else -1
        shapes = [np.shape(a) for a in emb]
        linear = [(emb.d,), (emb.d, k), (k, 0), (0,), (0, k)]
        mlp = [(m.d,), (m.d, k), (k, h), (h,), (h, k)]
        if emb.d != m.d or shapes not in (linear, mlp):
            raise InputError(
                f"embedding arrays of shapes {shapes} do not fit d={m.d}, k={k}"
            )
    book = m.codebook
    if book is not None:
        codes = np.shape(book.codes)
        if len(codes) != 2 or codes[0] != m.n:
            raise InputError(f"codes of shape {codes} do not fit n={m.n}")
        if book.kind == "int8":
            shapes = [np.shape(book.vmin), np.shape(book.vdiff), codes]
            ok = shapes == [(k,), (k,), (m.n, k)]
        else:
            t = book.transform
            shapes = [np.shape(t.mean), np.shape(t.projection), codes]
            ok = shapes == [(k,), (codes[1], k), (m.n, codes[1])]
        if not ok:
            raise InputError(f"codes of shapes {shapes} do not fit n={m.n}, k={k}")


def _leaves(m: Map):
    """(name, array) of every array the map holds."""
    import jax

    for path, leaf in jax.tree_util.tree_leaves_with_path(m):
        yield jax.tree_util.keystr(path).lstrip("."), leaf


def _check_finite(m: Map) -> None:
    for name, leaf in _leaves(m):
        if name.startswith("config."):  # checked by MapConfig (NaN: no threshold)
            continue
        value = np.asarray(leaf)
        if value.dtype.kind in "fc" and not np.isfinite(value).all():
            bad = int(value.size - np.isfinite(value).sum())
            raise InputError(
                f"{name} holds {bad:,} NaN or infinite value(s) of {value.size:,}"
            )


def _check_labels(m: Map) -> None:
    labels = m.extra.get("reference_labels")
    positions = m.extra.get("reference_positions")
    if positions is not None:
        shape = np.shape(positions)
        if len(shape) != 2 or shape[1] != 2:
            raise InputError(f"reference_positions of shape {shape}: want (rows, 2)")
    if labels is None:
        return
    labels = np.asarray(labels)
    if labels.ndim != 1 or labels.dtype.kind not in "iu" or not labels.size:
        raise InputError(
            f"reference_labels must be one integer place per reference frame, got "
            f"{labels.dtype} of shape {labels.shape}"
        )
    low, high = int(labels.min()), int(labels.max())
    if low < 0 or high >= m.n:
        raise InputError(
            f"reference_labels name places {low}..{high}, the map has 0..{m.n - 1}"
        )
    if positions is not None and np.shape(positions)[0] != len(labels):
        raise InputError(
            f"{len(labels)} reference_labels but {np.shape(positions)[0]} "
            "reference_positions"
        )


# -------------------------------------------------------------------- decodes
def decode_bytes(
    m: Map,
    how: str,
    rows: int = DECODE_BATCH,
    top: int = 3,
    sequence: bool = False,
    at_once: bool = False,
) -> int:
    """Bytes of the allocations of decoding ``rows`` queries of ``m`` with ``how``
    ("hard", "soft" or "topm"; ``top`` phases; ``sequence``: frames of a sequence)
    that grow with n: a score per place for ``min(rows, DECODE_BATCH)`` queries
    (``at_once``: for every query, as a ranking of all places holds each group's
    gathered scores and their sum, ``4 (r + 1)`` bytes a place and query), and
    with codes a similarity per place for every query. 0 for a hard decode that
    the map's layout makes without place scores (a map without codes; a sequence
    of a mixed or hierarchical map sums place scores whatever ``how``): its
    memory follows p, not n."""
    batch = max(1, int(rows) if at_once else min(int(rows), DECODE_BATCH))
    codes = m.codebook is not None
    places = codes or at_once or (sequence and m.groups.kind != "periods")
    if how == "hard" and not places:
        return 0
    if how == "topm" and m.groups.kind == "periods" and not places:
        combos = math.prod(min(int(top), t) for t in m.groups.sizes)
        return batch * combos * 12
    per_query = _PER_QUERY["topm" if how == "topm" else "soft"]
    if at_once:
        per_query = max(per_query, 4 * (len(m.groups.sizes) + 1))
    need = _COMPILE + m.n * (_PER_PLACE + batch * per_query)
    return need + (m.n * int(rows) * 4 if codes else 0)


def memory_budget() -> int:
    """Bytes a decode may allocate: what this process may still allocate
    (:func:`rhythmic_jax.io.reader.available_memory`: ``MemAvailable`` within an
    address-space limit)."""
    return available_memory()


def check_decode(
    m: Map,
    how: str,
    rows: int = DECODE_BATCH,
    top: int = 3,
    sequence: bool = False,
    budget: int | None = None,
    at_once: bool = False,
) -> int:
    """Refuse (:class:`InputError`) a decode of ``rows`` queries whose
    :func:`decode_bytes` exceed ``budget`` (default :func:`memory_budget`,
    read only for a decode above 128 MiB), before anything is allocated; else
    return those bytes."""
    need = decode_bytes(m, how, rows, top, sequence, at_once)
    if need <= _SMALL and budget is None:
        return need
    budget = memory_budget() if budget is None else int(budget)
    if need > budget:
        gib = f"about {need / 2**30:.1f} GiB but {budget / 2**30:.1f} GiB are available"
        if at_once:
            raise InputError(
                f"ranking {m.n:,} places for {rows:,} queries needs {gib}; use "
                "fewer queries, a smaller map or a machine with more memory"
            )
        raise InputError(
            f"a {how} decode of {m.n:,} places needs {gib}; {{opt:decode}} hard, "
            "or on a machine with more memory"
        )
    return need
