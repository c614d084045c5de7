"""Descriptor files: float32 (n, d) arrays in ``.npy``, read without unpickling.

A map's reference frames (or queries) described elsewhere come in as one ``.npy``
file per traversal, one row per frame in route order. The header is read and
checked before any data (:func:`descriptor_shape`), so a file of Python objects
is refused without being unpickled and a fit can be refused for its size before
the file is read; writes are atomic (temporary file, then rename).

A file ``describe`` writes keeps its provenance in a record beside it,
``ref.npy.json`` (:func:`save_described`, :func:`read_record`): the descriptor
and its settings (input size, the weights' digest), the frames' folder and
names, the rows, dimension and sha256 of the ``.npy`` it belongs to. The record
is written after the ``.npy`` and any older one removed before, so a file is
never paired with a record of another; a reader checks the pairing (shape and
digest) and refuses a record that does not belong to its file.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.io.atomic import save_npy
from rhythmic_jax.io.reader import file_sha256, load_npy, npy_header

__all__ = [
    "check_descriptors",
    "descriptor_shape",
    "frame_names",
    "load_descriptors",
    "read_npy_header",
    "read_record",
    "record_path",
    "save_described",
    "save_descriptors",
]

RECORD_FORMAT = "rhythmic_jax descriptor file"

_HEADERS = {
    (1, 0): np.lib.format.read_array_header_1_0,
    (2, 0): np.lib.format.read_array_header_2_0,
    (3, 0): np.lib.format.read_array_header_2_0,  # utf-8 field names, same layout
}


def read_npy_header(f) -> tuple[tuple[int, ...], bool, np.dtype]:
    """``(shape, fortran_order, dtype)`` a ``.npy`` file declares, read from the
    open binary file ``f`` (left at the first data byte); ``ValueError`` for a
    file that is not ``.npy`` or of a format version NumPy does not write."""
    version = np.lib.format.read_magic(f)
    read = _HEADERS.get(version)
    if read is None:
        raise ValueError(f"format version {version}")
    return read(f)


def check_descriptors(x: np.ndarray, where: str) -> np.ndarray:
    """``x`` as float32 (n, d), or :class:`InputError` naming ``where`` and why."""
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
    if not path.exists():
        raise InputError(f"descriptor file not found: {path}")
    header = npy_header(path, sizes=False)  # regular files only; no data read
    if header.dtype.hasobject:
        raise InputError(f"{path} contains Python objects; refusing to unpickle")
    return header.shape


def load_descriptors(path: str | os.PathLike) -> np.ndarray:
    """Read a float32 (n, d) descriptor matrix from a ``.npy`` file.

    Nothing is unpickled (``allow_pickle=False``); the array must be 2-D,
    non-empty, numeric and finite.
    """
    descriptor_shape(path)  # the header's checks, before any data is read
    return check_descriptors(load_npy(path), str(path))


def save_descriptors(path: str | os.PathLike, x: np.ndarray) -> None:
    """Write float32 (n, d) ``x`` to ``path`` (.npy) atomically (temp + rename)."""
    path = Path(path)
    if path.suffix.lower() != ".npy":
        raise InputError(f"descriptor file must be .npy, got {path}")
    x = check_descriptors(np.asarray(x), "descriptors")
    save_npy(path, x)


def record_path(path: str | os.PathLike) -> Path:
    """The provenance record of the descriptor file ``path``: ``path`` + ``.json``."""
    path = Path(path)
    return path.with_name(path.name + ".json")


def save_described(path: str | os.PathLike, x: np.ndarray, record: dict) -> dict:
    """Write float32 (n, d) ``x`` to ``path`` (.npy) and its provenance
    ``record`` (JSON-able: descriptor, settings, folder, frames...) beside it
    (:func:`record_path`), each atomically: an older record is removed first and
    the new one, holding the file's rows, dimension and sha256, written last.
    Returns the record as written."""
    from rhythmic_jax.io.atomic import write_file

    path = Path(path)
    save_descriptors(path, x)  # the checks before anything is removed
    side = record_path(path)
    if side.is_file() or side.is_symlink():
        side.unlink()
    n, d = np.shape(x)
    full = {"format": RECORD_FORMAT, **record, "rows": int(n), "dim": int(d),
            "sha256": file_sha256(path)}  # fmt: skip
    write_file(side, json.dumps(full, indent=1, sort_keys=True) + "\n")
    return full


def read_record(path: str | os.PathLike) -> dict[str, Any] | None:
    """The provenance record of the descriptor file ``path``, or None when it has
    none (no ``path.json``). Refuses (:class:`InputError`, one line) a record that
    is not one, or that belongs to another file (its rows, dimension or sha256
    differ from the file's)."""
    from rhythmic_jax.io.reader import read_json

    path, side = Path(path), record_path(path)
    if not side.exists():
        return None
    record = read_json(side, "descriptor record", limit=1 << 28)
    if not isinstance(record, dict) or record.get("format") != RECORD_FORMAT:
        raise InputError(f"{side}: not a descriptor record (describe writes them)")
    shape = descriptor_shape(path)
    if tuple(shape) != (record.get("rows"), record.get("dim")) or record.get(
        "sha256"
    ) != file_sha256(path):
        raise InputError(
            f"{side}: the record of another file than {path} (its rows or digest "
            "differ); describe the frames again, or remove the record"
        )
    if not isinstance(record.get("descriptor"), str) or not isinstance(
        record.get("settings"), dict
    ):
        raise InputError(f"{side}: not a descriptor record (no descriptor named)")
    return record


def frame_names(source: str | os.PathLike, what: str) -> list[str]:
    """The names of ``source``'s frames in route order: an image folder's files, or
    the frames a descriptor file's record names (``describe`` wrote it from a
    folder; the images need not be there any more). Anything else is refused in
    one line: ``what`` (e.g. "reference") names the source in it."""
    from rhythmic_jax.io.images import list_images

    path = Path(source)
    if path.is_dir():
        return [p.name for p in list_images(path, what)]
    npy = path.suffix.lower() == ".npy" and path.is_file()
    record = read_record(path) if npy else None
    if record is None or not record.get("frames"):
        raise InputError(
            f"{what} {path}: no frame names to read (an image folder, or a .npy "
            "describe wrote from one)"
        )
    return [str(name) for name in record["frames"]]
