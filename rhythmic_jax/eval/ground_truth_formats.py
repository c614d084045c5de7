"""Which ground-truth format a file holds, read from what it holds.

A file's name says little (a VPR-Bench ``ground_truth_new.npy`` copied to
``nord_gt_25m.npy`` is still VPR-Bench's), so :func:`detect_format` opens it
and reads its arrays' names, dtypes and shapes:

* an ``.npz`` (a zip) holding ``GThard`` and ``GTsoft``, (database, query)
  0/1 matrices: **VPR_Tutorial**; holding ``utmQ`` and ``utmDb``, (n, 2)
  positions, and ``posDistThr``: **Patch-NetVLAD**;
* a ``.npy`` of Python objects (read through the allowlist of
  :func:`rhythmic_jax.io.vpr_files.safe_object_npy`, no other code runs)
  whose rows are ``[query index, [reference indices]]``: **VPR-Bench**; whose
  rows are integer arrays: **OpenVPRLab**'s positives;
* a ``.npy`` of integers (b, k), k != 2: OpenVPRLab's positives, k per query;
  of real numbers (n, 2): **positions** (easting, northing);
* text: a **positions** CSV.

Only where the contents fit two formats does the name decide (:func:`_tie`):
an integer (b, 2) ``.npy`` is positions unless its name holds ``_gt_``
(OpenVPRLab's ``<name>_gt_25m.npy``); an object (b, 2) array of integers is
VPR-Bench's unless its name holds ``_gt_``. A file that fits none is refused
in one line naming what was found in it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.io.reader import npy_header, npz_headers, open_regular
from rhythmic_jax.io.vpr_files import safe_object_npy

__all__ = ["FORMATS", "detect_format"]

# the ground-truth formats, as --ground-truth-format names them
FORMATS = ("vpr-bench", "openvprlab", "vpr-tutorial", "patch-netvlad", "positions")
NAME_HINTS = {"openvprlab": "_gt_", "vpr-bench": "ground_truth"}  # ties only

_NPY_MAGIC = b"\x93NUMPY"
_ZIP_MAGIC = b"PK\x03\x04"


def detect_format(path: str | Path) -> str:
    """The format (one of :data:`FORMATS`) the file ``path`` holds, by its
    contents; :class:`InputError` naming what it holds when it fits none."""
    path = Path(path)
    if not path.exists():  # a FIFO or device exists: open_regular names it
        raise InputError(f"{{opt:ground_truth}} {path}: file not found")
    try:
        with open_regular(path) as f:  # a FIFO or device: refused, never opened
            magic = f.read(6)
    except OSError as err:
        raise InputError(f"{path}: cannot read ({err.strerror})") from None
    if magic.startswith(_ZIP_MAGIC):
        return _npz_format(path)
    if magic == _NPY_MAGIC:
        return _npy_format(path)
    return "positions"  # text: read_positions says what is wrong with it


def _tie(path: Path, candidates: tuple[str, ...]) -> str:
    """The candidate whose name hint (:data:`NAME_HINTS`) the file name holds,
    else the first: the name breaks a tie of contents and nothing more."""
    for fmt in candidates:
        hint = NAME_HINTS.get(fmt)
        if hint is not None and hint in path.name.lower():
            return fmt
    return candidates[0]


def _none_fits(path: Path, found: str) -> InputError:
    return InputError(
        f"{{opt:ground_truth}} {path}: no ground-truth format holds {found} "
        f"(formats: {', '.join(FORMATS)}; see {{opt:ground_truth_format}})"
    )


def _npz_format(path: Path) -> str:
    """VPR_Tutorial's or Patch-NetVLAD's, by the arrays an ``.npz`` holds."""
    held = {  # the members' headers alone: nothing inflated
        key: "Python objects" if head.dtype.hasobject else f"{head.dtype} {head.shape}"
        for key, head in npz_headers(path).items()
    }
    if {"GThard", "GTsoft"} <= held.keys():
        return "vpr-tutorial"
    if {"utmQ", "utmDb"} <= held.keys():
        return "patch-netvlad"
    shown = ", ".join(f"{k}: {v}" for k, v in sorted(held.items())[:8]) or "nothing"
    raise _none_fits(
        path,
        f"arrays {shown}; neither VPR_Tutorial's GThard/GTsoft nor Patch-NetVLAD's "
        "utmQ/utmDb",
    )


def _npy_format(path: Path) -> str:
    """A ``.npy``'s format, from its header and, for objects, its rows."""
    head = npy_header(path)
    shape, dtype = head.shape, head.dtype
    what = f"a .npy of {dtype} {tuple(shape)}"
    if dtype.hasobject:
        return _object_format(path, safe_object_npy(path))
    if len(shape) == 2 and shape[0] and dtype.kind in "iu":
        if shape[1] == 2:
            return _tie(path, ("positions", "openvprlab"))
        return "openvprlab"
    if len(shape) == 2 and shape[0] and shape[1] == 2 and dtype.kind == "f":
        return "positions"
    raise _none_fits(path, what)


def _is_int(v) -> bool:
    return isinstance(v, int | np.integer) and not isinstance(v, bool)


def _is_indices(v) -> bool:
    """A list of reference indices: an integer array, or a list/tuple of ints."""
    if isinstance(v, np.ndarray):
        return v.dtype.kind in "iu" and v.ndim <= 1
    return isinstance(v, list | tuple) and all(_is_int(r) for r in v)


def _vpr_bench_row(r) -> bool:
    """``[query index, [reference indices]]`` (or one reference index)."""
    return (
        isinstance(r, list | tuple) and len(r) == 2 and _is_int(r[0])
        and (_is_indices(r[1]) or _is_int(r[1]))
    )  # fmt: skip


def _openvprlab_row(r) -> bool:
    """An integer array of database indices (empty: none)."""
    return isinstance(r, np.ndarray) and r.dtype.kind in "iu" and r.ndim <= 1


def _kind(row) -> str:
    """What a row is, in a few words: ``list of 3: int, str, float``."""
    if isinstance(row, np.ndarray):
        return f"array {row.dtype} {row.shape}"
    if isinstance(row, list | tuple):
        inside = ", ".join(type(v).__name__ for v in row[:3])
        return f"{type(row).__name__} of {len(row)}: {inside}"
    return type(row).__name__


def _object_format(path: Path, arr: np.ndarray) -> str:
    """VPR-Bench's ``[query, [references]]`` rows or OpenVPRLab's index arrays."""
    if arr.ndim not in (1, 2) or not len(arr):
        raise _none_fits(path, f"an object array of shape {arr.shape}")
    rows = [list(r) for r in arr] if arr.ndim == 2 else arr.tolist()
    if all(_vpr_bench_row(r) for r in rows):
        if all(_is_int(r[1]) for r in rows):  # (b, 2) integers: either
            return _tie(path, ("vpr-bench", "openvprlab"))
        return "vpr-bench"
    if arr.ndim == 1 and all(_openvprlab_row(r) for r in rows):
        return "openvprlab"
    fits = [_vpr_bench_row(r) or _openvprlab_row(r) for r in rows]
    mixed = [_vpr_bench_row(r) != _vpr_bench_row(rows[0]) for r in rows]
    i = fits.index(False) if False in fits else mixed.index(True)
    raise _none_fits(
        path,
        f"an object array of shape {arr.shape}, row {i} a {_kind(rows[i])}; "
        "neither VPR-Bench's [query, [references]] rows nor OpenVPRLab's index "
        "arrays",
    )
