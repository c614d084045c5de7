"""Image augmentation with kornia: the paper's seven operations, seeded and replayable.

The paper trains on augmented copies of the reference frames when no second
traversal is available: Gaussian blur, horizontal flip, random crop, elastic
transform, contrast normalisation, channel invert and grey-scale, "each alone
and all merged" (here ``"all"`` applies the seven in that order).

Batches are float32 tensors ``(b, 3, H, W)`` in ``[0, 1]``; :func:`to_batch`
and :func:`to_images` convert from and to uint8 ``(n, H, W, 3)`` frames. Every
operation is a kornia augmentation module; its random draws are made by
``forward_parameters`` under a fixed torch seed (the global torch RNG is left as
it was), returned as a tuple of dicts of tensors (one per operation) and can be
applied again with :func:`replay` (they survive ``torch.save`` /
``torch.load(weights_only=True)``).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import kornia.augmentation as K
import numpy as np
import torch
import torch.nn.functional as F
from kornia.filters import get_gaussian_kernel1d

from rhythmic_jax.errors import InputError

__all__ = [
    "NAMES",
    "AugmentConfig",
    "Params",
    "augment",
    "augment_examples",
    "augmented_batch",
    "build_pipeline",
    "epoch_order",
    "replay",
    "sample_params",
    "to_batch",
    "to_images",
]

NAMES = (
    "gaussian_blur",
    "hflip",
    "random_crop",
    "elastic",
    "contrast",
    "invert",
    "grayscale",
)
ELASTIC_IMPLS = ("kornia", "coarse")

Params = tuple[dict[str, torch.Tensor], ...]


@dataclass(frozen=True)
class AugmentConfig:
    """Which augmentations to apply, and their ranges.

    Attributes:
      names: operations from :data:`NAMES`, applied in the order given;
        ``"all"`` stands for the seven in the paper's order.
      p: probability that each operation is applied to each image.
      blur_sigma: Gaussian blur sigma range in pixels, truncated at 4 sigma
        (as ``skimage.filters.gaussian``), mirror borders.
      crop_keep: range of the fraction of each side a random crop keeps; the crop
        is resized back to the input size (bilinear), as imgaug's
        ``Crop(percent=..., keep_size=True)``.
      elastic_alpha: root-mean-square displacement per axis of the elastic
        transform, in normalised coordinates (the image spans [-1, 1], so 0.03 is
        1.5% of the side: 3.4 pixels at 224).
      elastic_sigma: smoothness of the displacement field: the Gaussian sigma
        that smooths the random noise, as a fraction of the image side.
      elastic_impl: ``"kornia"`` (``RandomElasticTransform``: full-resolution
        noise smoothed by a large kernel) or ``"coarse"`` (the same field drawn
        on a grid coarser by about sigma/2 pixels, smoothed by a small kernel and
        upsampled bilinearly; several times faster, see
        ``scripts/bench_frames.py augment``).
      contrast: range of the contrast factor ``a`` in ``0.5 + a * (x - 0.5)``
        (imgaug's ``ContrastNormalization`` / ``LinearContrast`` about mid-grey).

    Example: ``augment(batch, AugmentConfig(("all",)), seed=0)`` returns a batch
    where every image had each of the seven operations with probability 1/2.
    """

    names: tuple[str, ...] = ("all",)
    p: float = 0.5
    blur_sigma: tuple[float, float] = (0.1, 2.0)
    crop_keep: tuple[float, float] = (0.8, 1.0)
    elastic_alpha: float = 0.03
    elastic_sigma: float = 0.08
    elastic_impl: str = "kornia"
    contrast: tuple[float, float] = (0.75, 1.5)

    def __post_init__(self):
        names = (self.names,) if isinstance(self.names, str) else tuple(self.names)
        object.__setattr__(self, "names", names)  # hashable: pipelines are cached
        if not self.names:
            raise InputError("augmentation names are empty; known: " + ", ".join(NAMES))
        for name in self.names:
            if name != "all" and name not in NAMES:
                known = ", ".join(NAMES + ("all",))
                raise InputError(f"unknown augmentation {name!r}; known: {known}")
        if not 0.0 <= self.p <= 1.0:
            raise InputError(f"augmentation p must be in [0, 1], got {self.p}")
        if self.elastic_impl not in ELASTIC_IMPLS:
            raise InputError(f"elastic_impl must be one of {ELASTIC_IMPLS}")
        checks = (
            ("blur_sigma", self.blur_sigma, 0.0, math.inf),
            ("crop_keep", self.crop_keep, 0.0, 1.0),
            ("contrast", self.contrast, 0.0, math.inf),
        )
        for field, pair, low, high in checks:
            if len(pair) != 2 or not low < pair[0] <= pair[1] <= high:
                raise InputError(f"{field} must satisfy {low} < lo <= hi <= {high}")
            object.__setattr__(self, field, (float(pair[0]), float(pair[1])))
        if self.elastic_alpha < 0 or self.elastic_sigma <= 0:
            raise InputError("elastic_alpha must be >= 0 and elastic_sigma > 0")

    @property
    def ops(self) -> tuple[str, ...]:
        """``names`` with ``"all"`` expanded."""
        return tuple(op for n in self.names for op in (NAMES if n == "all" else (n,)))


# ------------------------------------------------------------------ custom ops


class RandomLinearContrast(K.IntensityAugmentationBase2D):
    """``clip(0.5 + a * (x - 0.5), 0, 1)`` with ``a ~ U(lo, hi)`` per image."""

    def __init__(self, contrast: tuple[float, float], p: float):
        super().__init__(p=p, same_on_batch=False)
        self.contrast = contrast

    def generate_parameters(self, shape: tuple[int, ...]) -> dict[str, torch.Tensor]:
        lo, hi = self.contrast
        return {"factor": lo + (hi - lo) * torch.rand(shape[0])}

    def apply_transform(self, input, params, flags, transform=None):
        a = params["factor"].to(input).view(-1, 1, 1, 1)
        return (input - 0.5).mul_(a).add_(0.5).clamp_(0.0, 1.0)


class RandomCropResize(K.AugmentationBase2D):
    """Crop a random box keeping ``U(crop_keep)`` of each side, resize it back.

    Params: ``keep`` (b, 2) kept fraction of (height, width); ``offset`` (b, 2)
    where the box starts, as a fraction of the (height, width) left over.
    """

    def __init__(self, keep: tuple[float, float], p: float):
        super().__init__(p=p, same_on_batch=False, p_batch=1.0)
        self.keep = keep

    def generate_parameters(self, shape: tuple[int, ...]) -> dict[str, torch.Tensor]:
        lo, hi = self.keep
        return {
            "keep": lo + (hi - lo) * torch.rand(shape[0], 2),
            "offset": torch.rand(shape[0], 2),
        }

    def apply_transform(self, input, params, flags, transform=None):
        keep = params["keep"].to(input)
        centre = -1.0 + 2.0 * params["offset"].to(input) * (1.0 - keep) + keep
        theta = torch.zeros(len(input), 2, 3, dtype=input.dtype)
        theta[:, 0, 0], theta[:, 0, 2] = keep[:, 1], centre[:, 1]  # x: width
        theta[:, 1, 1], theta[:, 1, 2] = keep[:, 0], centre[:, 0]  # y: height
        grid = F.affine_grid(theta, list(input.shape), align_corners=False)
        return F.grid_sample(input, grid, padding_mode="border", align_corners=False)


def _kernel_1d(sigma: float, size: int) -> torch.Tensor:
    """Gaussian taps for a field of ``size`` samples: radius 2 sigma, < size."""
    radius = max(1, min(math.ceil(2.0 * sigma), size - 1))
    return get_gaussian_kernel1d(2 * radius + 1, sigma)


def _blur_matrix(kernel: torch.Tensor, n: int) -> torch.Tensor:
    """(n, n) matrix M with ``M @ v`` = ``v`` filtered by ``kernel`` (1, 2r + 1).

    Borders reflect without repeating the edge sample (torch's ``"reflect"``).
    A matrix product is far cheaper on CPU than a depthwise convolution for the
    small coarse fields it is used on.
    """
    radius = kernel.shape[-1] // 2
    idx = (torch.arange(n)[:, None] + torch.arange(-radius, radius + 1)).abs()
    idx = torch.where(idx > n - 1, 2 * (n - 1) - idx, idx)
    m = torch.zeros(n, n, dtype=kernel.dtype)
    return m.scatter_add_(1, idx, kernel.expand(n, -1).contiguous())


def _noise_scale(alpha: float, ky: torch.Tensor, kx: torch.Tensor) -> float:
    """Factor giving smoothed U(-1, 1) noise a root-mean-square of ``alpha``."""
    return alpha / math.sqrt(float((ky**2).sum() * (kx**2).sum()) / 3.0)


class RandomCoarseElastic(K.AugmentationBase2D):
    """Elastic transform with the displacement noise drawn on a coarse grid.

    kornia smooths full-resolution noise with a Gaussian of ``sigma_px`` pixels;
    a field that smooth is band-limited, so here the noise (params ``noise``
    (b, 2, h, w)) lives on a grid ``f = max(1, sigma_px // 2)`` times coarser, is
    smoothed with sigma ``sigma_px / f`` (2 to 4 cells; reflected borders, where
    kornia pads the noise with zeros), upsampled bilinearly to (H, W) and
    applied with ``grid_sample``, as kornia does.
    """

    def __init__(self, alpha: float, sigma: float, p: float):
        super().__init__(p=p, same_on_batch=False, p_batch=1.0)
        self.alpha, self.sigma = alpha, sigma

    def _grid(self, h: int, w: int) -> tuple[tuple[int, int], tuple[float, float]]:
        factors = [max(1, int(self.sigma * s // 2)) for s in (h, w)]
        shape = tuple(math.ceil(s / f) for s, f in zip((h, w), factors, strict=True))
        sigmas = tuple(self.sigma * s / f for s, f in zip((h, w), factors, strict=True))
        return shape, sigmas

    def generate_parameters(self, shape: tuple[int, ...]) -> dict[str, torch.Tensor]:
        (hc, wc), _ = self._grid(shape[2], shape[3])
        return {"noise": 2.0 * torch.rand(shape[0], 2, hc, wc) - 1.0}

    def apply_transform(self, input, params, flags, transform=None):
        h, w = input.shape[2:]
        (hc, wc), (sy, sx) = self._grid(h, w)
        ky, kx = _kernel_1d(sy, hc), _kernel_1d(sx, wc)
        my, mx = _blur_matrix(ky, hc).to(input), _blur_matrix(kx, wc).to(input)
        field = my @ params["noise"].to(input) @ mx.T  # separable Gaussian
        field = field * _noise_scale(self.alpha, ky, kx)
        field = F.interpolate(field, size=(h, w), mode="bilinear", align_corners=False)
        ys = torch.linspace(-1 + 1 / h, 1 - 1 / h, h, dtype=input.dtype)
        xs = torch.linspace(-1 + 1 / w, 1 - 1 / w, w, dtype=input.dtype)
        base = torch.stack(torch.meshgrid(xs, ys, indexing="xy"), dim=-1)
        grid = base + field.permute(0, 2, 3, 1)
        return F.grid_sample(
            input, grid, padding_mode="reflection", align_corners=False
        )


# -------------------------------------------------------------------- pipeline


def _make_op(name: str, config: AugmentConfig, h: int, w: int) -> K.AugmentationBase2D:
    p = config.p
    if name == "gaussian_blur":
        hi = config.blur_sigma[1]
        ks = tuple(2 * max(1, min(int(4.0 * hi + 0.5), s - 1)) + 1 for s in (h, w))
        return K.RandomGaussianBlur(ks, config.blur_sigma, border_type="reflect", p=p)
    if name == "hflip":
        return K.RandomHorizontalFlip(p=p)
    if name == "random_crop":
        return RandomCropResize(config.crop_keep, p=p)
    if name == "contrast":
        return RandomLinearContrast(config.contrast, p=p)
    if name == "invert":
        return K.RandomInvert(p=p)
    if name == "grayscale":
        return K.RandomGrayscale(p=p)
    alpha, sigma = config.elastic_alpha, config.elastic_sigma
    if config.elastic_impl == "coarse":
        return RandomCoarseElastic(alpha, sigma, p=p)
    ky, kx = _kernel_1d(sigma * h, h), _kernel_1d(sigma * w, w)
    scale = _noise_scale(alpha, ky, kx)
    return K.RandomElasticTransform(
        kernel_size=(ky.shape[-1], kx.shape[-1]),
        sigma=(sigma * h, sigma * w),
        alpha=(scale, scale),
        padding_mode="reflection",
        p=p,
    )


@functools.lru_cache(maxsize=32)
def build_pipeline(
    config: AugmentConfig, height: int, width: int
) -> tuple[K.AugmentationBase2D, ...]:
    """The kornia modules of ``config.ops`` for ``height x width`` images."""
    return tuple(_make_op(name, config, height, width) for name in config.ops)


def _check_batch(batch: torch.Tensor) -> torch.Tensor:
    if not isinstance(batch, torch.Tensor) or batch.ndim != 4 or batch.shape[1] != 3:
        shape = getattr(batch, "shape", type(batch).__name__)
        raise InputError(f"batch must be a (b, 3, H, W) torch tensor, got {shape}")
    if not batch.is_floating_point():
        raise InputError(f"batch must be float in [0, 1], got {batch.dtype}")
    return batch


def sample_params(config: AugmentConfig, shape: tuple[int, ...], seed: int) -> Params:
    """Draw every operation's parameters for a batch of ``shape`` (b, 3, H, W)."""
    ops = build_pipeline(config, int(shape[2]), int(shape[3]))
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(int(seed))
        return tuple(op.forward_parameters(torch.Size(shape)) for op in ops)


def replay(batch: torch.Tensor, config: AugmentConfig, params: Params) -> torch.Tensor:
    """Apply ``config``'s operations with previously drawn ``params``.

    Args:
      batch: float32 (b, 3, H, W) in [0, 1].
      config: the configuration the parameters were drawn for.
      params: one dict per operation, from :func:`augment` or :func:`sample_params`.

    Returns:
      float32 (b, 3, H, W), equal to the output that drew ``params``.
    """
    batch = _check_batch(batch)
    ops = build_pipeline(config, batch.shape[2], batch.shape[3])
    if len(params) != len(ops):
        raise InputError(
            f"params hold {len(params)} operations but config has {len(ops)}"
        )
    out = batch
    for op, p in zip(ops, params, strict=True):
        out = op(out, params=dict(p))
    return out


def augment(
    batch: torch.Tensor, config: AugmentConfig, seed: int
) -> tuple[torch.Tensor, Params]:
    """Augment float32 (b, 3, H, W) with ``config``; same seed, same output.

    Returns ``(out, params)``: the augmented batch and the drawn parameters,
    which :func:`replay` turns into ``out`` again.
    """
    batch = _check_batch(batch)
    params = sample_params(config, tuple(batch.shape), seed)
    return replay(batch, config, params), params


def to_batch(images: np.ndarray) -> torch.Tensor:
    """uint8 (n, H, W, 3) -> float32 (n, 3, H, W) in [0, 1]."""
    images = np.asarray(images)
    if images.dtype != np.uint8 or images.ndim != 4 or images.shape[3] != 3:
        raise InputError(
            f"images must be uint8 (n, H, W, 3), got {images.dtype} {images.shape}"
        )
    return torch.from_numpy(images).permute(0, 3, 1, 2).float().div_(255.0)


def to_images(batch: torch.Tensor) -> np.ndarray:
    """float (n, 3, H, W) in [0, 1] -> uint8 (n, H, W, 3), rounded."""
    batch = _check_batch(batch)
    out = (batch.detach().clamp(0, 1) * 255.0).round().to(torch.uint8)
    return out.permute(0, 2, 3, 1).cpu().numpy()


def epoch_order(n: int, seed: int, epoch: int, shuffle: bool = True) -> np.ndarray:
    """The (n,) order in which epoch ``epoch`` visits the frames."""
    if not shuffle:
        return np.arange(n)
    return np.random.default_rng([seed, epoch]).permutation(n)


def augmented_batch(
    images: np.ndarray,
    order: np.ndarray,
    config: AugmentConfig,
    batch_size: int,
    seed: int,
    epoch: int,
    i: int,
) -> tuple[np.ndarray, torch.Tensor]:
    """Batch ``i`` of an epoch: ``(indices (b,), augmented float32 (b, 3, H, W))``.

    ``order`` is the epoch's :func:`epoch_order`; the draws are seeded by
    ``(seed, epoch, i)``, so any batch can be made again on its own.
    """
    idx = order[i * batch_size : (i + 1) * batch_size]
    batch_seed = np.random.SeedSequence([seed, epoch, i]).generate_state(1)[0]
    out, _ = augment(to_batch(images[idx]), config, int(batch_seed))
    return idx, out


def augment_examples(
    images: np.ndarray, names: Sequence[str] = (*NAMES, "all"), seed: int = 0
) -> dict[str, np.ndarray]:
    """Each operation applied for certain to uint8 (k, H, W, 3) ``images``.

    Returns ``{"original": images, name: augmented uint8 (k, H, W, 3), ...}``,
    one row of :func:`rhythmic_jax.eval.figures.plot_examples` per name.
    """
    rows = {"original": np.asarray(images)}
    for name in names:
        out, _ = augment(to_batch(images), AugmentConfig((name,), p=1.0), seed=seed)
        rows[name] = to_images(out)
    return rows
