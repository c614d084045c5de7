"""Routes from disk: image-folder traversals and Nordland.

Image convention: frames from disk are ``uint8`` arrays of shape ``(n, H, W, 3)``
(RGB). A *traversal* is one folder of frames of a route under one condition
(season, time of day); sorted by name (natural order, so ``img2 < img10``) the
frames are the route in order, and the same index is the same place in every
condition of that route (the paper's Nordland protocol).

The RobotCar protocol's places (k-means over GPS) are
:mod:`rhythmic_jax.fitting.places`. The aerial protocol (tiles of large
images) is :mod:`rhythmic_jax.io.tiles`; descriptor files are
:mod:`rhythmic_jax.io.descriptor_files`.
"""

from __future__ import annotations

import logging
import os
import re
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.io.names import natural_sorted
from rhythmic_jax.io.reader import open_regular
from rhythmic_jax.progress import bar
from rhythmic_jax.validate import check_int

__all__ = [
    "Traversal",
    "list_images",
    "load_route",
    "load_traversal",
    "natural_key",
    "nordland",
    "read_rgb",
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


def list_images(folder: Path, what: str, one_pattern: bool = True) -> list[Path]:
    """Image files of ``folder`` in natural order, no two with the same key.

    With ``one_pattern`` all names must share their text parts (``img#.png``):
    frames named after different patterns have no order along a route. Names
    carrying positions (``@easting@northing@...``, Pittsburgh and GSV) are
    exempt: their order is by the numbers, and positions give the ground truth.
    """
    if not folder.is_dir():
        raise InputError(f"{what} folder not found: {folder}")
    try:
        entries = list(folder.iterdir())
    except OSError as err:
        raise InputError(
            f"cannot list {what} folder {folder}: {err.strerror}"
        ) from None
    files = [
        p
        for p in entries
        if not p.name.startswith(".")
        and p.suffix.lower() in IMAGE_SUFFIXES
        and not p.is_dir()
    ]
    for p in files:  # a frame left out would shift every later index
        if not p.exists():
            raise InputError(
                f"cannot read image {p}: a dangling link (to {os.readlink(p)})"
            )
        if not p.is_file():
            raise InputError(f"cannot read image {p}: not a regular file")
        if not os.access(p, os.R_OK):
            raise InputError(f"cannot read image {p}: permission denied")
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
    files = natural_sorted(files, lambda p: p.name)
    first = natural_key(files[0].name)[0]
    positioned = all(p.name.startswith("@") for p in files)  # @east@north@ names
    for p in files[1:] if one_pattern and not positioned else ():
        if natural_key(p.name)[0] != first:
            raise InputError(
                f"cannot order the frames of {folder}: {files[0].name!r} and "
                f"{p.name!r} follow different naming patterns"
            )
    return files


def _read_jpeg_reduced(fh, at_least: tuple[int, int]) -> np.ndarray | None:
    """The JPEG open as ``fh`` decoded at the smallest of libjpeg's DCT scales
    (1/2, 1/4, 1/8) still at least ``at_least`` = (width, height), as uint8 RGB;
    None for a file that is not a readable JPEG (:func:`read_rgb` then reads it)."""
    from PIL import Image

    try:
        with Image.open(fh) as im:
            if im.format != "JPEG":
                return None
            im.draft("RGB", at_least)
            return np.asarray(im.convert("RGB"))
    except Exception:  # read_rgb reads it again and names what is wrong
        return None


# colour spaces other than RGB and grey: PIL's convert("RGB") defines their RGB
# (skimage hands CMYK's four channels on as they are, the fourth then read as alpha)
_COLOUR_SPACES = frozenset({"CMYK", "YCbCr", "LAB", "HSV"})


def _read_other_colour_space(fh) -> np.ndarray | None:
    """A CMYK, YCbCr, LAB or HSV image (open as ``fh``) as PIL converts it to
    uint8 (H, W, 3) RGB; None for any other image (or a file PIL cannot open:
    skimage then reads it and names what is wrong)."""
    from PIL import Image

    try:
        with Image.open(fh) as im:
            if im.mode not in _COLOUR_SPACES:
                return None
            return np.asarray(im.convert("RGB"))
    except (OSError, ValueError, Image.DecompressionBombError):
        return None


def read_rgb(
    path: str | os.PathLike, at_least: tuple[int, int] | None = None
) -> np.ndarray:
    """Read one image as uint8 (H, W, 3) RGB.

    Grey images are repeated to three channels; CMYK, YCbCr, LAB and HSV images
    are converted as PIL's ``convert("RGB")`` defines; an alpha channel is composited
    over black (``rgb * alpha / 255``; opaque pixels are unchanged). 16-bit and
    float images are rescaled to ``0..255``.

    ``at_least`` (width, height): a JPEG larger than twice that in both sides is
    decoded at a reduced scale (libjpeg's DCT scaling, 1/2 to 1/8) that is still
    at least this size, so fewer pixels are decoded and then shrunk (the time
    saved: ``docs/performance.md``, "Performance from images"). Once the
    network's resize follows, the pixels are within 2 levels of the full
    decode's on Nordland frames (0.2 on average; a sharp saturated edge's
    chroma moves up to 7). Other files are read in full.
    """
    path = Path(path)
    try:
        fh = open_regular(path)  # a pipe or device is refused, never read
    except InputError as err:
        raise InputError(f"cannot read image {err}") from None
    with fh:
        return _read_rgb(fh, path, at_least)


def _read_rgb(fh, path: Path, at_least: tuple[int, int] | None) -> np.ndarray:
    """:func:`read_rgb` of the open file ``fh``."""
    if at_least is not None:
        image = _read_jpeg_reduced(fh, at_least)
        if image is not None:
            return image
        fh.seek(0)
    import skimage.io  # here, not at import: 0.3 s a job of JPEGs skips
    import skimage.util

    try:
        image = _read_other_colour_space(fh)
        if image is None:
            fh.seek(0)
            image = np.asarray(skimage.io.imread(fh))
    except Exception as exc:  # truncated, corrupt or not an image at all
        reason = str(exc)
        if isinstance(exc, OSError) and exc.strerror:  # missing, permission denied
            reason = exc.strerror.lower()
        elif "Could not find a backend" in reason:  # imageio adds pip advice
            reason = "no image reader recognises its contents"
        raise InputError(f"cannot read image {path}: {reason}") from None
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
    import skimage.transform

    out = skimage.transform.resize(
        image, (h, w), order=1, anti_aliasing=True, preserve_range=True
    )
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def _check_size(size: tuple[int, int] | None) -> tuple[int, int] | None:
    if size is None:
        return None
    msg = f"size must be (width, height) positive integers, got {size}"
    if len(size) != 2:
        raise InputError(msg)
    size = tuple(check_int(s, "size", 1, msg=msg) for s in size)
    return int(size[0]), int(size[1])


def load_traversal(
    folder: str | os.PathLike,
    size: tuple[int, int] | None = None,
    progress: bool = False,
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
    files = list_images(folder, "traversal")
    images = None
    for i, path in enumerate(bar(files, show=progress, desc=folder.name)):
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
    progress: bool = False,
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
    progress: bool = False,
) -> list[Traversal]:
    """The Nordland traversals ``root/<season>`` (e.g. ``shared/data/nordland_64x32``).

    Returns one :class:`Traversal` per season, in the order of ``seasons``; the
    64x32 set has 3576 frames per season, the same name being the same place.
    """
    return load_route([Path(root) / s for s in seasons], progress=progress)
