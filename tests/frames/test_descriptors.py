"""Descriptors against scikit-image, kornia and brute-force loops."""

from __future__ import annotations

import kornia
import numpy as np
import pytest
import torch
from skimage.feature import hog
from skimage.transform import resize as sk_resize

from rhythmic_jax.frames.descriptors import grey, resize
from rhythmic_jax.frames.features import describe, get_descriptor
from rhythmic_jax.frames.nets import load_efficientnet_lite0


@pytest.fixture(autouse=True)
def one_thread():
    """Leave the second core to the other tests running beside these."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def _frames(n: int, h: int, w: int, seed: int = 0) -> np.ndarray:
    """Smooth random uint8 RGB frames (n, h, w, 3) with some texture."""
    rng = np.random.default_rng(seed)
    small = rng.uniform(0, 255, size=(n, h // 4 + 1, w // 4 + 1, 3))
    big = np.stack([sk_resize(s, (h, w), order=1) for s in small])
    return np.clip(big + rng.normal(0, 12, big.shape), 0, 255).astype(np.uint8)


def _batch(images: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(images).permute(0, 3, 1, 2).float() / 255.0


def test_resize_upsampling_matches_skimage():
    img = np.random.default_rng(0).uniform(size=(32, 64)).astype(np.float32)
    ours = resize(torch.from_numpy(img)[None, None], 112, 224)[0, 0].numpy()
    ref = sk_resize(img, (112, 224), order=1, mode="edge", anti_aliasing=False)
    np.testing.assert_allclose(ours, ref, atol=1e-5)


def test_grey_matches_kornia():
    x = torch.rand(3, 3, 8, 10)
    torch.testing.assert_close(grey(x), kornia.color.rgb_to_grayscale(x))


def _patchnorm_loop(g: np.ndarray, p: int) -> np.ndarray:
    """SeqSLAM patch normalisation of one grey image, patch by patch."""
    out = np.zeros_like(g, dtype=np.float64)
    for y in range(0, g.shape[0], p):
        for x in range(0, g.shape[1], p):
            tile = g[y : y + p, x : x + p].astype(np.float64)
            if tile.std() > 1e-6:
                out[y : y + p, x : x + p] = (tile - tile.mean()) / tile.std()
    v = out.ravel()
    return v / max(np.linalg.norm(v), 1e-12)


def test_patchnorm_matches_loop():
    images = _frames(3, 32, 64)
    images[1, :8, :8] = 77  # one flat patch: zeros, not NaN
    d = get_descriptor("patchnorm")
    ours = describe(images, d, progress=False)
    assert ours.shape == (3, d.dim) == (3, 2048)
    for im, row in zip(images, ours, strict=True):
        g = im.astype(np.float64) @ np.array([0.299, 0.587, 0.114]) / 255.0
        np.testing.assert_allclose(row, _patchnorm_loop(g, 8), atol=1e-5)
    assert np.all(ours[1].reshape(32, 64)[:8, :8] == 0)


def test_hog_matches_skimage():
    images = _frames(2, 32, 64, seed=1)
    for settings in [{}, {"orientations": 6, "pixels_per_cell": 4}]:
        d = get_descriptor("hog", **settings)
        ours = describe(images, d, progress=False)
        assert ours.shape == (2, d.dim)
        for im, row in zip(images, ours, strict=True):
            g = im.astype(np.float64) @ np.array([0.299, 0.587, 0.114]) / 255.0
            c = d.pixels_per_cell
            ref = hog(g, d.orientations, (c, c), (d.cells_per_block,) * 2)
            np.testing.assert_allclose(row, ref / np.linalg.norm(ref), atol=1e-4)


def test_efficientnet_map_is_the_flattened_tap():
    d = get_descriptor("efficientnet_lite0")
    assert d.dim == 112 * 7 * 14 == 10976
    assert get_descriptor("efficientnet_lite0", height=224).dim == 112 * 14 * 14
    images = _frames(2, 32, 64, seed=2)
    ours = describe(images, d, progress=False)
    net = load_efficientnet_lite0()
    with torch.inference_mode():
        x = torch.nn.functional.interpolate(
            _batch(images), (112, 224), mode="bilinear", align_corners=False
        )
        tap = net.features(x, 10).permute(0, 2, 3, 1).reshape(2, -1).numpy()
    ref = tap / np.linalg.norm(tap, axis=1, keepdims=True)
    np.testing.assert_allclose(ours, ref, atol=1e-5)
    # any input size is resized to the descriptor's own: a 2x larger frame that
    # shrinks back to the same pixels gives nearly the same vector
    big = np.repeat(np.repeat(images, 2, axis=1), 2, axis=2)
    np.testing.assert_allclose(describe(big, d, progress=False), ours, atol=0.02)

