"""The files place-recognition tools write, read as plain numpy arrays.

Each reader takes one tool's own layout, checks it, and refuses anything else with
one line (:class:`~rhythmic_jax.errors.InputError`); none of them unpickles
arbitrary objects.

* **OpenVPRLab** (and the MixVPR, SALAD, BoQ validation files):
  ``<name>_dbImages.npy`` and ``<name>_qImages.npy`` hold image paths relative
  to the dataset root (string arrays), ``<name>_gt_25m.npy`` the positives of
  each query as indices into the database list. The tools write the positives
  with ``np.save`` of a ragged list of integer arrays, i.e. an object array,
  which numpy stores as a pickle (they read it back with ``allow_pickle=True``).
  :func:`read_openvprlab_positives` unpickles it with a loader that knows
  only numpy's array constructors (no other callable can be named) and then
  accepts only integer arrays; a rectangular ``(b, k)`` integer array (every
  query with k positives) is read without any pickle.
* **VPR_Tutorial** ``GT.npz``: ``GThard`` and ``GTsoft``, boolean
  ``(database, query)`` matrices; hard positives count for recall, places only
  in the soft set are not counted wrong (the tutorial's ``createPR`` and
  ``recallAtK`` suppress them).
* **hloc** ``global-feats-*.h5``: one HDF5 group per image name (nested groups
  where the name has ``/``) holding a ``global_descriptor`` dataset of shape
  ``(d,)``; read with ``h5py`` (the optional ``hdf5`` extra).
* **Patch-NetVLAD** ground-truth ``.npz``: ``utmQ`` (b, 2) and ``utmDb``
  (n, 2) positions in metres and ``posDistThr``, the radius of a positive.
"""

from __future__ import annotations

import io
import os
import pickle
from pathlib import Path

import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.io.names import natural_sorted
from rhythmic_jax.io.reader import (
    check_budget,
    inside,
    load_npy,
    load_npz,
    memory_budget,
    npy_header,
    open_h5,
    open_regular,
    read_h5,
)

__all__ = [
    "HDF5_SUFFIXES",
    "load_descriptor_file",
    "read_hloc_descriptors",
    "read_image_list",
    "read_openvprlab_positives",
    "read_patchnetvlad",
    "read_vpr_tutorial",
    "safe_object_npy",
]

HDF5_SUFFIXES = (".h5", ".hdf5")


def _npy_header(path: Path) -> tuple[tuple[int, ...], np.dtype]:
    """Shape and dtype a ``.npy`` file declares, from its header alone."""
    if not path.exists():
        raise InputError(f"{path}: file not found")
    head = npy_header(path)  # regular files only; sizes checked
    return head.shape, head.dtype


def _plain_npy(path: Path) -> np.ndarray:
    """A ``.npy`` without Python objects, loaded with ``allow_pickle=False``."""
    return load_npy(path)


def read_image_list(path: str | os.PathLike, root: str | os.PathLike | None = None):
    """An OpenVPRLab ``*_dbImages.npy`` / ``*_qImages.npy``: (n,) image paths.

    Paths are resolved against ``root`` (the dataset folder) when given, and
    must then exist inside it. Returns a list of n :class:`~pathlib.Path`.
    """
    path = Path(path)
    shape, dtype = _npy_header(path)
    if dtype.kind not in "US" or len(shape) != 1 or not shape[0]:
        raise InputError(
            f"{path}: expected a 1-d array of image paths, got {dtype} {shape}"
        )
    names = [str(v) for v in _plain_npy(path).tolist()]
    if root is None:
        return [Path(v) for v in names]
    for v in names:
        inside(root, v, "image")  # none leaves the dataset, links followed
    out = [Path(root) / v for v in names]
    missing = [p for p in out if not p.is_file()]
    if missing:
        raise InputError(
            f"{path}: {len(missing)} of {len(out)} images not under {root}, "
            f"e.g. {missing[0]}"
        )
    return out


def _numpy_callables() -> dict[tuple[str, str], object]:
    try:
        from numpy._core.multiarray import _reconstruct, scalar
    except ImportError:  # numpy < 2
        from numpy.core.multiarray import _reconstruct, scalar

    allowed = {"_reconstruct": _reconstruct, "scalar": scalar}
    out: dict[tuple[str, str], object] = {
        ("numpy", "ndarray"): np.ndarray,
        ("numpy", "dtype"): np.dtype,
    }
    for module in ("numpy.core.multiarray", "numpy._core.multiarray"):
        out.update({(module, name): f for name, f in allowed.items()})
    return out


class _Restricted(pickle.Unpickler):
    """Admits numpy arrays and scalars; ints, lists, tuples need no lookup."""

    def __init__(self, file, where: str):
        super().__init__(file)
        self.where = where
        self.allowed = _numpy_callables()

    def find_class(self, module: str, name: str):
        found = self.allowed.get((module, name))
        if found is None:
            raise InputError(
                f"{self.where}: refused: the pickle names {module}.{name}; only "
                "ints, lists, tuples and numpy arrays are read"
            )
        return found

    def persistent_load(self, pid):
        raise InputError(f"{self.where}: refused: the pickle holds external objects")


def safe_object_npy(path: str | Path) -> np.ndarray:
    """An object-dtype ``.npy`` unpickled through the allowlist (see the module)."""
    path = Path(path)
    head = npy_header(path)  # regular files only
    if not head.dtype.hasobject:
        return load_npy(path)
    shape = head.shape
    with open_regular(path) as f:
        f.seek(head.offset)
        data = f.read(memory_budget() + 1)
    if len(data) > memory_budget():
        raise InputError(f"{path}: an object array larger than the memory allowed")
    try:
        arr = _Restricted(io.BytesIO(data), str(path)).load()
    except InputError:
        raise
    except Exception as err:  # noqa: BLE001 - a broken pickle raises many kinds
        raise InputError(f"{path}: unreadable object array ({err!r})"[:300]) from None
    if not isinstance(arr, np.ndarray) or arr.shape != shape:
        raise InputError(f"{path}: the pickle is not the {shape} array it announces")
    return arr


def read_openvprlab_positives(
    path: str | os.PathLike, n_database: int | None = None
) -> list[np.ndarray]:
    """An OpenVPRLab ``<name>_gt_25m.npy``: b int64 arrays of database indices.

    Object arrays go through a loader that admits only numpy's array
    constructors (see the module); every element must be a 1-d integer array
    (empty: no positive). ``n_database``: when given, every index must be below.
    """
    path = Path(path)
    shape, dtype = _npy_header(path)
    if not dtype.hasobject:
        arr = _plain_npy(path)
        if arr.dtype.kind not in "iu" or arr.ndim != 2:
            raise InputError(
                f"{path}: expected positives per query (object array of index "
                f"arrays, or (b, k) integers), got {arr.dtype} {arr.shape}"
            )
        rows = list(arr.astype(np.int64))
    else:
        arr = safe_object_npy(path)
        if arr.ndim != 1:
            raise InputError(f"{path}: not the 1-d array of {shape} its header says")
        rows = []
        for i, v in enumerate(arr.tolist()):
            ok = isinstance(v, np.ndarray) and v.ndim <= 1 and v.dtype.kind in "iu"
            if not ok:
                raise InputError(
                    f"{path}: query {i} holds {type(v).__name__}; expected an "
                    "integer array of database indices"
                )
            rows.append(v.reshape(-1).astype(np.int64))
    if not rows:
        raise InputError(f"{path}: no query")
    for i, v in enumerate(rows):
        if v.size and (
            v.min() < 0 or (n_database is not None and v.max() >= n_database)
        ):
            bad = v.min() if v.min() < 0 else v.max()
            raise InputError(
                f"{path}: query {i} lists database image {bad}, outside "
                f"0..{(n_database or 0) - 1}"
            )
    return rows


def _npz(path: Path, keys: tuple[str, ...]) -> dict[str, np.ndarray]:
    """The named arrays of an ``.npz``, none of them a pickle, their sizes
    checked before any is inflated (:func:`rhythmic_jax.io.reader.load_npz`)."""
    if not path.exists():
        raise InputError(f"{path}: file not found")
    return load_npz(path, keys)


def read_vpr_tutorial(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """VPR_Tutorial ``GT.npz``: ``(hard, soft)``, bool (database, query) each.

    The soft matrix is taken as ``GTsoft | GThard`` (the tutorial's soft set
    contains the hard one).
    """
    path = Path(path)
    got = _npz(path, ("GThard", "GTsoft"))
    out = []
    for key in ("GThard", "GTsoft"):
        a = got[key]
        if a.dtype.kind not in "biuf" or a.ndim != 2 or 0 in a.shape:
            raise InputError(
                f"{path}: {key} must be a (database, query) matrix, got "
                f"{a.dtype} {a.shape}"
            )
        if a.dtype.kind != "b" and not np.isin(a, (0, 1)).all():
            raise InputError(f"{path}: {key} holds values other than 0 and 1")
        out.append(a.astype(bool))
    hard, soft = out
    if hard.shape != soft.shape:
        raise InputError(
            f"{path}: GThard is {hard.shape} but GTsoft is {soft.shape}; they must "
            "match"
        )
    return hard, soft | hard


def read_patchnetvlad(
    path: str | os.PathLike,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Patch-NetVLAD ground truth: ``(utmDb (n, 2), utmQ (b, 2), posDistThr)``."""
    path = Path(path)
    got = _npz(path, ("utmQ", "utmDb", "posDistThr"))
    xy = []
    for key in ("utmDb", "utmQ"):
        a = got[key]
        if a.dtype.kind not in "iuf" or a.ndim != 2 or a.shape[1] != 2 or not len(a):
            raise InputError(
                f"{path}: {key} must be (n, 2) positions in metres, got "
                f"{a.dtype} {a.shape}"
            )
        a = a.astype(np.float64)
        if not np.isfinite(a).all():
            raise InputError(f"{path}: {key} holds NaN or infinite values")
        xy.append(a)
    thr = got["posDistThr"]
    if (
        thr.dtype.kind not in "iuf"
        or thr.size != 1
        or not float(thr.reshape(-1)[0]) > 0
    ):
        raise InputError(f"{path}: posDistThr must be one positive number, got {thr}")
    return xy[0], xy[1], float(thr.reshape(-1)[0])


def read_hloc_descriptors(
    path: str | os.PathLike, select: str | None = None
) -> tuple[list[str], np.ndarray]:
    """hloc ``global-feats-*.h5``: ``(names, descriptors (n, d) float32)``.

    Every dataset called ``global_descriptor`` is one image, named by its
    group's path (hloc writes the image name as the group name, nested groups
    where it has ``/``; float16 when written ``as_half``). Rows are in the
    natural order of the names (:func:`rhythmic_jax.io.names.name_key`, the
    order of an image folder's frames: ``frame2`` before ``frame10``).

    ``select``: only the images whose names start with it (``"db/"``,
    ``"query/"``: hloc's ``db_prefix`` and ``query_prefix``, one file holding
    both); one that selects nothing is refused naming the prefixes present.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: file not found")
    found: dict[str, np.ndarray] = {}

    def visit(name, obj):
        if hasattr(obj, "shape") and name.split("/")[-1] == "global_descriptor":
            found[name.rpartition("/")[0]] = obj

    try:
        with open_h5(path) as f:  # regular file; no link into another file
            f.visititems(visit)
            names = natural_sorted(found)
            if not names:
                raise InputError(f"{path}: no global_descriptor dataset (not hloc's)")
            names = _selected(path, names, select)
            shapes = {found[k].shape for k in names}
            kinds = {found[k].dtype.kind for k in names}
            if len(shapes) != 1 or len(next(iter(shapes))) != 1 or kinds - set("fiu"):
                raise InputError(
                    f"{path}: global_descriptor datasets must all be (d,) numbers, "
                    f"got shapes {sorted(shapes)[:3]} of kinds {sorted(kinds)}"
                )
            shape = next(iter(shapes))
            need = len(names) * int(np.prod(shape, dtype=object)) * 4
            check_budget(path, need, f"{len(names)} float32 descriptors of {shape}")
            x = np.stack([read_h5(found[k], path) for k in names])
            x = x.astype(np.float32)
    except InputError:
        raise
    except Exception as err:  # noqa: BLE001 - h5py raises OSError, KeyError, ...
        raise InputError(f"{path}: not a readable HDF5 file ({err})"[:300]) from None
    if not np.isfinite(x).all():
        row = int(np.flatnonzero(~np.isfinite(x).all(1))[0])
        raise InputError(f"{path}: {names[row]} holds NaN or inf")
    return names, x


def _selected(path: Path, names: list[str], select: str | None) -> list[str]:
    """The ``names`` starting with ``select`` (all without one); none is refused
    in one line naming the prefixes the file holds (its top-level groups)."""
    if select is None:
        return names
    kept = [n for n in names if n.startswith(select)]
    if kept:
        return kept
    tops = natural_sorted({n.split("/")[0] + ("/" if "/" in n else "") for n in names})
    more = f", ... ({len(tops)} in all)" if len(tops) > 8 else ""
    shown = ", ".join(tops[:8]) + more
    raise InputError(
        f"{path}: no image name starts with {select!r}; the names start with "
        f"{shown}"
    )


def load_descriptor_file(
    path: str | os.PathLike, select: str | None = None
) -> np.ndarray:
    """(n, d) float32 descriptors of a ``.npy`` or an hloc ``.h5`` file;
    ``select``: an ``.h5``'s rows whose names start with it."""
    if Path(path).suffix.lower() in HDF5_SUFFIXES:
        return read_hloc_descriptors(path, select)[1]
    if select is not None:
        raise InputError(
            f"{path}: {{opt:select}} picks images by name, and a .npy names none "
            "(it applies to hloc .h5 files)"
        )
    from rhythmic_jax.io.descriptor_files import load_descriptors

    return load_descriptors(path)
