"""Datasets: image-folder traversals, aerial tiles, GPS places, descriptor files.

Image convention: frames from disk are ``uint8`` arrays of shape ``(n, H, W, 3)``
(RGB). A *traversal* is one folder of frames of a route under one condition
(season, time of day); sorted by name (natural order, so ``img2 < img10``) the
frames are the route in order, and the same index is the same place in every
condition of that route (the paper's Nordland protocol).

The paper's other two protocols are here as well: "Aerial Brisbane" cuts a map
image into ``224 x 224`` tiles with a 112-pixel stride (one tile = one place) and
queries with the tiles of an image of the same ground taken at another date;
RobotCar groups GPS positions into places with k-means on normalised
coordinates.
"""

from __future__ import annotations

import logging
import os
import re
import tempfile
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import skimage.io
import skimage.transform
import skimage.util
from sklearn.cluster import KMeans
from threadpoolctl import threadpool_limits
from tqdm.auto import tqdm

from rhythmic_jax.errors import InputError

__all__ = [
    "AerialRoute",
    "Tiles",
    "Traversal",
    "descriptor_shape",
    "gps_places",
    "load_aerial_pair",
    "load_aerial_route",
    "load_descriptors",
    "load_route",
    "load_traversal",
    "natural_key",
    "nordland",
    "read_rgb",
    "save_descriptors",
    "tile_image",
]

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


# ----------------------------------------------------------------- image folders


@dataclass(frozen=True, eq=False)
class Traversal:
    """One pass along a route: ``images`` uint8 (n, H, W, 3), ``names`` (n,)."""

    images: np.ndarray
    names: tuple[str, ...]
    root: Path

    def __len__(self) -> int:
        return len(self.names)


def natural_key(name: str) -> tuple[tuple[str, ...], tuple[int, ...]]:
    """Sort key of a file name: its stem with digit runs read as integers.

    ``"Img010.png"`` and ``"img10.jpg"`` have the same key (case, zero padding and
    suffix are normalised away); the key is ``(text parts, numbers)``.
    """
    parts = re.split(r"(\d+)", Path(name).stem.lower())
    return tuple(parts[0::2]), tuple(int(p) for p in parts[1::2])


def _list_images(folder: Path, what: str, one_pattern: bool = True) -> list[Path]:
    """Image files of ``folder`` in natural order, no two with the same key.

    With ``one_pattern`` all names must share their text parts (``img#.png``):
    frames named after different patterns have no order along a route.
    """
    if not folder.is_dir():
        raise InputError(f"{what} folder not found: {folder}")
    files = [
        p
        for p in folder.iterdir()
        if p.is_file()
        and not p.name.startswith(".")
        and p.suffix.lower() in IMAGE_SUFFIXES
    ]
    if not files:
        raise InputError(f"no PNG/JPG images in {what} folder {folder}")
    seen: dict[tuple, Path] = {}
    for p in files:
        key = natural_key(p.name)
        if key in seen:
            raise InputError(
                f"{seen[key].name!r} and {p.name!r} in {folder} name the same frame "
                "(names equal after ignoring case, zero padding and suffix)"
            )
        seen[key] = p
    files.sort(key=lambda p: natural_key(p.name))
    first = natural_key(files[0].name)[0]
    for p in files[1:] if one_pattern else ():
        if natural_key(p.name)[0] != first:
            raise InputError(
                f"cannot order the frames of {folder}: {files[0].name!r} and "
                f"{p.name!r} follow different naming patterns"
            )
    return files


def read_rgb(path: str | os.PathLike) -> np.ndarray:
    """Read one image as uint8 (H, W, 3) RGB.

    Grey images are repeated to three channels; an alpha channel is composited
    over black (``rgb * alpha / 255``; opaque pixels are unchanged). 16-bit and
    float images are rescaled to ``0..255``.
    """
    path = Path(path)
    try:
        image = np.asarray(skimage.io.imread(path))
    except Exception as exc:  # truncated, corrupt or not an image at all
        reason = str(exc)
        if "Could not find a backend" in reason:  # imageio adds pip advice
            reason = "no image reader recognises its contents"
        raise InputError(f"cannot read image {path}: {reason}") from exc
    if image.ndim == 2:
        image = image[:, :, None]
    if image.ndim != 3 or image.shape[2] not in (1, 2, 3, 4) or image.size == 0:
        raise InputError(f"image {path} has unsupported shape {image.shape}")
    if image.dtype != np.uint8:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                image = skimage.util.img_as_ubyte(image)
        except ValueError as exc:
            raise InputError(
                f"image {path} has unsupported dtype {image.dtype}"
            ) from exc
    channels = image.shape[2]
    if channels in (2, 4):  # colour + alpha: composite over black
        alpha = image[:, :, -1:].astype(np.float32) / 255.0
        colour = image[:, :, :-1].astype(np.float32) * alpha
        image = np.clip(np.rint(colour), 0, 255).astype(np.uint8)
    if image.shape[2] == 1:
        image = np.repeat(image, 3, axis=2)
    return np.ascontiguousarray(image)


def _resize(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Resize uint8 (H, W, 3) to ``size = (w, h)`` with anti-aliasing."""
    w, h = size
    if image.shape[:2] == (h, w):
        return image
    out = skimage.transform.resize(
        image, (h, w), order=1, anti_aliasing=True, preserve_range=True
    )
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def _check_size(size: tuple[int, int] | None) -> tuple[int, int] | None:
    if size is None:
        return None
    if len(size) != 2 or any(int(s) != s or s < 1 for s in size):
        raise InputError(f"size must be (width, height) positive integers, got {size}")
    return int(size[0]), int(size[1])


def load_traversal(
    folder: str | os.PathLike,
    size: tuple[int, int] | None = None,
    progress: bool = True,
) -> Traversal:
    """Load one folder of frames as a :class:`Traversal`, in natural name order.

    Args:
      folder: a folder of PNG/JPG frames (other files are ignored).
      size: ``(w, h)`` to resize every frame to (scikit-image, anti-aliased);
        without it all frames must share one size.
      progress: show a progress bar.

    Returns:
      ``Traversal`` with ``images`` uint8 (n, H, W, 3) and the file ``names``.
    """
    folder = Path(folder)
    size = _check_size(size)
    files = _list_images(folder, "traversal")
    images = None
    for i, path in enumerate(tqdm(files, desc=folder.name, disable=not progress)):
        image = read_rgb(path)
        if size is not None:
            image = _resize(image, size)
        if images is None:
            images = np.empty((len(files),) + image.shape, np.uint8)
        elif image.shape != images.shape[1:]:
            h, w = image.shape[:2]
            h0, w0 = images.shape[1:3]
            raise InputError(
                f"frame {path} is {w}x{h} but {files[0].name} is {w0}x{h0}; "
                "pass size=(w, h) to resize"
            )
        images[i] = image
    return Traversal(images=images, names=tuple(p.name for p in files), root=folder)


def load_route(
    folders: Sequence[str | os.PathLike],
    size: tuple[int, int] | None = None,
    progress: bool = True,
) -> list[Traversal]:
    """Several conditions of one route; index i is the same place in each.

    Every folder must hold the same number of frames of the same size.
    """
    if len(folders) == 0:
        raise InputError("load_route needs at least one folder")
    route = [load_traversal(f, size=size, progress=progress) for f in folders]
    first = route[0]
    for t in route[1:]:
        if len(t) != len(first):
            raise InputError(
                f"condition {t.root} has {len(t)} frames but {first.root} has "
                f"{len(first)}; every condition must cover the same places"
            )
        if t.images.shape[1:] != first.images.shape[1:]:
            raise InputError(
                f"frames of {t.root} are {t.images.shape[1:3]} (H, W) but those of "
                f"{first.root} are {first.images.shape[1:3]}; pass size=(w, h)"
            )
    return route


def nordland(
    root: str | os.PathLike,
    seasons: Sequence[str] = ("summer", "winter"),
    progress: bool = True,
) -> list[Traversal]:
    """The Nordland traversals ``root/<season>`` (e.g. ``shared/data/nordland_64x32``).

    Returns one :class:`Traversal` per season, in the order of ``seasons``; the
    64x32 set has 3576 frames per season, the same name being the same place.
    """
    return load_route([Path(root) / s for s in seasons], progress=progress)


# ------------------------------------------------------------------ aerial tiles


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
    if int(size) != size or int(stride) != stride or size < 1 or stride < 1:
        raise InputError(f"size and stride must be positive integers: {size}, {stride}")
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
    progress: bool = True,
) -> AerialRoute:
    """Every pair ``folder/A/<name>``, ``folder/B/<name>`` tiled into one route.

    Pairs are taken in natural name order and their tiles concatenated: A tiles
    are the map, B tiles the queries. A pair whose images differ in shape is
    cropped to the common top-left region with a logged warning (``crop=True``)
    or raises. With the defaults ``aerial_pairs/samples_LEVIR`` gives 769
    places (its 768x384 pair differs by one row) and ``samples_DSIFN`` 490.
    """
    folder = Path(folder)
    files_a = _list_images(folder / "A", "aerial A", one_pattern=False)
    names_b = {p.name for p in _list_images(folder / "B", "aerial B", False)}
    missing = [p.name for p in files_a if p.name not in names_b]
    if missing:
        raise InputError(f"{folder / 'B' / missing[0]} is missing (it is in A)")
    pairs = [
        _pair_tiles(path, folder / "B" / path.name, size, stride, crop)
        for path in tqdm(files_a, desc=folder.name, disable=not progress)
    ]
    index = [np.full(len(a.tiles), i, np.int64) for i, (a, _) in enumerate(pairs)]
    return AerialRoute(
        map_tiles=np.concatenate([a.tiles for a, _ in pairs]),
        query_tiles=np.concatenate([b.tiles for _, b in pairs]),
        positions=np.concatenate([a.positions for a, _ in pairs]),
        pair_index=np.concatenate(index),
        names=tuple(p.name for p in files_a),
    )


# -------------------------------------------------------------------- GPS places


def gps_places(coords: np.ndarray, k: int, seed: int = 0) -> np.ndarray:
    """Group GPS positions into ``k`` places (the paper's RobotCar protocol).

    k-means (scikit-learn, ``n_init=10``) on coordinates normalised to zero mean
    and unit variance per axis; labels are renumbered in route order, so place 0
    holds the first frame and a new place number appears the first time the
    sequence enters that place.

    Args:
      coords: float (n, 2) positions along the sequence (e.g. northing, easting).
      k: number of places, ``1 <= k <= n``.
      seed: k-means random state.

    Returns:
      int64 (n,) place label per frame.
    """
    coords = np.asarray(coords, dtype=np.float64)
    if coords.ndim != 2 or coords.shape[1] != 2 or len(coords) == 0:
        raise InputError(f"coords must have shape (n, 2), got {coords.shape}")
    bad = np.flatnonzero(~np.isfinite(coords).all(axis=1))
    if bad.size:
        raise InputError(f"coords row {bad[0]} is not finite: {coords[bad[0]]}")
    if int(k) != k or not 1 <= k <= len(coords):
        raise InputError(f"k must be an integer in [1, {len(coords)}], got {k}")
    std = coords.std(axis=0)
    z = (coords - coords.mean(axis=0)) / np.where(std > 0, std, 1.0)
    kmeans = KMeans(n_clusters=int(k), n_init=10, random_state=seed)
    with threadpool_limits(limits=1):  # small 2-D problem: threads only add waiting
        labels = kmeans.fit_predict(z)
    _, first = np.unique(labels, return_index=True)
    rank = np.empty(int(labels.max()) + 1, np.int64)
    rank[labels[np.sort(first)]] = np.arange(len(first))
    return rank[labels]


# -------------------------------------------------------------- descriptor files


def _check_descriptors(x: np.ndarray, where: str) -> np.ndarray:
    if x.dtype.kind not in "fiu":
        raise InputError(f"{where} has dtype {x.dtype}; expected a real number array")
    if x.ndim != 2 or x.shape[0] == 0 or x.shape[1] == 0:
        raise InputError(f"{where} must be a non-empty (n, d) array, got {x.shape}")
    with np.errstate(over="ignore"):  # too large for float32 -> inf, reported below
        x = np.asarray(x, dtype=np.float32)
    bad = np.flatnonzero(~np.isfinite(x).all(axis=1))
    if bad.size:
        raise InputError(f"{where} row {bad[0]} holds NaN or inf (as float32)")
    return x


def descriptor_shape(path: str | os.PathLike) -> tuple[int, ...]:
    """The shape a ``.npy`` descriptor file declares, read from its header only.

    Refuses (:class:`InputError`) a file that is missing, not ``.npy``, not a
    valid header, or of Python objects; nothing is unpickled and no data is read.
    """
    path = Path(path)
    if path.suffix.lower() != ".npy":
        raise InputError(f"descriptor file must be .npy, got {path}")
    if not path.is_file():
        raise InputError(f"descriptor file not found: {path}")
    with open(path, "rb") as f:
        head = f.read(6)
        if head[:1] == b"\x80":
            raise InputError(f"{path} contains Python objects; refusing to unpickle")
        f.seek(0)
        try:
            version = np.lib.format.read_magic(f)
            if version == (1, 0):
                header = np.lib.format.read_array_header_1_0(f)
            else:
                header = np.lib.format.read_array_header_2_0(f)
        except Exception as exc:
            raise InputError(f"{path} is not a valid .npy file: {exc}") from exc
    if header[2].hasobject:
        raise InputError(f"{path} contains Python objects; refusing to unpickle")
    return tuple(int(k) for k in header[0])


def load_descriptors(path: str | os.PathLike) -> np.ndarray:
    """Read a float32 (n, d) descriptor matrix from a ``.npy`` file.

    Nothing is unpickled (``allow_pickle=False``); the array must be 2-D,
    non-empty, numeric and finite.
    """
    descriptor_shape(path)  # the header's checks, before any data is read
    try:
        x = np.load(path, allow_pickle=False)
    except Exception as exc:  # truncated data after a valid header
        raise InputError(f"{path} is not a valid .npy file: {exc}") from exc
    return _check_descriptors(x, str(path))


def save_descriptors(path: str | os.PathLike, x: np.ndarray) -> None:
    """Write float32 (n, d) ``x`` to ``path`` (.npy) atomically (temp + rename)."""
    path = Path(path)
    if path.suffix.lower() != ".npy":
        raise InputError(f"descriptor file must be .npy, got {path}")
    x = _check_descriptors(np.asarray(x), "descriptors")
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            np.save(f, x, allow_pickle=False)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
