"""Reading and resizing ahead of the network: order, bounds, errors, the cache."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from rhythmic_jax.errors import InputError
from rhythmic_jax.frames import pipeline
from rhythmic_jax.frames.features import describe, get_descriptor
from rhythmic_jax.frames.pipeline import ahead, describe_files, read_frames
from rhythmic_jax.io import images as data
from rhythmic_jax.io.images import load_traversal


def test_ahead_keeps_order_and_stays_bounded():
    made = []

    def items():
        for i in range(20):
            made.append(i)
            yield i

    got = []
    for v in ahead(items(), depth=2):
        time.sleep(0.005)  # a slow consumer: the producer must wait for it
        assert len(made) - len(got) <= 4  # queue (2) + one in hand + one made
        got.append(v)
    assert got == list(range(20))


def test_ahead_raises_at_the_failing_item_and_stops_when_closed():
    def items():
        yield 1
        yield 2
        raise InputError("bad frame x.png")

    out = []
    with pytest.raises(InputError, match="bad frame x.png"):
        for v in ahead(items()):
            out.append(v)
    assert out == [1, 2]
    before = threading.active_count()
    it = ahead(iter(range(10**6)), depth=1)
    assert next(it) == 0
    it.close()  # the background thread ends instead of making a million items
    assert threading.active_count() <= before


def _folder(tmp_path, rgb, write_image, n=7, size=(24, 40)):
    folder = tmp_path / "frames"
    for i in range(n):
        write_image(folder, f"img{i}.png", rgb(*size))
    return folder, data.list_images(folder, "traversal")


def test_read_frames_equals_load_traversal(tmp_path, rgb, write_image):
    folder, files = _folder(tmp_path, rgb, write_image)
    chunks = list(read_frames(files, batch_size=3))
    assert [len(c) for c in chunks] == [3, 3, 1]
    np.testing.assert_array_equal(
        np.concatenate(chunks), load_traversal(folder, progress=False).images
    )


def test_read_frames_names_the_bad_file(tmp_path, rgb, write_image):
    folder, _ = _folder(tmp_path, rgb, write_image, n=3)
    write_image(folder, "img5.png", rgb(30, 20))
    (folder / "img4.png").write_bytes(b"not an image")
    files = data.list_images(folder, "traversal")
    with pytest.raises(InputError, match=r"cannot read image .*img4\.png"):
        list(read_frames(files, batch_size=2))
    (folder / "img4.png").unlink()
    files = data.list_images(folder, "traversal")
    with pytest.raises(InputError, match=r"img5\.png is 20x30 but img0\.png is 40x24"):
        list(read_frames(files, batch_size=2))


def test_describe_files_equals_describe_and_uses_the_cache(
    tmp_path, rgb, write_image, monkeypatch
):
    folder, files = _folder(tmp_path, rgb, write_image)
    desc = get_descriptor("patchnorm", width=16, height=8, patch=4)
    images = load_traversal(folder, progress=False).images
    cache = tmp_path / "cache"
    x, kept = describe_files(files, desc, "k", keep_images=True, cache_dir=cache)
    np.testing.assert_allclose(x, describe(images, desc, progress=False), atol=1e-6)
    np.testing.assert_array_equal(kept, images)
    assert len(list(cache.glob("k-patchnorm-files-*.npy"))) == 1

    def no_reading(path):
        raise AssertionError(f"read {path} despite the cache")

    monkeypatch.setattr(data, "read_rgb", no_reading)
    again, none = describe_files(files, desc, "k", batch_size=2, cache_dir=cache)
    np.testing.assert_array_equal(again, x)
    assert none is None
    (files[0]).write_bytes((files[1]).read_bytes())  # new contents: recomputed
    monkeypatch.undo()
    fresh, _ = describe_files(files, desc, "k", cache_dir=cache)
    np.testing.assert_array_equal(fresh[0], fresh[1])
    assert len(list(cache.glob("k-patchnorm-files-*.npy"))) == 2


def test_describe_chunks_counts_frames():
    desc = get_descriptor("patchnorm", width=16, height=8, patch=4)
    chunk = np.zeros((2, 8, 16, 3), np.uint8)
    with pytest.raises(InputError, match="more than the 1 frames announced"):
        pipeline.describe_chunks(iter([chunk]), 1, desc)
    with pytest.raises(InputError, match="2 frames described, 3 announced"):
        pipeline.describe_chunks(iter([chunk]), 3, desc)


def test_frames_larger_than_the_network_input_shrink_in_uint8_as_the_float_resize():
    """A network's frames are shrunk to its input size in uint8 before the
    float conversion: the float resize's values to within one level (1/255);
    frames no larger than the input, and descriptors without a network, are
    left to the descriptor's own resize."""
    import torch

    from rhythmic_jax.frames.features import resize

    rng = np.random.default_rng(0)
    smooth = rng.integers(0, 256, (3, 40, 80, 3)).astype(np.float32)
    chunk = np.clip(smooth, 0, 255).astype(np.uint8)
    got = pipeline._to_batch(chunk, (14, 28))
    assert got.shape == (3, 3, 14, 28) and got.dtype == torch.float32
    want = resize(pipeline._to_batch(chunk), 14, 28)
    err = (got - want).abs()  # torch's uint8 kernel: fixed-point weights, rounded
    assert float(err.max()) <= 1.0 / 255 and float(err.mean()) <= 0.3 / 255
    same = pipeline._to_batch(chunk, (80, 160))  # upsampling: untouched
    np.testing.assert_array_equal(same.numpy(), pipeline._to_batch(chunk).numpy())
    assert pipeline._network_size(get_descriptor("efficientnet_lite0")) == (112, 224)
    assert pipeline._network_size(get_descriptor("patchnorm")) is None


def _smooth_jpeg(folder, name, h=320, w=640, seed=0):
    """A smooth photo-like frame (low frequencies, an edge) saved as JPEG."""
    from PIL import Image

    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w] / max(h, w)
    image = np.zeros((h, w, 3))
    for c in range(3):
        for _ in range(4):
            fy, fx, ph = rng.uniform(0.5, 6, 2).tolist() + [rng.uniform(0, 6)]
            image[..., c] += np.sin(2 * np.pi * (fy * yy + fx * xx) + ph)
    image[:, w // 3 : w // 2] += 1.5  # an edge
    image = np.clip(127 + 40 * image, 0, 255).astype(np.uint8)
    folder.mkdir(parents=True, exist_ok=True)
    Image.fromarray(image).save(folder / name, quality=90)
    return folder / name


def test_jpegs_decode_at_a_reduced_scale_close_to_the_full_decode(tmp_path, rgb):
    """A JPEG read for a 224x112 network decodes at half scale (320x160 of
    640x320), and once shrunk to the network's input it is close to the full
    decode's shrink: 0.5 levels on average, 3 at the 99.9th percentile (the
    chroma of a sharp saturated edge moves most); PNGs and small JPEGs are read
    in full."""
    import skimage.io

    files = [_smooth_jpeg(tmp_path / "f", f"img{i}.jpg", seed=i) for i in range(3)]
    reduced = data.read_rgb(files[0], at_least=(224, 112))
    full = data.read_rgb(files[0])
    assert full.shape == (320, 640, 3) and reduced.shape == (160, 320, 3)
    assert data.read_rgb(files[0], at_least=(400, 112)).shape == full.shape
    chunks = np.concatenate(list(read_frames(files, 2, at_least=(224, 112))))
    assert chunks.shape == (3, 160, 320, 3)
    wholes = np.stack([data.read_rgb(f) for f in files])
    a = pipeline._to_batch(chunks, (112, 224)).numpy() * 255
    b = pipeline._to_batch(wholes, (112, 224)).numpy() * 255
    diff = np.abs(a - b)  # here 0.31 on average, 2 at the 99.9th percentile, 7 at most
    assert diff.mean() <= 0.5 and np.percentile(diff, 99.9) <= 3 and diff.max() <= 10
    png = tmp_path / "p.png"
    skimage.io.imsave(png, rgb(320, 640), check_contrast=False)
    assert data.read_rgb(png, at_least=(224, 112)).shape == (320, 640, 3)
    bad = tmp_path / "bad.jpg"
    bad.write_bytes(files[0].read_bytes()[:600])  # truncated
    with pytest.raises(InputError, match=r"cannot read image .*bad\.jpg"):
        data.read_rgb(bad, at_least=(224, 112))
