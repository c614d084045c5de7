"""A route's frames described once and kept as a descriptor file.

``rhythmic-jax describe summer/ --descriptor efficientnet_lite0 --out summer.npy``
is :func:`describe_frames`: the frames of one image folder (in natural name
order), or the tiles of one large image, described the way ``fit`` describes
them (the same descriptor, weights and cache:
:func:`rhythmic_jax.frames.sources.load_sources`) and written as one float32
``.npy`` of shape (n, d), row i = frame i, with its provenance beside it
(``summer.npy.json``: the descriptor and its settings, input size and weights'
digest among them, the frames' folder and names;
:func:`rhythmic_jax.io.descriptor_files.save_described`). ``fit``, ``query``,
``evaluate``, ``learn`` and ``frontier`` then read the file instead of the
images: a map fitted on it is the map the folder gives (same periods, same
predictions, the same descriptor recorded, so image queries, ``--matches`` and
embeddings learned on the folders work with it), and nothing is described again.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.frames.compile_policy import AUTO, CompilePolicy
from rhythmic_jax.io.vpr_files import HDF5_SUFFIXES

__all__ = ["describe_frames"]

DESCRIPTOR_FILES = (".npy", *HDF5_SUFFIXES)


def describe_frames(
    source: str | Path,
    descriptor: str | None = None,
    *,
    weights: str | None = None,
    tile: int | None = None,
    stride: int | None = None,
    out: str | Path | None = None,
    progress: bool = False,
    compile: CompilePolicy = AUTO,
    input_size: tuple[int, int] | None = None,
) -> np.ndarray:
    """Descriptors (n, d) float32 of the frames of ``source``, written to ``out``.

    Args:
      source: an image folder (frames sorted by name: the route in order), or
        one large image cut into ``tile``-pixel tiles every ``stride`` pixels
        (default ``tile // 2``) in raster order.
      descriptor: a registered descriptor (patchnorm, hog, efficientnet_lite0,
        vgg16_fc7; None: patchnorm, as ``fit`` reads images).
      weights: the state-dict file of a descriptor that needs one (vgg16_fc7).
      out: a ``.npy`` file to write (atomically: whole or absent); None writes
        nothing.
      progress: show a progress bar; compile: when a network runs compiled
        (:class:`rhythmic_jax.frames.compiled.CompilePolicy`).
      input_size: (width, height) the frames are resized to (default the
        descriptor's own: :data:`rhythmic_jax.frames.sources.INPUT_SIZES`).

    Returns the rows as ``fit`` would have described them, so ``fit(out)`` gives
    the map ``fit(source)`` gives. Frames already described with the same
    descriptor are read from the descriptor cache. Raises InputError (one line)
    for a source that is already descriptors, an ``out`` that is not ``.npy``,
    or frames that cannot be read.
    """
    from rhythmic_jax.frames.sources import load_sources

    path = Path(source)
    if path.suffix.lower() in DESCRIPTOR_FILES and not path.is_dir():
        raise InputError(
            f"{path}: already a descriptor file; describe reads an image folder "
            "or one large image ({opt:tile})"
        )
    if out is not None:
        _check_out(Path(out))
    feats = load_sources(
        [str(path)], descriptor, tile, stride, progress, weights=weights,
        compile=compile, keep_images=False, input_size=input_size,
    )  # fmt: skip
    x = np.ascontiguousarray(feats.x, np.float32)
    if out is not None:
        from rhythmic_jax.io.descriptor_files import save_described
        from rhythmic_jax.io.outputs import write_errors

        with write_errors("out", str(out)):
            save_described(out, x, provenance(path, feats, tile, stride))
    return x


def provenance(source: Path, feats, tile: int | None, stride: int | None) -> dict:
    """What made the rows of ``feats`` from ``source``: the descriptor, its
    settings (input size, weights' digest), the source's absolute path (the
    frames' folder, or the tiled image) and its frames' names in row order."""
    from rhythmic_jax.io.images import list_images

    folder = source.expanduser().absolute()
    frames = (
        [f.name for f in list_images(source, "traversal")] if source.is_dir() else []
    )
    record = {"descriptor": feats.descriptor, "settings": feats.settings,
              "input_size": [feats.settings.get("width"), feats.settings.get("height")],
              "folder": str(folder), "frames": frames}  # fmt: skip
    if tile is not None:
        record["tile"] = [int(tile), int(stride or max(1, tile // 2))]
    return record


def _check_out(out: Path) -> None:
    """Refuse, before any frame is described, an ``out`` the readers would not
    take as descriptors, or one that cannot be written."""
    if out.suffix.lower() != ".npy":
        raise InputError(f"{{opt:out}} {out}: give a .npy file name")
    if out.is_dir():
        raise InputError(f"{{opt:out}} {out}: a folder, not a file")
    from rhythmic_jax.io.outputs import check_place

    check_place("out", out)  # a read-only, full or forbidden place: refused now
