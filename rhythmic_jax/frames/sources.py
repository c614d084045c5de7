"""What a command-line SOURCE means: descriptor files, image folders or a tiled image.

* ``ref.npy`` (one or several, one per traversal): ready descriptors (n, d).
* a folder of images (one or several, one per condition of the same route): frames
  in natural name order, described with the chosen descriptor (default
  ``patchnorm``); several folders make a multi-exemplar map.
* one large image with ``--tile SIZE [--stride S]``: tiles in raster order are the
  places (the paper's aerial protocol).

Several sources share place labels: row i of each is place i.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.frames.compiled import AUTO, CompilePolicy
from rhythmic_jax.io.descriptor_files import read_record
from rhythmic_jax.io.vpr_files import HDF5_SUFFIXES
from rhythmic_jax.validate import check_int

if TYPE_CHECKING:
    from rhythmic_jax.frames.features import Descriptor

__all__ = [
    "Features",
    "apply_projection",
    "describe_images",
    "files_descriptor",
    "INPUT_SIZES",
    "parse_input_size",
    "size_settings",
    "size_text",
    "load_query_source",
    "load_sources",
    "reference_features",
    "source_key",
]

DEFAULT_DESCRIPTOR = "patchnorm"
NPY_DESCRIPTOR = "features"
#: Each descriptor's input (width, height) in pixels where --input-size gives none
#: (frames are resized to it; patchnorm and hog read them grey).
INPUT_SIZES = {"patchnorm": (64, 32), "hog": (64, 32),
               "efficientnet_lite0": (224, 112), "vgg16_fc7": (224, 224)}  # fmt: skip
STRIDE_NEEDS_TILE = "{opt:stride} needs {opt:tile} (it is the step between tiles)"


@dataclass(frozen=True)
class Features:
    """Descriptors ``x`` (n, d) float32 with place ``labels`` (n,) and provenance.

    ``descriptor`` and ``settings`` name what described the rows (saved with a
    map); ``describer`` is that descriptor, resolved once when the sources were
    read (None for ``.npy`` files), for whatever describes frames again.
    """

    x: np.ndarray
    labels: np.ndarray
    descriptor: str
    settings: dict
    extra: dict = field(default_factory=dict)
    images: np.ndarray | None = None  # uint8 (n, H, W, 3) for image sources
    describer: Descriptor | None = field(default=None, compare=False)


def parse_input_size(text: str | None) -> tuple[int, int] | None:
    """``"224x112"`` -> ``(224, 112)`` (width, height); None stays None."""
    if text is None:
        return None
    w, sep, h = str(text).lower().partition("x")
    if not (sep and w.isdigit() and h.isdigit() and int(w) > 0 and int(h) > 0):
        raise InputError(
            f"{{opt:input_size}} must be WIDTHxHEIGHT in pixels (224x112), got {text!r}"
        )
    return int(w), int(h)


def size_settings(size: tuple[int, int] | None) -> dict:
    """A descriptor's settings for the input ``size`` (none: its default)."""
    return {} if size is None else {"width": int(size[0]), "height": int(size[1])}


def size_text(settings: dict) -> str:
    """``"224x112"``: the input size a descriptor's settings record."""
    return f"{settings.get('width')}x{settings.get('height')}"


def same_size(size: tuple[int, int] | None, settings: dict) -> bool:
    """Whether the input ``size`` (None: any) is the one ``settings`` record."""
    return size is None or size_settings(size) == {
        "width": settings.get("width"),
        "height": settings.get("height"),
    }


def files_descriptor(paths, descriptor, weights, input_size):
    """``(name, settings, declared)`` of descriptor files: their records' (which
    must agree with each other and with ``descriptor`` and ``input_size`` where
    given), else ``descriptor``'s as declared (``declared``: that descriptor,
    resolved, to check the files' dimension), else ``features``."""
    records = [(p, read_record(p)) for p in paths if p.suffix.lower() == ".npy"]
    made = {}
    for p, r in records:
        if r is not None:
            made.setdefault(json.dumps([r["descriptor"], r["settings"]],
                                       sort_keys=True), p)  # fmt: skip
    if len(made) > 1:
        first, other = list(made.values())[:2]
        raise InputError(
            f"{first} and {other} were described differently (their records "
            "differ); describe the traversals alike"
        )
    if made:
        name, settings = json.loads(next(iter(made)))
        if descriptor is not None and descriptor != name:
            raise InputError(
                f"{next(iter(made.values()))}: described with {name} (its record "
                f"says), not {descriptor}"
            )
        if not same_size(input_size, settings):
            raise InputError(
                f"{next(iter(made.values()))}: described at {size_text(settings)}, "
                f"not {input_size[0]}x{input_size[1]} ({{opt:input_size}})"
            )
        return name, settings, None
    if descriptor is None:
        return NPY_DESCRIPTOR, {}, None
    settings = size_settings(input_size)
    if weights is not None:
        settings["weights"] = str(Path(weights).expanduser().absolute())
    declared = _resolve(descriptor, settings)
    return descriptor, declared.settings(), declared


def _kind(path: Path, tile: int | None) -> str:
    if not path.exists():
        raise InputError(f"{path}: no such file or folder")
    files = (".npy", *HDF5_SUFFIXES)  # descriptor files: numpy's, or hloc's .h5
    kind = "folder" if path.is_dir() else "npy" if path.suffix.lower() in files else ""
    if kind and tile is not None:
        what = "a folder of frames" if kind == "folder" else "a descriptor file"
        raise InputError(
            f"{path}: {{option}} cuts one large image, but this is {what}",
            option="tile",
        )
    if kind:
        return kind
    if tile is not None:
        return "image"
    raise InputError(
        f"{path}: not a .npy descriptor file or an image folder "
        "(to tile one large image, give {option} SIZE); hloc's .h5 descriptor "
        "files are read too",
        option="tile",
    )


def describe_images(
    images: np.ndarray,
    name: str,
    settings: dict,
    key: str,
    progress: bool,
    compile: CompilePolicy = AUTO,
) -> tuple[np.ndarray, dict]:
    """Describe uint8 frames (n, H, W, 3) with a registered descriptor (cached).

    ``compile``: when the descriptor's network runs compiled
    (:mod:`rhythmic_jax.frames.compiled`)."""
    desc = _resolve(name, settings)
    return _describe_images(images, desc, key, progress, compile), desc.settings()


def _describe_images(
    images: np.ndarray, desc: Descriptor, key: str, progress: bool, compile
) -> np.ndarray:
    """uint8 frames (n, H, W, 3) -> rows (n, d) of the resolved ``desc`` (cached)."""
    from rhythmic_jax.frames.features import cached_describe

    return cached_describe(images, desc, key=key, progress=progress, compile=compile)


def _describe_folder(
    path: Path, desc: Descriptor, key: str, progress, compile, keep: bool
) -> tuple[np.ndarray, np.ndarray | None]:
    """A folder of frames described as it is read: decoding and resizing run ahead
    of the network (:func:`rhythmic_jax.frames.pipeline.describe_files`), cached by the
    files' bytes. ``(x (n, d), uint8 (n, H, W, 3) when keep)``."""
    from rhythmic_jax.frames.pipeline import describe_files
    from rhythmic_jax.io.images import list_images

    files = list_images(path, "traversal")
    return describe_files(
        files, desc, key, keep_images=keep, progress=progress, policy=compile
    )


def _images(path: Path, kind: str, tile: int | None, stride: int | None, progress):
    from rhythmic_jax.io import images, tiles

    tile, stride = _tiling(tile, stride)
    return tiles.tile_image(images.read_rgb(path), tile, stride).tiles


def _tiling(tile: int, stride: int | None) -> tuple[int, int]:
    """(size, stride) of tiles; the stride defaults to half the size."""
    tile = check_int(tile, "tile", 1, msg=f"{{opt:tile}} must be >= 1, got {tile!r}")
    if stride is None:
        return tile, max(1, tile // 2)
    msg = f"{{opt:stride}} must be >= 1, got {stride!r}"
    return tile, check_int(stride, "stride", 1, msg=msg)


def _map_tiling(path: Path, model, tile, stride) -> tuple[int | None, int | None]:
    """The tiling for queries of ``model``: a map fitted on tiles of one image is
    queried with the same tiles (its own when no tile is given); another
    tiling would give places that are not the map's."""
    own = model.reference.get("tile")
    if own is None or path.is_dir() or path.suffix.lower() == ".npy":
        return tile, stride
    own = _tiling(own, model.reference.get("stride"))
    if tile is None:
        if stride is not None:
            raise InputError(STRIDE_NEEDS_TILE)
        return own
    if _tiling(tile, stride) != own:
        raise InputError(
            f"{path}: the map was fitted on {own[0]}-pixel tiles every {own[1]} "
            f"pixels, not {tile} every {_tiling(tile, stride)[1]}; give the same "
            "{opt:tile} and {opt:stride}, or neither to use the map's"
        )
    return tile, stride


def source_key(path: Path, tile=None, stride=None) -> str:
    """The descriptor cache's key of a source (a folder, video or image) cut with
    ``tile`` and ``stride``: its name and a digest of its resolved path, its
    modification time and the cut, so a changed source is described afresh."""
    stat = path.stat()
    raw = f"{path.resolve()}|{stat.st_mtime_ns}|{tile}|{stride}"
    digest = hashlib.sha1(raw.encode("utf-8", "surrogateescape")).hexdigest()
    return f"{path.name}-{digest[:12]}"


def _resolve(name: str, settings: dict) -> Descriptor:
    """The descriptor ``name`` with ``settings``: bad settings or weights end
    here, before any source is read."""
    from rhythmic_jax.frames.features import get_descriptor

    return get_descriptor(name, **settings)


def _one(
    path: Path,
    kind: str,
    desc: Descriptor | None,
    tile,
    stride,
    progress,
    compile: CompilePolicy = AUTO,
    keep: bool = True,
    select: str | None = None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """(descriptors, images or None) of one source, described with the resolved
    ``desc`` (None for ``.npy``); a folder's frames are kept only with ``keep``;
    ``select``: an hloc ``.h5``'s rows whose image names start with it."""
    from rhythmic_jax.io.vpr_files import load_descriptor_file

    if kind == "npy":
        return load_descriptor_file(path, select), None
    if select is not None:
        raise InputError(
            f"{path}: {{opt:select}} picks images of an hloc .h5 file by name; "
            "this is not one"
        )
    key = source_key(path, tile, stride)
    if kind == "folder":
        return _describe_folder(path, desc, key, progress, compile, keep)
    images = _images(path, kind, tile, stride, progress)
    return _describe_images(images, desc, key, progress, compile), images


def load_sources(
    sources: Sequence[str],
    descriptor: str | None = None,
    tile: int | None = None,
    stride: int | None = None,
    progress: bool = False,
    pca: int | None = None,
    weights: str | None = None,
    same_length: bool = True,
    compile: CompilePolicy = AUTO,
    keep_images: bool = True,
    select: str | None = None,
    input_size: tuple[int, int] | None = None,
) -> Features:
    """Reference features from one or several sources of the same kind.

    A descriptor file names what described it through its record
    (:func:`rhythmic_jax.io.descriptor_files.read_record`, written by
    ``describe``), or ``descriptor`` (with ``weights`` and ``input_size``)
    declares it for files without one; else it is ``features``, descriptors of
    unknown make. ``input_size``: (width, height) the frames are resized to for
    the descriptor (default its own, :data:`INPUT_SIZES`).

    ``same_length``: traversals must match frame for frame (row i of each is
    place i); False when places come from elsewhere (positions). ``compile``:
    when a descriptor network runs compiled; ``keep_images``: False leaves a
    folder's frames out of ``images`` (they are described as they are read);
    ``select``: the rows of hloc ``.h5`` sources whose image names start with it.

    ``pca=k`` projects the descriptors on the k leading principal axes of the
    reference set (L2-normalised after); the projection is kept in ``extra`` so
    the map saves it and queries are projected the same way.
    """
    paths = [Path(s) for s in sources]
    kinds = {_kind(p, tile) for p in paths}
    if len(kinds) > 1:
        raise InputError(f"mixed source kinds {sorted(kinds)}; give one kind at a time")
    kind = kinds.pop()
    declared = None  # the descriptor a .npy without a record is declared to hold
    if kind == "npy":
        name, settings, declared = files_descriptor(
            paths, descriptor, weights, input_size
        )
        desc = None
    else:
        name, settings = descriptor or DEFAULT_DESCRIPTOR, {}
        if weights is not None:
            settings = {"weights": str(Path(weights).expanduser().absolute())}
        desc = _resolve(name, settings | size_settings(input_size))
        settings = desc.settings()
    blocks, images = [], []
    for p in paths:
        x, imgs = _one(
            p, kind, desc, tile, stride, progress, compile, keep_images, select
        )
        blocks.append(x)
        images.append(imgs)
    n, d = blocks[0].shape
    for p, x in zip(paths, blocks, strict=True):
        if x.shape != (n, d) and (same_length or x.shape[1] != d):
            raise InputError(
                f"{p}: {x.shape[0]} frames of {x.shape[1]}-d, but {paths[0]} has "
                f"{n} of {d}-d; traversals of one route must match frame for frame"
            )
    if declared is not None and declared.dim != d:
        raise InputError(
            f"{paths[0]}: {d}-d rows, but {name} at {size_text(settings)} gives "
            f"{declared.dim}-d; {{opt:descriptor}} names what described the file"
        )
    if kind == "npy" and name == NPY_DESCRIPTOR:
        settings = {"dim": d}
    labels = np.concatenate([np.arange(len(b)) for b in blocks])
    kept = kind != "npy" and all(im is not None for im in images)
    stacked = _stack_images(paths, images) if kept else None
    x, extra = np.concatenate(blocks), {}
    if pca is not None:
        x, extra = _fit_pca(x, pca)
        settings = {**settings, "pca": int(pca)}
    return Features(
        x, labels, name, settings, extra=extra, images=stacked, describer=desc
    )


def _fit_pca(x: np.ndarray, k: int) -> tuple[np.ndarray, dict]:
    from rhythmic_jax.map.projection import fit_pca, project

    if not 1 <= k <= min(x.shape):
        raise InputError(
            f"{{option}} must lie in [1, {min(x.shape)}], got {k}", option="pca"
        )
    model = fit_pca(x, k)
    extra = {
        "pca_mean": np.asarray(model.mean),
        "pca_components": np.asarray(model.components),
    }
    return np.asarray(project(model, x, normalize=True)), extra


def apply_projection(x: np.ndarray, extra: dict) -> np.ndarray:
    """Project descriptors (n, d) with a map's saved PCA, if it has one."""
    if "pca_components" not in extra:
        return x
    from rhythmic_jax.map.projection import PCA, project

    comps = np.asarray(extra["pca_components"])
    if x.shape[1] != comps.shape[1]:
        raise InputError(
            f"{x.shape[1]}-d descriptors but the map's PCA expects {comps.shape[1]}-d"
        )
    model = PCA(np.asarray(extra["pca_mean"]), comps, np.zeros(len(comps)))
    return np.asarray(project(model, x, normalize=True))


def _stack_images(paths: list[Path], images: list[np.ndarray]) -> np.ndarray:
    shapes = {im.shape[1:] for im in images}
    if len(shapes) > 1:
        raise InputError(
            f"{paths[0]} and the other sources hold frames of different sizes "
            f"{sorted(shapes)}; resize them to one size"
        )
    return np.concatenate(images)


def load_query_source(
    source: str,
    model,
    descriptor: str | None = None,
    tile: int | None = None,
    stride: int | None = None,
    progress: bool = False,
    weights: str | None = None,
    compile: CompilePolicy = AUTO,
    select: str | None = None,
    input_size: tuple[int, int] | None = None,
) -> Features:
    """Query features described the way ``model`` (a fitted map) was built.

    ``weights``: a copy of the descriptor's weights file at another path (checked
    against the sha256 the map recorded); ``compile``: when a descriptor network
    runs compiled; ``select``: an hloc ``.h5``'s rows whose names start with it.
    A descriptor file's record (``describe``'s) must name the map's descriptor
    and input size; ``input_size``, where given, must be the map's.
    """
    path = Path(source)
    tile, stride = _map_tiling(path, model, tile, stride)
    kind = _kind(path, tile)
    name, settings = model.config.descriptor, dict(model.config.descriptor_settings)
    settings.pop("pca", None)
    if weights is not None:
        settings = _moved_weights(name, settings, weights)
    if descriptor is not None and descriptor != name:
        raise InputError(
            f"the map was built with descriptor {name!r}, not {descriptor!r}"
        )
    if kind != "npy" and name == NPY_DESCRIPTOR:
        raise InputError(
            f"{path}: the map was fitted on descriptor files that name no "
            "descriptor; give queries as .npy, or fit from files describe wrote "
            "(or with {opt:descriptor} NAME)"
        )
    _same_make(path, kind, name, settings, input_size)
    desc = None if kind == "npy" else _resolve(name, settings)
    x, _ = _one(path, kind, desc, tile, stride, progress, compile, False, select)
    if kind != "npy" or "pca_components" in model.extra and x.shape[1] != model.d:
        x = apply_projection(x, model.extra)
    if x.shape[1] != model.d:
        raise InputError(
            f"{path}: {x.shape[1]}-d features but the map was built for {model.d}-d"
        )
    return Features(x, np.arange(len(x)), name, settings, describer=desc)


def _same_make(path: Path, kind: str, name: str, settings: dict, input_size) -> None:
    """Refuse queries described otherwise than the map's frames: another input
    size given, or a descriptor file whose record names another descriptor or
    size (a map of unknown make takes any)."""
    if name == NPY_DESCRIPTOR:
        return
    size = size_text(settings)
    if not same_size(input_size, settings):
        raise InputError(
            f"{{opt:input_size}} {input_size[0]}x{input_size[1]}: the map's frames "
            f"were described at {size}; queries must be described alike"
        )
    record = read_record(path) if kind == "npy" and path.suffix == ".npy" else None
    if record is None:
        return
    if record["descriptor"] != name:
        raise InputError(
            f"{path}: described with {record['descriptor']}, the map's frames with "
            f"{name}; describe the queries alike"
        )
    if size_text(record["settings"]) != size:
        raise InputError(
            f"{path}: described at {size_text(record['settings'])}, the map's frames "
            f"at {size}; describe the queries with {{opt:input_size}} {size}"
        )


def _moved_weights(name: str, settings: dict, weights: str) -> dict:
    """The map's descriptor settings with its weights file at ``weights``."""
    if "weights" not in settings:
        raise InputError(
            f"{{opt:weights}}: the map's descriptor {name!r} takes no weights"
        )
    settings = {k: v for k, v in settings.items() if k not in _PACKAGE_KEYS}
    return settings | {"weights": str(Path(weights).expanduser().absolute())}


_PACKAGE_KEYS = ("weights_package", "weights_version")


def reference_features(
    model,
    source: str | None = None,
    descriptor: str | None = None,
    tile: int | None = None,
    stride: int | None = None,
    progress: bool = False,
    weights: str | None = None,
    compile: CompilePolicy = AUTO,
    select: str | None = None,
) -> tuple[np.ndarray | None, np.ndarray | None, str]:
    """Brute force's reference for ``model``: ``(x (m, d), labels (m,), note)``.

    ``source`` when given; else the sources the map was fitted on (the command
    line records their paths and tiling in ``model.reference``), when they are
    all still there. Otherwise ``(None, None, note)``, the note saying why.
    ``select``: the rows of an hloc ``.h5`` reference whose names start with it
    (default: the prefix the map was fitted with).
    """
    if source:
        sources = [source]
        if Path(source).suffix.lower() in HDF5_SUFFIXES:
            select = select or model.reference.get("select")
        note = f"brute force over the reference {source}"
    else:
        sources = list(model.reference.get("sources") or [])
        tile, stride = model.reference.get("tile"), model.reference.get("stride")
        select = select or model.reference.get("select")
        missing = [s for s in sources if not Path(s).exists()]
        if not sources or missing:
            why = f"{missing[0]} is gone" if missing else "the map names none"
            note = (
                "no brute-force line: the map's reference frames are not at hand "
                f"({why}); give --reference SOURCE"
            )
            return None, None, note
        note = "brute force over the map's reference " + ", ".join(sources)
    blocks = [
        load_query_source(
            s, model, descriptor, tile, stride, progress, weights, compile, select
        ).x
        for s in sources
    ]
    labels = np.concatenate([np.arange(len(b)) for b in blocks])
    return np.concatenate(blocks), labels, note
