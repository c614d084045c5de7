"""Frames on disk, read in blocks: one ``.npy`` file or a folder of ``.npy`` shards.

A route of 10^6 frames of 256 floats is 1 GiB: a fit that must stay under a
memory bound cannot hold it. :func:`open_frames` reads only the headers;
:meth:`Frames.read` then reads rows ``start .. stop`` with plain file reads into
a fresh buffer (no memory map, so pages already read do not stay in the
process's resident set). A folder of shards (``*.npy`` sorted by name, same
width) reads as their rows in order; :class:`ShardWriter` writes one as frames
arrive, so a descriptor stage never holds the whole route either.

Names: n frames, d features.
"""

from __future__ import annotations

import json
import os
import shutil
import uuid
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.io.descriptor_files import check_descriptors, descriptor_shape
from rhythmic_jax.io.reader import npy_header, open_regular, read_json

__all__ = [
    "Frames",
    "ShardWriter",
    "is_frame_source",
    "open_frames",
    "shard_descriptor",
]
_META = "descriptor.json"


@dataclass(frozen=True)
class _Part:
    path: Path
    offset: int  # bytes before the data
    rows: int
    d: int
    dtype: np.dtype


@dataclass(frozen=True)
class Frames:
    """The rows of one or several ``.npy`` files, in order, read on demand."""

    parts: tuple[_Part, ...]
    d: int

    @property
    def n(self) -> int:
        return sum(p.rows for p in self.parts)

    @property
    def shape(self) -> tuple[int, int]:
        return self.n, self.d

    def read(self, start: int, stop: int) -> np.ndarray:
        """Rows ``start .. stop`` as checked float32 (stop - start, d)."""
        out = np.empty((max(stop - start, 0), self.d), np.float32)
        first = 0
        for part in self.parts:
            lo, hi = max(start, first), min(stop, first + part.rows)
            if lo < hi:
                raw = np.empty((hi - lo, self.d), part.dtype)
                with open_regular(part.path) as fh:
                    fh.seek(part.offset + (lo - first) * self.d * part.dtype.itemsize)
                    if fh.readinto(memoryview(raw).cast("B")) != raw.nbytes:
                        raise InputError(f"{part.path}: truncated (rows {lo}..{hi})")
                where = f"{part.path} rows {lo - first}..{hi - first}"
                out[lo - start : hi - start] = check_descriptors(raw, where)
            first += part.rows
        return out

    def blocks(self, start: int, stop: int, rows: int) -> Iterator[np.ndarray]:
        """Rows ``start .. stop`` in blocks of at most ``rows``."""
        for lo in range(start, stop, rows):
            yield self.read(lo, min(stop, lo + rows))


def _part(path: Path) -> _Part:
    shape = descriptor_shape(path)  # header only; refuses pickles
    if len(shape) != 2 or 0 in shape:
        raise InputError(f"{path}: expected a non-empty (n, d) array, got {shape}")
    head = npy_header(path)  # regular files only; the data is in the file
    if head.fortran or head.dtype.kind not in "fiu":
        raise InputError(f"{path}: need a C-ordered real array, got {head.dtype}")
    return _Part(path, head.offset, int(shape[0]), int(shape[1]), head.dtype)


def is_frame_source(path: str | os.PathLike) -> bool:
    """A ``.npy`` file, or a folder holding ``.npy`` shards."""
    p = Path(path)
    if p.suffix.lower() == ".npy":
        return True
    return p.is_dir() and any(p.glob("*.npy"))


def open_frames(paths: str | os.PathLike | Sequence[str | os.PathLike]) -> Frames:
    """Frames of a ``.npy`` file, a folder of shards, or several of these in order."""
    if isinstance(paths, str | os.PathLike):
        paths = [paths]
    parts: list[_Part] = []
    for p in map(Path, paths):
        if p.is_dir():
            files = sorted(p.glob("*.npy"))
            if not files:
                raise InputError(f"{p}: a folder with no .npy shards")
            parts += [_part(f) for f in files]
        else:
            parts.append(_part(p))
    widths = {p.d for p in parts}
    if len(widths) != 1:
        raise InputError(f"{paths[0]}: shards of different widths {sorted(widths)}")
    return Frames(tuple(parts), widths.pop())


def shard_descriptor(path: str | os.PathLike) -> tuple[str, dict]:
    """(descriptor name, settings) of a shard folder written from images, or
    ``("features", {})`` for descriptor files."""
    meta = Path(path) / _META
    if not os.path.lexists(meta):
        return "features", {}
    try:
        got = read_json(meta, "shard metadata")
        return str(got["descriptor"]), dict(got["settings"])
    except (ValueError, KeyError, TypeError) as err:
        raise InputError(f"{meta}: corrupt ({err!r})") from None


class ShardWriter:
    """Writes frames as ``.npy`` shards of ``rows`` frames into a new folder.

    Shards go to a hidden folder beside ``path``, renamed into place by
    :meth:`close`; a writer left without closing (an error) removes it, so no
    half-written folder is ever found at ``path``::

        with ShardWriter("route.shards", rows=4096) as out:
            for batch in batches:
                out.write(describe(batch))
    """

    def __init__(
        self, path: str | os.PathLike, rows: int = 4096, meta: dict | None = None
    ):
        self.path = Path(path).expanduser().absolute()
        if self.path.exists():
            raise InputError(f"{self.path}: exists; give a new folder for the shards")
        if rows < 1:
            raise InputError(f"rows per shard must be >= 1, got {rows}")
        self.rows, self.n, self._count = rows, 0, 0
        self._tmp = self.path.parent / f".{self.path.name}.tmp-{uuid.uuid4().hex[:8]}"
        self._tmp.mkdir(parents=True)
        if meta is not None:  # what the frames are, read by shard_descriptor
            (self._tmp / _META).write_text(json.dumps(meta))
        self._buf: list[np.ndarray] = []

    def write(self, x: np.ndarray) -> None:
        """Append frames (m, d)."""
        self._buf.append(check_descriptors(np.asarray(x), "frames"))
        while sum(len(b) for b in self._buf) >= self.rows:
            self._flush(self.rows)

    def _flush(self, rows: int) -> None:
        x = np.concatenate(self._buf)
        np.save(self._tmp / f"shard-{self._count:06d}.npy", x[:rows])
        self._buf = [x[rows:]] if len(x) > rows else []
        self._count, self.n = self._count + 1, self.n + min(rows, len(x))

    def close(self) -> Path:
        """Write the last shard and move the folder into place."""
        if self._buf:
            self._flush(sum(len(b) for b in self._buf))
        os.rename(self._tmp, self.path)
        return self.path

    def __enter__(self) -> ShardWriter:
        return self

    def __exit__(self, kind, *_) -> None:
        if kind is None:
            self.close()
        else:
            shutil.rmtree(self._tmp, ignore_errors=True)
