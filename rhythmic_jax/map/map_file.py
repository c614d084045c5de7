"""A map's file format: what a map folder holds, written, read and checked here.

A map folder (:mod:`rhythmic_jax.io.checkpoint` writes it atomically) holds the
arrays

* ``w`` (d, p), ``b`` (p,): the kept templates in their dtype, with ``scale``
  (p,) when they are int8;
* ``extra_<name>``: arrays a source kept with the map (a projection, ...);
* the codes' arrays (:data:`CODE_ARRAYS`, by kind) when the map has codes;
* the embedding's arrays when one is applied before the map;

and ``map.json``: every key of :data:`INFO_KEYS` (what ``rhythmic-jax info``
shows, :meth:`rhythmic_jax.RhythmicMap.info`) plus ``codes_kind``, ``dtype``,
``package_version``, ``format_version`` and ``digests`` (the sha256 of every
stored file and array, checked by :func:`load` and :func:`info`).

:func:`save` writes a :class:`~rhythmic_jax.map.pytree.Map`, :func:`load`
reads one back, checked, and :func:`info` describes a folder from
``map.json`` and its files' checksums when its metadata is complete and
consistent and its arrays are listed as saved (no JAX imported, no array
decoded). Maps saved before layouts, embeddings, codes or checksums existed,
or with a setting under its earlier name (:data:`RENAMED_SETTINGS`), still
load.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.io.checkpoint import (
    arrays_listed,
    checksums_of,
    load_map,
    locked,
    read_metadata,
    save_map,
    verify_files,
)
from rhythmic_jax.map.periods import database_bytes
from rhythmic_jax.map.quantize import dequantize

__all__ = [
    "CODE_ARRAYS",
    "INFO_KEYS",
    "RENAMED_SETTINGS",
    "MapFile",
    "consistent",
    "describe",
    "embedding_info",
    "info",
    "load",
    "save",
    "settings_now",
]

INFO_KEYS = (
    "n", "d", "periods", "storage_bytes", "database_bytes", "compression_ratio",
    "c", "candidates", "candidate_errors", "descriptor", "descriptor_settings",
    "config", "reference", "storage", "codes_bits", "embedding_bytes", "embedding",
    "layout", "groups", "group_errors",
)  # fmt: skip
# by kind of codes (rhythmic_jax.map.codes, rhythmic_jax.map.scalar_codes)
CODE_ARRAYS = {
    "itq": {"codes_mean", "codes_projection", "codes_packed"},
    "int8": {"codes_vmin", "codes_vdiff", "codes_uint8"},
}
# settings saved under an earlier name in a map's config: earlier -> now
RENAMED_SETTINGS = {"m": "top"}
EMBEDDING_KEYS = ("kind", "head", "d", "k", "descriptor", "descriptor_settings",
                  "learn", "sources")  # fmt: skip


class MapFile(NamedTuple):
    """A map folder's templates and record, checked: what the
    :class:`~rhythmic_jax.map.pytree.Map` is built from. ``stored`` holds ``w``
    (k, p), ``b`` (p,) and ``scale`` (p,) for int8 templates; ``params`` their
    float32 values; ``k`` is the embedding's output dimension, else ``d``."""

    stored: dict[str, np.ndarray]
    params: tuple[np.ndarray, np.ndarray]
    periods: tuple[int, ...]
    n: int
    groups: Any  # rhythmic_jax.map.groups.Groups
    group_errors: tuple[float, ...]
    c: float
    candidates: tuple[int, ...]
    candidate_errors: tuple[float, ...]


def describe(m) -> dict[str, Any]:
    """The :data:`INFO_KEYS` and ``codes_kind`` of the map ``m`` (a
    :class:`~rhythmic_jax.map.pytree.Map`): what ``map.json`` and ``rhythmic-jax
    info --json`` hold."""
    from rhythmic_jax.map.embedding import embedding_bytes
    from rhythmic_jax.map.pytree import storage as map_storage

    book, emb = m.codebook, m.embedding
    storage = map_storage(m)
    return {
        "n": m.n,
        "d": m.d,
        "periods": list(m.periods),
        "layout": m.groups.describe(),
        "groups": m.groups.to_dict(),
        "group_errors": [float(e) for e in m.group_errors],
        "storage_bytes": storage["total"],
        "embedding_bytes": 0 if emb is None else embedding_bytes(emb),
        "embedding": None if emb is None else {"kind": emb.kind, "k": emb.k},
        "database_bytes": database_bytes(m.n, m.d, 4),
        "compression_ratio": storage["share"],
        "storage": storage,
        "codes_bits": book.bits if book else None,
        "codes_kind": book.kind if book else None,
        "c": float(m.c),
        "candidates": list(m.candidates),
        "candidate_errors": [float(e) for e in m.candidate_errors],
        "descriptor": m.config.descriptor,
        "descriptor_settings": m.config.descriptor_settings,
        "config": dict(asdict(m.config)),
        "reference": m.where_from(),
    }


def save(path: str | os.PathLike, m) -> None:
    """Write the map ``m`` (a :class:`~rhythmic_jax.map.pytree.Map`) to the
    folder ``path``, atomically."""
    from rhythmic_jax.map.embedding import embedding_arrays
    from rhythmic_jax.version import __version__

    arrays = {k: np.asarray(v) for k, v in m.stored.items()}
    arrays.update({f"extra_{k}": np.asarray(v) for k, v in m.extra.items()})
    if m.codebook is not None:
        arrays.update(m.codebook.arrays())
    if m.embedding is not None:
        arrays.update(embedding_arrays(m.embedding))
    meta = describe(m)
    meta.update(dtype=m.config.dtype, package_version=__version__)
    save_map(path, arrays, meta)


def reference(sources, **more) -> str:
    """A map's provenance as ``Map.reference`` holds it: JSON of the sources'
    absolute paths and ``more`` (the tiling, a selection, the embedding, ...),
    so that brute force finds the reference frames again."""
    paths = [str(Path(s).expanduser().absolute()) for s in sources]
    return json.dumps({"sources": paths, **more}, sort_keys=True)


def settings_now(saved: dict) -> dict:
    """A saved map's configuration ``{setting: value}`` under the names its
    settings have now (:data:`RENAMED_SETTINGS`; a name of now wins)."""
    got = dict(saved)
    for old, new in RENAMED_SETTINGS.items():
        if old in got:
            value = got.pop(old)
            got.setdefault(new, value)
    return got


def load(
    path: str | os.PathLike,
    make_config: Callable[..., Any] | None = None,
    *,
    descriptor: str | None = None,
    descriptor_settings: dict | None = None,
    d: int | None = None,
):
    """Read and check the map folder ``path`` into a
    :class:`~rhythmic_jax.map.pytree.Map`; ``make_config(**settings)``
    (default :class:`~rhythmic_jax.map.config.MapConfig`) builds its
    configuration from ``map.json``'s, earlier names renamed
    (:func:`settings_now`). A map built for another descriptor, other settings
    or another d is refused (:class:`InputError`), as is a corrupt one."""
    from rhythmic_jax.map.checks import check_map
    from rhythmic_jax.map.codes import codebook_from_arrays
    from rhythmic_jax.map.config import MapConfig
    from rhythmic_jax.map.embedding import embedding_from_arrays
    from rhythmic_jax.map.groups import Groups
    from rhythmic_jax.map.pytree import Map

    make_config = make_config or MapConfig
    arrays, meta = load_map(path)
    try:
        cfg = make_config(**settings_now(meta["config"]))
        periods = tuple(int(t) for t in meta["periods"])
        n, dim = int(meta["n"]), int(meta["d"])
        c = float(meta["c"])
        cands = tuple(int(t) for t in meta.get("candidates", ()))
        errors = tuple(float(e) for e in meta.get("candidate_errors", ()))
        group_errors = tuple(float(e) for e in meta.get("group_errors", ()))
        w, b = arrays["w"], arrays["b"]
        # maps saved before layouts existed are periods maps
        kind = meta.get("groups", {}).get("kind", "periods")
        groups = (
            Groups("periods", periods)
            if kind == "periods"
            else Groups.from_dict(meta["groups"])
        )
        emb = embedding_from_arrays(arrays)
    except (KeyError, TypeError, ValueError, OverflowError, AttributeError) as err:
        raise InputError(f"{path}: corrupt map metadata ({err!r})") from None
    tdim = dim if emb is None else emb.k
    if emb is not None and emb.d != dim:
        raise InputError(f"{path}: embedding expects {emb.d}-d input, map says {dim}")
    if w.shape != (tdim, groups.p) or b.shape != (groups.p,):
        raise InputError(
            f"{path}: weights of shape {w.shape} do not fit "
            f"{groups.describe()}, d={tdim}"
        )
    try:
        groups.check(n)
    except InputError as err:
        raise InputError(f"{path}: corrupt map metadata ({err})") from None
    _check_queries(path, cfg, dim, descriptor, descriptor_settings, d)
    stored = {"w": w, "b": b}
    if "scale" in arrays:
        stored["scale"] = arrays["scale"]
    if (w.dtype == np.int8) != ("scale" in stored) or str(w.dtype) != cfg.dtype:
        raise InputError(f"{path}: weights stored as {w.dtype}, map says {cfg.dtype}")
    codebook = None
    if cfg.codes is not None:
        try:
            codebook = codebook_from_arrays(arrays, n, tdim, cfg.codes)
        except KeyError as err:
            raise InputError(f"{path}: codes are missing ({err})") from None
        except InputError as err:
            raise InputError(f"{path}: {err}") from None
    reference = meta.get("reference", {})
    kept = MapFile(
        stored=stored, params=dequantize(stored), periods=periods, n=n,
        groups=groups, group_errors=group_errors, c=c, candidates=cands,
        candidate_errors=errors,
    )  # fmt: skip
    return check_map(Map.build(
        kept, dim, cfg, codebook=codebook, embedding=emb,
        extra={k[6:]: v for k, v in arrays.items() if k.startswith("extra_")},
        reference=reference if isinstance(reference, dict) else {},
    ), path)  # fmt: skip


def _check_queries(path, cfg, dim, descriptor, descriptor_settings, d) -> None:
    """Refuse queries described otherwise than the map's reference frames."""
    if descriptor is not None and descriptor != cfg.descriptor:
        raise InputError(
            f"{path}: map built with descriptor {cfg.descriptor!r}, "
            f"queries use {descriptor!r}"
        )
    if descriptor_settings is not None and descriptor_settings != (
        cfg.descriptor_settings
    ):
        raise InputError(
            f"{path}: map built with {cfg.descriptor} settings "
            f"{cfg.descriptor_settings}, queries use {descriptor_settings}"
        )
    if d is not None and d != dim:
        raise InputError(f"{path}: map built for {dim}-d features, queries are {d}-d")


def consistent(meta: dict[str, Any], listed: set[str]) -> bool:
    """Whether a map's metadata holds every info field, agreeing with itself, and
    ``listed`` (the arrays a completed save lists) holds the arrays it needs."""
    try:
        n, d, periods = int(meta["n"]), int(meta["d"]), list(meta["periods"])
        k = int(meta["embedding"]["k"]) if meta["embedding"] else d  # templates' d
        templates = sum(int(t) for t in periods) * (k + 1) * 4
        st = meta["storage"]
        ok = sum(st["per_period"].values()) == templates
        ok = ok and meta["storage_bytes"] == templates + st["fixed"] + st["per_place"]
        ok = ok and meta["database_bytes"] == n * d * 4
        kind = meta.get("codes_kind") or "itq"
        arrays = {"w", "b"} | (CODE_ARRAYS[kind] if meta["codes_bits"] else set())
    except (KeyError, TypeError, ValueError, OverflowError, AttributeError):
        return False
    return ok and all(k in meta for k in INFO_KEYS) and arrays <= listed


def info(
    path: str | os.PathLike, load_info: Callable[[str | os.PathLike], dict]
) -> dict[str, Any]:
    """What the map (or embedding) folder ``path`` holds.

    Every file of the map is first checked against its save's digests (a changed
    byte ends in :class:`InputError` naming the file; ``checksums`` says whether
    the map carries them). A map whose metadata is :func:`consistent` is then
    described from ``map.json`` alone; any other is handed to ``load_info`` (the
    loaded map's own :meth:`~rhythmic_jax.RhythmicMap.info`, whose load says what
    is wrong).
    """
    with locked(path, exclusive=False):  # one whole version, not half of two
        folder, meta = read_metadata(path)
        listed = arrays_listed(folder)  # empty: the load names what is missing
        verify_files(folder, meta, missing=bool(listed))
        checksums = {"checksums": checksums_of(meta)}
        if meta.get("kind") == "embedding":
            return embedding_info(meta) | checksums
        if consistent(meta, listed):
            return (
                {key: meta[key] for key in INFO_KEYS}
                | checksums
                | {"codes_kind": meta.get("codes_kind")}
            )
    return load_info(path) | checksums


def embedding_info(meta: dict[str, Any]) -> dict[str, Any]:
    """What an embedding folder holds (written by ``learn``), from its metadata:
    kind, dimensions, descriptor, how it was learned and the fusion weight learned
    with it (None in one written before the weight was kept)."""
    return {key: meta.get(key) for key in EMBEDDING_KEYS} | {
        "fusion": meta.get("fusion")
    }
