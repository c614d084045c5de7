"""Tiles of large images and aerial pairs against slicing loops."""

from __future__ import annotations

import numpy as np
import pytest

from rhythmic_jax.errors import InputError
from rhythmic_jax.io.images import read_rgb
from rhythmic_jax.io.tiles import load_aerial_pair, load_aerial_route, tile_image


@pytest.mark.parametrize(
    ("h", "w", "size", "stride"),
    [(100, 130, 32, 16), (64, 96, 32, 32), (50, 50, 50, 7)],
)
def test_tiles_match_slicing_loop(h, w, size, stride, rgb):
    image = rgb(h, w)
    tiles = tile_image(image, size, stride)
    ref, pos = [], []
    for r in range(0, h - size + 1, stride):
        for c in range(0, w - size + 1, stride):
            ref.append(image[r : r + size, c : c + size])
            pos.append((r, c))
    np.testing.assert_array_equal(tiles.tiles, np.stack(ref))
    np.testing.assert_array_equal(tiles.positions, np.array(pos))


def test_tile_errors(rgb):
    with pytest.raises(InputError, match="does not fit"):
        tile_image(rgb(20, 40), size=32)
    with pytest.raises(InputError, match="uint8"):
        tile_image(rgb(40, 40).astype(np.float32), size=32)
    with pytest.raises(InputError, match="positive integers"):
        tile_image(rgb(40, 40), size=32, stride=0)


def test_aerial_pair_and_route(tmp_path, caplog, rgb, write_image):
    a1, b1, a2, b2 = rgb(96, 64), rgb(96, 64), rgb(64, 64), rgb(63, 64)
    for name, a, b in (("p1.png", a1, b1), ("p2.png", a2, b2)):
        write_image(tmp_path / "A", name, a)
        write_image(tmp_path / "B", name, b)
    pair = load_aerial_pair(tmp_path / "A/p1.png", tmp_path / "B/p1.png", 32, 16)
    np.testing.assert_array_equal(pair.map_tiles, tile_image(a1, 32, 16).tiles)
    np.testing.assert_array_equal(pair.query_tiles, tile_image(b1, 32, 16).tiles)
    assert len(pair) == 5 * 3
    with pytest.raises(InputError, match=r"p2\.png is 64x64 but .*p2\.png is 64x63"):
        load_aerial_pair(tmp_path / "A/p2.png", tmp_path / "B/p2.png", 32, 16)
    route = load_aerial_route(tmp_path, 32, 16, progress=False)
    assert "cropping p2.png" in caplog.text
    assert route.names == ("p1.png", "p2.png")
    assert len(route) == 15 + 2 * 3  # p2 cropped to 63 rows: 2 tile rows
    np.testing.assert_array_equal(np.bincount(route.pair_index), [15, 6])
    np.testing.assert_array_equal(route.query_tiles[15:], tile_image(b2, 32, 16).tiles)
    with pytest.raises(InputError, match="the pair must cover the same pixels"):
        load_aerial_route(tmp_path, 32, 16, crop=False, progress=False)
    (tmp_path / "B/p2.png").unlink()
    with pytest.raises(InputError, match=r"p2\.png is missing"):
        load_aerial_route(tmp_path, 32, 16, progress=False)


def test_real_aerial_routes(aerial_root):
    levir = load_aerial_route(aerial_root / "samples_LEVIR", progress=False)
    dsifn = load_aerial_route(aerial_root / "samples_DSIFN", progress=False)
    assert len(levir) == 769 and len(dsifn) == 490
    assert levir.map_tiles.shape == levir.query_tiles.shape == (769, 64, 64, 3)
    a = read_rgb(aerial_root / "samples_DSIFN/A" / dsifn.names[3])
    i = np.flatnonzero(dsifn.pair_index == 3)[10]
    r, c = dsifn.positions[i]
    np.testing.assert_array_equal(dsifn.map_tiles[i], a[r : r + 64, c : c + 64])
    rgba = aerial_root / "samples_LEVIR"
    with pytest.raises(InputError, match="test_113_0256"):
        load_aerial_pair(rgba / "A/test_113_0256.png", rgba / "B/test_113_0256.png")
