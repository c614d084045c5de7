"""The descriptor stage, streamed: image folders -> folders of ``.npy`` shards.

:func:`describe_to_shards` reads a folder's frames a chunk at a time, describes
each chunk and writes it as a shard (:class:`rhythmic_jax.io.frame_files.ShardWriter`),
so neither the images nor the descriptors of a route are ever held whole; the
streamed fit (:func:`rhythmic_jax.fitting.scale_fit.fit_map_files`) reads the shards.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from rhythmic_jax.io.frame_files import ShardWriter
from rhythmic_jax.progress import bar as progress_bar

__all__ = ["describe_to_shards"]


def describe_to_shards(
    folder: str | os.PathLike,
    out: str | os.PathLike,
    descriptor: str = "patchnorm",
    settings: dict | None = None,
    rows: int = 2048,
    progress: bool = True,
) -> dict:
    """Describe every frame of ``folder`` (natural name order) into shards at ``out``.

    Returns the descriptor's settings (what a map built on the shards records).
    """
    from rhythmic_jax.errors import InputError
    from rhythmic_jax.frames.features import describe, get_descriptor
    from rhythmic_jax.io.images import list_images, read_rgb

    desc = get_descriptor(descriptor, **(settings or {}))
    files = list_images(Path(folder), "traversal")
    bar = progress_bar(total=len(files), show=progress, desc=Path(folder).name)
    shape = None
    meta = {"descriptor": descriptor, "settings": desc.settings()}
    with ShardWriter(out, rows=rows, meta=meta) as writer:
        for lo in range(0, len(files), rows):
            chunk = [read_rgb(p) for p in files[lo : lo + rows]]
            for p, image in zip(files[lo : lo + rows], chunk, strict=True):
                shape = shape or image.shape
                if image.shape != shape:
                    raise InputError(f"frame {p} is {image.shape[:2]}, not {shape[:2]}")
            writer.write(describe(np.stack(chunk), desc, progress=False))
            bar.update(len(chunk))
    bar.close()
    return desc.settings()
