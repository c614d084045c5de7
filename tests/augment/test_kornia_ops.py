"""Augmentations against scikit-image and closed forms; seeding and replay."""

from __future__ import annotations

import io

import numpy as np
import pytest
import skimage.filters
import skimage.transform
import torch
from kornia.filters import filter2d_separable

from rhythmic_jax.augment.kornia_ops import (
    NAMES,
    AugmentConfig,
    _blur_matrix,
    _kernel_1d,
    augment,
    augmented_batch,
    build_pipeline,
    epoch_order,
    replay,
    to_batch,
    to_images,
)
from rhythmic_jax.errors import InputError


def epoch_batches(images, config, batch_size, seed, epoch):
    """Every batch of one epoch, each made on its own by ``augmented_batch``."""
    order = epoch_order(len(images), seed, epoch, True)
    count = -(-len(images) // batch_size)
    return [
        augmented_batch(images, order, config, batch_size, seed, epoch, i)
        for i in range(count)
    ]


@pytest.fixture
def batch() -> torch.Tensor:
    """Six random colour images, 32 high and 48 wide, in [0, 1]."""
    g = torch.Generator().manual_seed(0)
    return torch.rand(6, 3, 32, 48, generator=g)


def _only(name: str, **kw) -> AugmentConfig:
    return AugmentConfig((name,), p=1.0, **kw)


def _hwc(x: torch.Tensor) -> np.ndarray:
    return x.permute(1, 2, 0).numpy().astype(np.float64)


def _ramp(b: int, h: int, w: int) -> torch.Tensor:
    """Channel 0 holds (x + 1) / 2, channel 1 (y + 1) / 2 at pixel centres."""
    ys, xs = (torch.arange(h) + 0.5) / h, (torch.arange(w) + 0.5) / w
    planes = [xs[None, :].expand(h, w), ys[:, None].expand(h, w), torch.zeros(h, w)]
    return torch.stack(planes)[None].repeat(b, 1, 1, 1)


def test_config_rejects_unknown_names_and_bad_ranges():
    with pytest.raises(InputError, match="known: gaussian_blur, hflip.*grayscale"):
        AugmentConfig(("gaussian_blur", "sharpen"))
    with pytest.raises(InputError, match="names are empty"):
        AugmentConfig(())
    with pytest.raises(InputError, match="p must be"):
        AugmentConfig(p=1.5)
    with pytest.raises(InputError, match="crop_keep"):
        AugmentConfig(crop_keep=(0.9, 0.8))
    with pytest.raises(InputError, match="elastic_impl"):
        AugmentConfig(elastic_impl="fast")
    assert AugmentConfig(("all",)).ops == NAMES
    listed = AugmentConfig(["hflip"], blur_sigma=[1, 2])  # lists become tuples
    assert listed == AugmentConfig(("hflip",), blur_sigma=(1.0, 2.0))
    assert hash(listed) == hash(AugmentConfig("hflip", blur_sigma=(1.0, 2.0)))
    assert AugmentConfig(("invert", "all")).ops == ("invert",) + NAMES
    assert len(build_pipeline(AugmentConfig(), 32, 48)) == 7


def test_hflip_is_torch_flip(batch):
    out, _ = augment(batch, _only("hflip"), seed=0)
    assert torch.equal(out, torch.flip(batch, dims=[-1]))


def test_invert_is_one_minus_x(batch):
    out, _ = augment(batch, _only("invert"), seed=0)
    torch.testing.assert_close(out, 1.0 - batch, rtol=0, atol=1e-7)


def test_grayscale_equal_channels_with_luma_weights(batch):
    out, _ = augment(batch, _only("grayscale"), seed=0)
    assert torch.equal(out[:, 0], out[:, 1]) and torch.equal(out[:, 1], out[:, 2])
    x = batch.numpy().astype(np.float64)
    luma = 0.299 * x[:, 0] + 0.587 * x[:, 1] + 0.114 * x[:, 2]
    np.testing.assert_allclose(out[:, 0].numpy(), luma, atol=1e-6)


def test_contrast_is_linear_about_mid_grey(batch):
    out, _ = augment(batch, _only("contrast", contrast=(1.4, 1.4)), seed=0)
    ref = np.clip(0.5 + 1.4 * (batch.numpy() - 0.5), 0.0, 1.0)
    np.testing.assert_allclose(out.numpy(), ref, atol=1e-6)
    out, params = augment(batch, _only("contrast"), seed=0)
    factor = params[0]["factor"].numpy()
    assert factor.shape == (6,) and np.all((factor >= 0.75) & (factor <= 1.5))
    ref = np.clip(0.5 + factor[:, None, None, None] * (batch.numpy() - 0.5), 0, 1)
    np.testing.assert_allclose(out.numpy(), ref, atol=1e-6)


@pytest.mark.parametrize("sigma", [0.7, 1.0, 1.6])
def test_gaussian_blur_matches_skimage(batch, sigma):
    out, params = augment(batch, _only("gaussian_blur", blur_sigma=(sigma, sigma)), 0)
    assert torch.allclose(params[0]["sigma"], torch.tensor(sigma))
    for x, y in zip(batch, out, strict=True):
        ref = skimage.filters.gaussian(
            _hwc(x), sigma=sigma, mode="mirror", truncate=4.0, channel_axis=-1
        )
        np.testing.assert_allclose(_hwc(y), ref, atol=2e-6)


def test_random_crop_matches_skimage_warp(batch):
    out, params = augment(batch, _only("random_crop", crop_keep=(0.6, 0.9)), seed=3)
    keep, offset = params[0]["keep"].numpy(), params[0]["offset"].numpy()
    assert np.all((keep >= 0.6) & (keep <= 0.9))
    h, w = batch.shape[2:]
    for x, y, (kh, kw), (oy, ox) in zip(batch, out, keep, offset, strict=True):
        top, left = oy * (1 - kh) * h, ox * (1 - kw) * w  # crop corner in pixels
        # output pixel (r, c) samples input (top + (r + .5) kh - .5, ...)
        tform = skimage.transform.AffineTransform(
            scale=(kw, kh), translation=(left + 0.5 * kw - 0.5, top + 0.5 * kh - 0.5)
        )
        ref = skimage.transform.warp(_hwc(x), tform, order=1, mode="edge")
        np.testing.assert_allclose(_hwc(y), ref, atol=1e-5)


@pytest.mark.parametrize("impl", ["kornia", "coarse"])
def test_elastic_displacement_size_and_identity(impl):
    ramp = _ramp(16, 96, 96)
    config = _only("elastic", elastic_impl=impl, elastic_alpha=0.03)
    out, _ = augment(ramp, config, seed=1)
    disp = 2.0 * (out - ramp)[:, :2, 16:-16, 16:-16]  # normalised coordinates
    rms = disp.pow(2).mean(dim=(0, 2, 3)).sqrt()
    assert torch.all((rms > 0.024) & (rms < 0.036)), rms
    # smooth field: neighbouring pixels move alike (sigma is 7.7 pixels here)
    step = (disp[..., 1:] - disp[..., :-1]).pow(2).mean().sqrt()
    assert step < 0.15 * rms.mean()
    still, _ = augment(ramp, _only("elastic", elastic_impl=impl, elastic_alpha=0.0), 1)
    torch.testing.assert_close(still, ramp, rtol=0, atol=1e-5)


@pytest.mark.parametrize(
    ("h", "w", "sigma"), [(28, 28, 2.2), (5, 9, 3.0), (7, 40, 1.0)]
)
def test_coarse_field_smoothing_matches_kornia_filter(h, w, sigma):
    noise = torch.rand(3, 2, h, w, generator=torch.Generator().manual_seed(h))
    ky, kx = _kernel_1d(sigma, h), _kernel_1d(sigma, w)
    ref = filter2d_separable(noise, kx, ky, border_type="reflect")
    out = _blur_matrix(ky, h) @ noise @ _blur_matrix(kx, w).T
    torch.testing.assert_close(out, ref, rtol=0, atol=1e-6)


@pytest.mark.parametrize("impl", ["kornia", "coarse"])
def test_all_seven_keep_shape_and_range(batch, impl):
    out, params = augment(batch, AugmentConfig(("all",), p=1.0, elastic_impl=impl), 0)
    assert out.shape == batch.shape and out.dtype == torch.float32
    assert len(params) == 7 and float(out.min()) >= 0.0 and float(out.max()) <= 1.0
    assert not torch.allclose(out, batch, atol=0.05)


def test_p_zero_is_identity_and_p_half_is_per_image(batch):
    out, _ = augment(batch, AugmentConfig(("all",), p=0.0), seed=0)
    assert torch.equal(out, batch)
    out, params = augment(batch, AugmentConfig(("invert",), p=0.5), seed=0)
    chosen = params[0]["batch_prob"] > 0.5
    assert 0 < int(chosen.sum()) < len(batch)  # with this seed some are, some not
    torch.testing.assert_close(out[chosen], 1.0 - batch[chosen], rtol=0, atol=1e-7)
    assert torch.equal(out[~chosen], batch[~chosen])


@pytest.mark.parametrize("impl", ["kornia", "coarse"])
def test_seeded_and_replayable(batch, impl):
    config = AugmentConfig(("all",), p=0.5, elastic_impl=impl)
    state = torch.get_rng_state()
    out, params = augment(batch, config, seed=7)
    assert torch.equal(torch.get_rng_state(), state)  # global RNG untouched
    again, _ = augment(batch, config, seed=7)
    assert torch.equal(out, again)
    other, _ = augment(batch, config, seed=8)
    assert not torch.allclose(out, other)
    torch.testing.assert_close(replay(batch, config, params), out, rtol=0, atol=1e-6)
    buffer = io.BytesIO()
    torch.save(params, buffer)
    buffer.seek(0)
    loaded = torch.load(buffer, weights_only=True)
    torch.testing.assert_close(replay(batch, config, loaded), out, rtol=0, atol=1e-6)
    with pytest.raises(InputError, match="params hold 6 operations"):
        replay(batch, config, params[:6])


def test_batch_conversions_and_checks():
    rng = np.random.default_rng(0)
    images = rng.integers(0, 256, (5, 8, 12, 3), dtype=np.uint8)
    batch = to_batch(images)
    assert batch.shape == (5, 3, 8, 12) and batch.dtype == torch.float32
    np.testing.assert_array_equal(
        batch[2, 1].numpy(), images[2, :, :, 1] / np.float32(255)
    )
    np.testing.assert_array_equal(to_images(batch), images)
    with pytest.raises(InputError, match="uint8"):
        to_batch(images.astype(np.float32))
    with pytest.raises(InputError, match=r"\(b, 3, H, W\)"):
        augment(torch.rand(2, 8, 12), AugmentConfig(), 0)


def test_augmented_batches_cover_images_and_are_deterministic():
    rng = np.random.default_rng(1)
    images = rng.integers(0, 256, (11, 16, 24, 3), dtype=np.uint8)
    config = AugmentConfig(("all",), p=0.5)

    def run(seed, epoch, cfg=config):
        return list(epoch_batches(images, cfg, batch_size=4, seed=seed, epoch=epoch))

    first = run(0, 0)
    assert [len(i) for i, _ in first] == [4, 4, 3]
    assert sorted(np.concatenate([i for i, _ in first])) == list(range(11))
    again = run(0, 0)
    for (i, x), (j, y) in zip(first, again, strict=True):
        assert np.array_equal(i, j) and torch.equal(x, y)
    later = run(0, 1)
    assert not all(
        torch.equal(x, y) for (_, x), (_, y) in zip(first, later, strict=True)
    )
    plain = run(0, 0, AugmentConfig(("all",), p=0.0))
    for idx, x in plain:
        assert torch.equal(x, to_batch(images[idx]))
