"""Frame descriptors by name, run over frames, cached on disk; the torch/JAX
seam (DLPack).

:func:`get_descriptor` makes a registered descriptor (:data:`DESCRIPTORS`, the
classes of :mod:`rhythmic_jax.frames.descriptors`, importable from here too) from
its name and settings; :func:`describe` runs it over uint8 frames,
:func:`cached_describe` memoises that in an .npy file. Nordland winter queries
against the summer map, recall@1 (exact index): ``efficientnet_lite0`` 0.477 at
224x112, 0.547 at 224x224; patchnorm 0.126, HOG 0.212.

``python scripts/bench_frames.py descriptors`` measures them all on Nordland.

torch (seconds to import) and scikit-image's HOG load when a descriptor first
computes rows: naming a descriptor, its settings and a cache hit need neither.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.frames.cache_files import (
    default_cache_dir,
    load_cached,
    save_cached,
)
from rhythmic_jax.frames.compiled import AUTO, CompilePolicy
from rhythmic_jax.frames.descriptors import Descriptor as Descriptor
from rhythmic_jax.frames.descriptors import (
    EfficientNetLite0Map as EfficientNetLite0Map,
)
from rhythmic_jax.frames.descriptors import Hog as Hog
from rhythmic_jax.frames.descriptors import PatchNorm as PatchNorm
from rhythmic_jax.frames.descriptors import VGG16Fc7 as VGG16Fc7
from rhythmic_jax.frames.descriptors import check_positive
from rhythmic_jax.frames.descriptors import grey as grey
from rhythmic_jax.frames.descriptors import resize as resize
from rhythmic_jax.frames.weights import PROVENANCE

if TYPE_CHECKING:
    import jax
    import torch


__all__ = [
    "DESCRIPTORS",
    "Descriptor",
    "EfficientNetLite0Map",
    "Hog",
    "PatchNorm",
    "VGG16Fc7",
    "cache_path",
    "cached_describe",
    "default_cache_dir",
    "describe",
    "get_descriptor",
    "grey",
    "resize",
    "to_jax",
]

log = logging.getLogger(__name__)

DESCRIPTORS: dict[str, type] = {
    d.name: d for d in (EfficientNetLite0Map, VGG16Fc7, PatchNorm, Hog)
}


def get_descriptor(name: str, **settings) -> Descriptor:
    """The registered descriptor ``name`` with ``settings`` (see each class)."""
    if name not in DESCRIPTORS:
        raise InputError(f"unknown descriptor {name!r}; known: {sorted(DESCRIPTORS)}")
    cls = DESCRIPTORS[name]
    fields = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(settings) - fields)
    if unknown:
        raise InputError(
            f"descriptor {name}: unknown settings {unknown}; known: {sorted(fields)}"
        )
    required = sorted(
        f.name
        for f in dataclasses.fields(cls)
        if f.default is dataclasses.MISSING
        and f.default_factory is dataclasses.MISSING
        and f.name not in settings
    )
    if required:
        hint = " (a state-dict file: {option} PATH)" if "weights" in required else ""
        raise InputError(
            f"descriptor {name} needs {', '.join(required)}{hint}", option="weights"
        )
    return cls(**settings)


@contextmanager
def _torch_threads(num_threads: int | None) -> Iterator[None]:
    """Run with ``num_threads`` intra-op torch threads, then restore the count."""
    import torch

    before = torch.get_num_threads()
    if num_threads:
        torch.set_num_threads(num_threads)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def _check_images(images: np.ndarray, name: str = "images") -> None:
    if not isinstance(images, np.ndarray) or images.dtype != np.uint8:
        raise InputError(f"{name}: expected a uint8 numpy array (n, H, W, 3)")
    if images.ndim != 4 or images.shape[-1] != 3:
        raise InputError(f"{name}: expected shape (n, H, W, 3), got {images.shape}")


def describe(
    images: np.ndarray,
    descriptor: Descriptor,
    batch_size: int = 64,
    progress: bool = False,
    num_threads: int | None = None,
    compile: CompilePolicy = AUTO,
) -> np.ndarray:
    """Describe uint8 RGB frames (n, H, W, 3) -> float32 (n, dim), rows unit norm.

    Conversion and resizing run a batch or two ahead of the network, which runs
    compiled when ``compile`` says the job is large enough
    (:mod:`rhythmic_jax.frames.compiled`). ``num_threads`` sets torch's intra-op threads
    for the call (None: unchanged).
    """
    from rhythmic_jax.frames.pipeline import describe_chunks

    _check_images(images)
    check_positive(batch_size=batch_size)
    chunks = (images[i : i + batch_size] for i in range(0, len(images), batch_size))
    with _torch_threads(num_threads):
        return describe_chunks(chunks, len(images), descriptor, compile, progress)


def to_jax(t: torch.Tensor) -> jax.Array:
    """torch tensor -> jax.Array through DLPack, sharing memory when contiguous.

    Do not modify ``t`` afterwards: the JAX array sees the change.
    """
    import jax

    return jax.dlpack.from_dlpack(t.detach().contiguous())


def _cache_settings(descriptor: Descriptor) -> dict:
    """Settings that identify a descriptor's output in the cache.

    Packaged weights are named by their file, whose name carries the first eight
    hex digits of its sha256 (the torch hub convention); a user's file by its
    path and sha256.
    """
    s = dict(descriptor.settings())
    drop = PROVENANCE if s.get("weights_package") else ("weights_version",)
    return {k: v for k, v in s.items() if k not in drop}


def cache_path(
    images: np.ndarray, descriptor: Descriptor, key: str, cache_dir=None
) -> Path:
    """``<cache_dir>/<key>-<name>-<hash>.npy``; the hash covers the descriptor's
    name and settings and the images' shape and bytes."""
    if not key or any(c in key for c in "/\\") or key.startswith("."):
        raise InputError(f"cache key {key!r}: use a plain, non-empty file-name part")
    _check_images(images)
    ident = {"name": descriptor.name, "settings": _cache_settings(descriptor)}
    pixels = hashlib.sha256(np.ascontiguousarray(images).data).hexdigest()
    ident["images"] = [list(images.shape), pixels]
    digest = hashlib.sha256(json.dumps(ident, sort_keys=True).encode()).hexdigest()
    folder = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    return folder / f"{key}-{descriptor.name}-{digest[:16]}.npy"


def cached_describe(
    images: np.ndarray,
    descriptor: Descriptor,
    key: str,
    cache_dir: str | Path | None = None,
    batch_size: int = 64,
    progress: bool = False,
    num_threads: int | None = None,
    compile: CompilePolicy = AUTO,
) -> np.ndarray:
    """:func:`describe`, memoised in an .npy file (see :func:`cache_path`).

    The file is written atomically (temporary file, then ``os.replace``); an
    unreadable or mis-shaped cache file is recomputed, and a cache that cannot
    be written (full, read-only, a file) warns once and is gone without.
    """
    images = np.ascontiguousarray(images)
    path = cache_path(images, descriptor, key, cache_dir)
    x = load_cached(path, (len(images), descriptor.dim))
    if x is not None:
        return x
    x = describe(images, descriptor, batch_size, progress, num_threads, compile)
    save_cached(path, x)  # a cache that cannot be written warns once
    return x
