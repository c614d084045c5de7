"""The aerial protocol: large images cut into overlapping tiles, one tile a place.

"Aerial Brisbane" in the paper cuts a map image into ``224 x 224`` tiles with a
112-pixel stride and queries with the tiles of an image of the same ground taken
at another date. :func:`tile_image` cuts one image in raster order;
:func:`load_aerial_pair` and :func:`load_aerial_route` pair the tiles of
co-registered images (``A/<name>`` is the map, ``B/<name>`` the queries).
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import skimage.util

from rhythmic_jax.errors import InputError
from rhythmic_jax.io.images import list_images, read_rgb
from rhythmic_jax.io.reader import inside
from rhythmic_jax.progress import bar
from rhythmic_jax.validate import check_int

__all__ = [
    "AerialRoute",
    "Tiles",
    "load_aerial_pair",
    "load_aerial_route",
    "tile_image",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class Tiles:
    """``tiles`` uint8 (n, size, size, 3); ``positions`` int64 (n, 2) top-left."""

    tiles: np.ndarray
    positions: np.ndarray


def tile_image(image: np.ndarray, size: int = 224, stride: int = 112) -> Tiles:
    """Cut uint8 (H, W, 3) into ``size x size`` tiles every ``stride`` pixels.

    Tiles come in raster order (row by row); a tile that would cross the right or
    bottom edge is dropped, giving ``((H - size) // stride + 1) *
    ((W - size) // stride + 1)`` tiles (the paper: 224 / 112 on Aerial Brisbane).
    """
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise InputError(
            f"image must be uint8 (H, W, 3), got {image.dtype} {image.shape}"
        )
    msg = f"size and stride must be positive integers: {size}, {stride}"
    size, stride = (
        check_int(size, "size", 1, msg=msg),
        check_int(stride, "stride", 1, msg=msg),
    )
    h, w = image.shape[:2]
    if size > h or size > w:
        raise InputError(f"tile size {size} does not fit in a {w}x{h} image")
    windows = skimage.util.view_as_windows(image, (size, size, 3), step=stride)
    rows, cols = windows.shape[:2]
    tiles = np.ascontiguousarray(windows.reshape(rows * cols, size, size, 3))
    r, c = np.meshgrid(
        np.arange(rows) * stride, np.arange(cols) * stride, indexing="ij"
    )
    positions = np.stack([r.ravel(), c.ravel()], axis=1).astype(np.int64)
    return Tiles(tiles=tiles, positions=positions)


@dataclass(frozen=True, eq=False)
class AerialRoute:
    """Places cut from co-registered image pairs; tile i is place i in both.

    ``map_tiles`` (from A) and ``query_tiles`` (from B) are uint8
    (n, size, size, 3); ``positions`` int64 (n, 2) is the tile's top-left
    (row, col) in its image; ``pair_index`` int64 (n,) indexes ``names``.
    """

    map_tiles: np.ndarray
    query_tiles: np.ndarray
    positions: np.ndarray
    pair_index: np.ndarray
    names: tuple[str, ...]

    def __len__(self) -> int:
        return len(self.positions)


def _pair_tiles(a_path: Path, b_path: Path, size: int, stride: int, crop: bool):
    """Tiles of A and of B (see :func:`load_aerial_route` for ``crop``)."""
    a, b = read_rgb(a_path), read_rgb(b_path)
    if a.shape != b.shape:
        if not crop:
            raise InputError(
                f"{a_path} is {a.shape[1]}x{a.shape[0]} but {b_path} is "
                f"{b.shape[1]}x{b.shape[0]}; the pair must cover the same pixels"
            )
        log.warning("cropping %s: A is %s, B is %s", a_path.name, a.shape, b.shape)
        h, w = min(a.shape[0], b.shape[0]), min(a.shape[1], b.shape[1])
        a, b = a[:h, :w], b[:h, :w]
    return tile_image(a, size, stride), tile_image(b, size, stride)


def load_aerial_pair(
    path_a: str | os.PathLike,
    path_b: str | os.PathLike,
    size: int = 224,
    stride: int = 112,
) -> AerialRoute:
    """Map tiles from image A, query tiles from image B of the same ground.

    Both images must have the same shape; tile i of A and tile i of B cover the
    same pixels (see :func:`tile_image`).
    """
    path_a, path_b = Path(path_a), Path(path_b)
    a, b = _pair_tiles(path_a, path_b, size, stride, crop=False)
    index = np.zeros(len(a.tiles), np.int64)
    return AerialRoute(a.tiles, b.tiles, a.positions, index, (path_a.name,))


def load_aerial_route(
    folder: str | os.PathLike,
    size: int = 64,
    stride: int = 32,
    crop: bool = True,
    progress: bool = False,
) -> AerialRoute:
    """Every pair ``folder/A/<name>``, ``folder/B/<name>`` tiled into one route.

    Pairs are taken in natural name order and their tiles concatenated: A tiles
    are the map, B tiles the queries. A pair whose images differ in shape is
    cropped to the common top-left region with a logged warning (``crop=True``)
    or raises. With the defaults ``aerial_pairs/samples_LEVIR`` gives 769
    places (its 768x384 pair differs by one row) and ``samples_DSIFN`` 490.
    """
    folder = Path(folder)
    files_a = list_images(folder / "A", "aerial A", one_pattern=False)
    names_b = {p.name for p in list_images(folder / "B", "aerial B", False)}
    missing = [p.name for p in files_a if p.name not in names_b]
    if missing:
        raise InputError(f"{folder / 'B' / missing[0]} is missing (it is in A)")
    pairs = [  # A/<name> and B/<name> lie inside their folders, links followed
        _pair_tiles(
            inside(folder / "A", path.name, "image"),
            inside(folder / "B", path.name, "image"),
            size,
            stride,
            crop,
        )
        for path in bar(files_a, show=progress, desc=folder.name)
    ]
    index = [np.full(len(a.tiles), i, np.int64) for i, (a, _) in enumerate(pairs)]
    return AerialRoute(
        map_tiles=np.concatenate([a.tiles for a, _ in pairs]),
        query_tiles=np.concatenate([b.tiles for _, b in pairs]),
        positions=np.concatenate([a.positions for a, _ in pairs]),
        pair_index=np.concatenate(index),
        names=tuple(p.name for p in files_a),
    )
