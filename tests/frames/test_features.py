"""Descriptors by name, run over frames and cached; the torch/JAX seam."""

from __future__ import annotations

import json

import jax
import numpy as np
import pytest
import torch
from skimage.transform import resize as sk_resize

from rhythmic_jax.errors import InputError
from rhythmic_jax.frames.features import (
    DESCRIPTORS,
    cache_path,
    cached_describe,
    default_cache_dir,
    describe,
    get_descriptor,
    to_jax,
)


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


def test_describe_batching_and_errors():
    images = _frames(5, 32, 64, seed=3)
    d = get_descriptor("patchnorm", width=32, height=16, patch=4)
    whole = describe(images, d, batch_size=64, progress=False)
    np.testing.assert_array_equal(
        describe(images, d, batch_size=2, progress=False), whole
    )
    np.testing.assert_array_equal(whole, d(_batch(images)).numpy())
    np.testing.assert_allclose(np.linalg.norm(whole, axis=1), 1.0, rtol=1e-5)
    assert describe(images[:0], d, progress=False).shape == (0, 512)
    with pytest.raises(InputError, match="uint8"):
        describe(images.astype(np.float32), d)
    with pytest.raises(InputError, match=r"\(n, H, W, 3\)"):
        describe(images[..., 0], d)


def test_registry():
    assert set(DESCRIPTORS) == {"efficientnet_lite0", "vgg16_fc7", "patchnorm", "hog"}
    with pytest.raises(InputError, match="known: .*efficientnet_lite0.*patchnorm"):
        get_descriptor("sift")
    with pytest.raises(InputError, match="unknown settings \\['size'\\]"):
        get_descriptor("hog", size=3)
    with pytest.raises(InputError, match="weights"):
        get_descriptor("vgg16_fc7")
    with pytest.raises(InputError, match="not found"):
        get_descriptor("vgg16_fc7", weights="/nonexistent/vgg16.pth")
    with pytest.raises(InputError, match="patch=5"):
        get_descriptor("patchnorm", patch=5)
    with pytest.raises(InputError, match="fewer cells"):
        get_descriptor("hog", pixels_per_cell=32)
    with pytest.raises(InputError, match=r"\(b, 3, H, W\)"):
        get_descriptor("hog")(torch.rand(2, 1, 32, 64))
    with pytest.raises(InputError, match="block=16"):
        get_descriptor("efficientnet_lite0", block=16)
    for name in ("efficientnet_lite0", "patchnorm", "hog"):
        d = get_descriptor(name)
        assert d.name == name
        assert json.loads(json.dumps(d.settings())) == d.settings()


def test_to_jax_shares_memory():
    t = torch.arange(24, dtype=torch.float32).reshape(4, 6)
    a = to_jax(t)
    assert isinstance(a, jax.Array) and a.shape == (4, 6)
    np.testing.assert_array_equal(np.asarray(a), t.numpy())
    assert a.unsafe_buffer_pointer() == t.data_ptr()  # zero copy on CPU
    np.testing.assert_array_equal(np.asarray(to_jax(t.T)), t.T.numpy())  # strided
    y = get_descriptor("patchnorm")(torch.rand(2, 3, 32, 64))  # an inference tensor
    np.testing.assert_array_equal(np.asarray(to_jax(y)), y.numpy())


def test_cached_describe(tmp_path, monkeypatch):
    images = _frames(4, 32, 64, seed=4)
    d = get_descriptor("patchnorm")
    first = cached_describe(images, d, "toy", cache_dir=tmp_path, progress=False)
    files = sorted(tmp_path.iterdir())
    assert len(files) == 1 and files[0].name.startswith("toy-patchnorm-")
    np.testing.assert_array_equal(first, describe(images, d, progress=False))
    # a second call reads the file: prove it by planting different values there
    np.save(files[0], np.full_like(first, 0.5))
    again = cached_describe(images, d, "toy", cache_dir=tmp_path, progress=False)
    assert np.all(again == 0.5)
    # other settings or other pixels: another file
    cached_describe(images, get_descriptor("patchnorm", patch=4), "toy", tmp_path)
    cached_describe(images[::-1], d, "toy", cache_dir=tmp_path, progress=False)
    assert len(list(tmp_path.iterdir())) == 3
    # a damaged file is recomputed and replaced; no temporary file is left
    files[0].write_bytes(b"garbage")
    fixed = cached_describe(images, d, "toy", cache_dir=tmp_path, progress=False)
    np.testing.assert_array_equal(fixed, first)
    assert not list(tmp_path.glob("*.tmp"))
    with pytest.raises(InputError, match="cache key"):
        cached_describe(images, d, "../escape", cache_dir=tmp_path)
    monkeypatch.setenv("RHYTHMIC_JAX_CACHE", str(tmp_path / "env"))
    assert default_cache_dir() == tmp_path / "env"
    assert cache_path(images, d, "toy").parent == tmp_path / "env"


@pytest.mark.slow
def test_efficientnet_recall_on_nordland(nordland_lite0):
    """Winter queries against the summer map, brute-force cosine NN: recall@1
    (exact index) about 0.48 with the block-10 map at 224x112 (the eager network,
    shared with the other tests that describe all of Nordland with it)."""
    summer, winter = nordland_lite0
    nearest = np.argmax(winter @ summer.T, axis=1)
    recall = np.mean(nearest == np.arange(len(winter)))
    assert recall >= 0.45, recall
