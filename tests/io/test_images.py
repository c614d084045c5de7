"""Image folders, Nordland and GPS places against plain references."""

from __future__ import annotations

import numpy as np
import pytest
import skimage.io
import skimage.transform
import skimage.util

from rhythmic_jax.errors import InputError
from rhythmic_jax.io.images import (
    load_route,
    load_traversal,
    natural_key,
    nordland,
    read_rgb,
)

RNG = np.random.default_rng(0)


# ------------------------------------------------------------------- traversals


def test_natural_order_and_non_images_ignored(tmp_path, rgb, write_image):
    images = {f"img{i}.png": rgb(6, 8) for i in (10, 2, 1, 33)}
    for name, image in images.items():
        write_image(tmp_path, name, image)
    (tmp_path / "notes.txt").write_text("not a frame")
    t = load_traversal(tmp_path, progress=False)
    assert t.names == ("img1.png", "img2.png", "img10.png", "img33.png")
    assert t.images.shape == (4, 6, 8, 3) and t.images.dtype == np.uint8
    for name, image in zip(t.names, t.images, strict=True):
        np.testing.assert_array_equal(image, images[name])
    assert natural_key("Img010.png") == natural_key("img10.jpg")
    assert sorted(["a10", "a9", "a100"], key=natural_key) == ["a9", "a10", "a100"]


def test_grey_rgba_and_16_bit_become_rgb(tmp_path, rgb, write_image):
    grey = RNG.integers(0, 256, (5, 7), dtype=np.uint8)
    rgba = np.dstack([rgb(5, 7), np.full((5, 7), 255, np.uint8)])
    half = rgba.copy()
    half[..., 3] = 128
    deep = (grey.astype(np.uint16) << 8) | 0x80  # 16-bit grey
    for i, image in enumerate([grey, rgba, half, deep]):
        write_image(tmp_path, f"f{i}.png", image)
    t = load_traversal(tmp_path, progress=False)
    np.testing.assert_array_equal(t.images[0], np.repeat(grey[..., None], 3, axis=2))
    np.testing.assert_array_equal(t.images[1], rgba[..., :3])
    expected = np.rint(half[..., :3] * (128 / 255)).astype(np.uint8)
    np.testing.assert_array_equal(t.images[2], expected)
    np.testing.assert_array_equal(t.images[3], t.images[0])  # top byte kept


@pytest.mark.parametrize(
    "space, name", [("CMYK", "f.jpg"), ("CMYK", "f.tif"), ("YCbCr", "f.tif"),
                    ("LAB", "f.tif")]
)  # fmt: skip
def test_other_colour_spaces_convert_as_pil_does(tmp_path, rgb, space, name):
    """A CMYK (or YCbCr, LAB) image is PIL's convert("RGB") of it, full size and
    reduced; its fourth channel is not alpha (a CMYK JPEG was read as black)."""
    from PIL import Image

    image = Image.fromarray(rgb(24, 32)).convert(space)
    path = tmp_path / name
    image.save(path)
    with Image.open(path) as im:
        assert im.mode == space
        expected = np.asarray(im.convert("RGB"))
    got = read_rgb(path)
    assert got.shape == (24, 32, 3) and got.dtype == np.uint8
    np.testing.assert_array_equal(got, expected)
    assert got.mean() > 60  # not the black of CMYK's K taken for alpha
    np.testing.assert_array_equal(read_rgb(path, at_least=(32, 24)), expected)


def test_palette_grey_alpha_bilevel_and_16_bit_modes(tmp_path, rgb):
    """P, LA, 1-bit and I;16 images against PIL's and scikit-image's conversions."""
    from PIL import Image

    colour = Image.fromarray(rgb(6, 9))
    grey = colour.convert("L")
    alpha = Image.fromarray(RNG.integers(0, 256, (6, 9), dtype=np.uint8))
    deep = RNG.integers(0, 65536, (6, 9)).astype(np.uint16)
    colour.convert("P").save(tmp_path / "p.png")
    Image.merge("LA", (grey, alpha)).save(tmp_path / "la.png")
    colour.convert("1").save(tmp_path / "b.png")
    Image.fromarray(deep).save(tmp_path / "i16.png")
    with Image.open(tmp_path / "p.png") as im:
        np.testing.assert_array_equal(
            read_rgb(tmp_path / "p.png"), np.asarray(im.convert("RGB"))
        )
    over_black = np.asarray(grey, np.float64) * np.asarray(alpha) / 255.0
    np.testing.assert_array_equal(
        read_rgb(tmp_path / "la.png"),
        np.repeat(np.rint(over_black).astype(np.uint8)[..., None], 3, axis=2),
    )
    with Image.open(tmp_path / "b.png") as im:
        assert im.mode == "1"
        bits = np.asarray(im.convert("RGB"))
    np.testing.assert_array_equal(read_rgb(tmp_path / "b.png"), bits)
    with Image.open(tmp_path / "i16.png") as im:
        assert im.mode.startswith("I")
    top = skimage.util.img_as_ubyte(skimage.io.imread(tmp_path / "i16.png"))
    np.testing.assert_array_equal(
        read_rgb(tmp_path / "i16.png"), np.repeat(top[..., None], 3, axis=2)
    )


def test_jpeg_frames_load(tmp_path, write_image):
    image = np.full((16, 16, 3), (200, 40, 90), np.uint8)
    write_image(tmp_path, "a1.jpg", image)
    write_image(tmp_path, "a2.jpeg", image)
    t = load_traversal(tmp_path, progress=False)
    assert t.images.shape == (2, 16, 16, 3)
    assert np.abs(t.images.astype(int) - image).max() <= 3  # lossy, flat colour


def test_mixed_sizes_error_or_resize(tmp_path, rgb, write_image):
    small, big = rgb(6, 8), rgb(12, 10)
    write_image(tmp_path, "f1.png", small)
    write_image(tmp_path, "f2.png", big)
    with pytest.raises(InputError, match=r"f2\.png is 10x12 but f1\.png is 8x6"):
        load_traversal(tmp_path, progress=False)
    t = load_traversal(tmp_path, size=(8, 6), progress=False)
    ref = skimage.transform.resize(
        big, (6, 8), order=1, anti_aliasing=True, preserve_range=True
    )
    np.testing.assert_array_equal(t.images[0], small)
    np.testing.assert_array_equal(t.images[1], np.rint(ref).astype(np.uint8))


def test_bad_folders_and_files(tmp_path, rgb, write_image):
    with pytest.raises(InputError, match="folder not found"):
        load_traversal(tmp_path / "nowhere", progress=False)
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="no PNG/JPG images"):
        load_traversal(tmp_path / "empty", progress=False)
    good = write_image(tmp_path / "cut", "f1.png", rgb(20, 20))
    (tmp_path / "cut" / "f2.png").write_bytes(good.read_bytes()[:60])
    with pytest.raises(InputError, match=r"cannot read image .*f2\.png"):
        load_traversal(tmp_path / "cut", progress=False)
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "x1.png").write_bytes(b"not a png at all")
    with pytest.raises(InputError, match=r"x1\.png"):
        load_traversal(tmp_path / "junk", progress=False)


@pytest.mark.parametrize(
    ("names", "message"),
    [
        (("img1.png", "img01.png"), "name the same frame"),
        (("img1.png", "IMG1.jpg"), "name the same frame"),
        (("a1.png", "b2.png"), "different naming patterns"),
        (("frame7.png", "frame7_b.png"), "different naming patterns"),
    ],
)
def test_ambiguous_names(tmp_path, names, message, rgb, write_image):
    for name in names:
        write_image(tmp_path, name, rgb(4, 4))
    with pytest.raises(InputError, match=message):
        load_traversal(tmp_path, progress=False)


def test_route_checks_counts_and_sizes(tmp_path, rgb, write_image):
    for i in range(3):
        write_image(tmp_path / "day", f"{i}.png", rgb(6, 8))
        write_image(tmp_path / "night", f"{i}.png", rgb(6, 8))
        write_image(tmp_path / "big", f"{i}.png", rgb(12, 16))
    write_image(tmp_path / "dusk", "0.png", rgb(6, 8))
    route = load_route([tmp_path / "day", tmp_path / "night"], progress=False)
    assert [len(t) for t in route] == [3, 3]
    with pytest.raises(InputError, match=r"dusk has 1 frames but .*day has 3"):
        load_route([tmp_path / "day", tmp_path / "dusk"], progress=False)
    with pytest.raises(InputError, match="pass size"):
        load_route([tmp_path / "day", tmp_path / "big"], progress=False)
    both = load_route([tmp_path / "day", tmp_path / "big"], size=(8, 6), progress=False)
    assert both[1].images.shape == (3, 6, 8, 3)


def test_nordland_frames_in_route_order(tmp_path, nordland_root):
    """A quick slice of the real set: symlinks to 25 frames, read in order."""
    sources = sorted((nordland_root / "summer").glob("*.png"))[:25]
    for src in sources[::-1]:
        (tmp_path / src.name).symlink_to(src)
    t = load_traversal(tmp_path, progress=False)
    assert t.names == tuple(p.name for p in sources)
    assert t.images.shape == (25, 32, 64, 3)
    np.testing.assert_array_equal(t.images[7], skimage.io.imread(sources[7])[..., :3])


@pytest.mark.slow
def test_nordland_both_seasons(nordland_root):
    summer, winter = nordland(nordland_root, progress=False)
    assert summer.images.shape == winter.images.shape == (3576, 32, 64, 3)
    assert summer.names == winter.names
    assert summer.names[0] == "images-00010.png"
    assert summer.names[-1] == "images-35760.png"
    assert not np.array_equal(summer.images[100], winter.images[100])
