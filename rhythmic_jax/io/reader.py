"""How any input file is opened: one boundary between the tool and files from others.

A map, a data file or a ground-truth file may come from anyone, so every file the
tool reads passes here first (as git checks a fetched object before it uses it,
and safetensors checks every offset against the file's size before allocating):

* **regular files only**: a FIFO, a character or block device, a socket, a folder
  (or a link to one) is refused in one line. The path is stat-ed first and opened
  with ``O_NONBLOCK``, then the open file is checked again (``fstat``), so a pipe
  or ``/dev/zero`` never blocks or streams (:func:`open_regular`);
* **names inside their folder**: a name that a file names (``map.json``'s digest
  paths, a tiled pair's image) is resolved, links followed, and must stay inside
  the folder it is relative to (:func:`inside`);
* **sizes before allocation**: text and JSON are read up to a cap checked against
  the file's size first, JSON nested at most :data:`JSON_DEPTH` deep
  (:func:`read_json`); a ``.npy`` header's declared bytes must fit in the file
  (:func:`npy_header`), an ``.npz`` member's in its declared size, read from the
  few bytes inflated of its header (:func:`npz_headers`), and what is read into
  memory in :func:`memory_budget` (:func:`check_budget`: :func:`load_npy`,
  :func:`load_npz`, :func:`read_h5`; the map's arrays before orbax restores them);
* **``.h5`` data from the same file**: external links, external storage and
  virtual datasets are refused (:func:`open_h5`, :func:`read_h5`).

Refusals are :class:`~rhythmic_jax.errors.InputError` naming the file; nothing is
unpickled (``allow_pickle=False`` everywhere).
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import resource
import stat
import zipfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from rhythmic_jax.errors import InputError

__all__ = [
    "JSON_DEPTH",
    "TEXT_LIMIT",
    "NpyHeader",
    "available_memory",
    "check_budget",
    "file_sha256",
    "inside",
    "load_npy",
    "load_npz",
    "memory_budget",
    "npy_header",
    "npz_headers",
    "open_h5",
    "open_regular",
    "read_bytes",
    "read_h5",
    "read_json",
    "read_text",
]

TEXT_LIMIT = 16 * 2**20  # map.json and the other metadata files: a few KiB in use
JSON_DEPTH = 64  # map.json nests four deep
_KINDS = (
    (stat.S_ISDIR, "a folder"),
    (stat.S_ISFIFO, "a FIFO (named pipe)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)
_SIZE = re.compile(r"\s*(\d+(?:\.\d*)?)\s*([kmgt]?)(?:i?b)?\s*", re.IGNORECASE)


def available_memory() -> int:
    """Bytes this process may still allocate: ``MemAvailable`` of /proc/meminfo
    (else physical RAM), within what an address-space limit (``ulimit -v``)
    leaves it."""
    budget = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    budget = int(line.split()[1]) * 1024
                    break
    except OSError:
        pass
    limit = resource.getrlimit(resource.RLIMIT_AS)[0]
    if limit != resource.RLIM_INFINITY:
        try:
            with open("/proc/self/statm") as fh:
                used = int(fh.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
        except OSError:
            used = 0
        budget = min(budget, max(0, limit - used))
    return budget


def memory_budget() -> int:
    """Bytes one input file may make the tool allocate: ``$RHYTHMIC_JAX_MEMORY``
    (bytes, or with a K/M/G/T suffix) when set, else half of
    :func:`available_memory`."""
    env = os.environ.get("RHYTHMIC_JAX_MEMORY")
    if not env:
        return available_memory() // 2
    m = _SIZE.fullmatch(env)
    if m is None:
        raise InputError(
            f"RHYTHMIC_JAX_MEMORY={env!r}: give bytes, e.g. 4G or 4294967296"
        )
    return int(float(m.group(1)) * 1024 ** " kmgt".index(m.group(2).lower() or " "))


def _gib(v: int) -> str:
    return f"{v / 2**30:.2f} GiB" if v >= 2**30 else f"{v / 2**20:.3g} MiB"


def check_budget(path: str | os.PathLike, nbytes: int, what: str) -> None:
    """Refuse (:class:`InputError`, naming ``path``) ``what``, declaring
    ``nbytes``, when they exceed :func:`memory_budget`."""
    budget = memory_budget()
    if nbytes > budget:
        why = "half the available memory; RHYTHMIC_JAX_MEMORY sets it"
        why = "RHYTHMIC_JAX_MEMORY" if os.environ.get("RHYTHMIC_JAX_MEMORY") else why
        raise InputError(
            f"{path}: {what} would take {nbytes:,} bytes ({_gib(nbytes)}), more "
            f"than the {budget:,} bytes ({_gib(budget)}) allowed ({why})"
        )


def _kind(mode: int) -> str | None:
    return next((name for test, name in _KINDS if test(mode)), None)


def _not_regular(path, mode: int) -> InputError:
    kind = _kind(mode) or "an unknown kind of file"
    return InputError(f"{path}: {kind}, not a regular file; refusing to read it")


def open_regular(path: str | os.PathLike) -> BinaryIO:
    """``path`` opened for binary reading, when it is a regular file (links
    followed). Anything else is refused without blocking: the path is stat-ed,
    opened ``O_NONBLOCK`` and the open file stat-ed again."""
    try:
        st = os.stat(path)
        if not stat.S_ISREG(st.st_mode):
            raise _not_regular(path, st.st_mode)
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except OSError as err:
        reason = (err.strerror or str(err)).lower()
        raise InputError(f"{path}: cannot read ({reason})") from None
    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode):  # replaced between the stat and the open
        os.close(fd)
        raise _not_regular(path, st.st_mode)
    os.set_blocking(fd, True)
    fh = os.fdopen(fd, "rb")
    fh.raw.name = os.fspath(path)  # as open() names it (image readers read it)
    return fh



def file_sha256(path: str | os.PathLike) -> str:
    """The sha256 (hex) of a regular file's bytes, read a MiB at a time."""
    import hashlib

    digest = hashlib.sha256()
    with open_regular(path) as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()

def inside(folder: str | os.PathLike, name: str, what: str = "file") -> Path:
    """The path of ``name`` (a relative name a file gave) under ``folder``,
    resolved, links followed; refused when it is absolute, climbs out of the
    folder or is a link leaving it."""
    try:
        root = Path(folder).resolve()
    except (OSError, RuntimeError) as err:  # the folder itself a loop of links
        raise InputError(f"{folder}: cannot be resolved ({err})") from None
    if not isinstance(name, str) or not name or "\x00" in name:
        raise InputError(f"{folder}: {what} name {name!r} is not a file name")
    if Path(name).is_absolute():
        raise InputError(f"{folder}: {what} {name!r} is absolute; it must lie inside")
    try:
        target = (root / name).resolve()
    except (OSError, RuntimeError) as err:  # a loop of links
        raise InputError(
            f"{folder}: {what} {name!r} cannot be resolved ({err})"
        ) from None
    if target != root and root not in target.parents:
        raise InputError(f"{folder}: {what} {name!r} leads outside the folder")
    return target


def read_bytes(path: str | os.PathLike, limit: int = TEXT_LIMIT) -> bytes:
    """A regular file's bytes, refused when it holds more than ``limit``."""
    with open_regular(path) as fh:
        size = os.fstat(fh.fileno()).st_size
        if size > limit:
            raise InputError(
                f"{path}: {size:,} bytes, more than the {limit:,} read of such a file"
            )
        data = fh.read(limit + 1)
    if len(data) > limit:  # grew while read
        raise InputError(f"{path}: more than the {limit:,} bytes read of such a file")
    return data


def read_text(
    path: str | os.PathLike, limit: int = TEXT_LIMIT, encoding: str = "utf-8"
) -> str:
    """A regular file's text (at most ``limit`` bytes) in ``encoding``."""
    try:
        return read_bytes(path, limit).decode(encoding)
    except UnicodeDecodeError as err:
        raise InputError(f"{path}: not {encoding} text ({err.reason})") from None


def _depth(value: Any) -> int:
    """How deep lists and dicts nest in ``value`` (iteratively: no recursion)."""
    deepest, todo = 0, [(value, 1)]
    while todo:
        v, d = todo.pop()
        if isinstance(v, dict | list):
            deepest = max(deepest, d)
            if d <= JSON_DEPTH:
                todo.extend(
                    (x, d + 1) for x in (v.values() if isinstance(v, dict) else v)
                )
    return deepest


def read_json(
    path: str | os.PathLike, what: str = "JSON", limit: int = TEXT_LIMIT
) -> Any:
    """The JSON value of a regular file of at most ``limit`` bytes, nested at
    most :data:`JSON_DEPTH` deep; ``what`` names the content in a refusal
    (``"{path}: corrupt {what} (...)"``)."""
    data = read_bytes(path, limit)
    try:
        value = json.loads(data.decode("utf-8"))
    except (ValueError, UnicodeDecodeError) as err:
        raise InputError(f"{path}: corrupt {what} ({err})") from None
    except RecursionError:
        raise InputError(f"{path}: corrupt {what} (nested too deep)") from None
    if _depth(value) > JSON_DEPTH:
        raise InputError(f"{path}: corrupt {what} (nested over {JSON_DEPTH} deep)")
    return value


# ------------------------------------------------------------------- numpy files


@dataclass(frozen=True)
class NpyHeader:
    """What a ``.npy`` header declares; ``offset``: bytes before the data."""

    shape: tuple[int, ...]
    fortran: bool
    dtype: np.dtype
    offset: int

    @property
    def nbytes(self) -> int:
        """Bytes of the data (0 for Python objects, whose size is unknown)."""
        count = int(np.prod(self.shape, dtype=object))
        return 0 if self.dtype.hasobject else count * self.dtype.itemsize


_HEADERS = {
    (1, 0): np.lib.format.read_array_header_1_0,
    (2, 0): np.lib.format.read_array_header_2_0,
    (3, 0): np.lib.format.read_array_header_2_0,  # utf-8 field names, same layout
}


def _header(fh, path) -> NpyHeader:
    """The ``.npy`` header at the position of ``fh`` (binary, seekable), with
    ``offset`` counted from that position."""
    try:
        start = fh.tell()
        if fh.read(1) == b"\x80":
            raise InputError(
                f"{path} contains Python objects; refusing to unpickle (a raw "
                "pickle, not .npy)"
            )
        fh.seek(start)
        version = np.lib.format.read_magic(fh)
        if version not in _HEADERS:
            raise ValueError(f"format version {version}")
        shape, fortran, dtype = _HEADERS[version](fh)
        offset = fh.tell() - start
    except InputError:
        raise
    except Exception as err:  # noqa: BLE001 - numpy raises several kinds
        raise InputError(f"{path} is not a valid .npy file: {err}"[:300]) from None
    return NpyHeader(tuple(int(k) for k in shape), bool(fortran), dtype, offset)


def npy_header(path: str | os.PathLike, sizes: bool = True) -> NpyHeader:
    """A ``.npy`` file's header. ``sizes``: the data it declares must be in the
    file (a header declaring 10^12 rows over a small file is refused). Object
    arrays pass unchecked (their data is a pickle: :func:`load_npy` refuses
    them)."""
    with open_regular(path) as fh:
        head = _header(fh, path)
        size = os.fstat(fh.fileno()).st_size
    if not sizes:
        return head
    if head.nbytes > size - head.offset:
        raise InputError(
            f"{path}: truncated, not a valid .npy file: its header declares "
            f"{head.shape} {head.dtype} "
            f"({head.nbytes:,} bytes) but the file holds {size - head.offset:,}"
        )
    return head


def load_npy(path: str | os.PathLike, mmap: bool = False) -> np.ndarray:
    """A ``.npy`` file's array after :func:`npy_header`'s checks, and one read
    into memory within :func:`memory_budget`; Python objects are refused unread.
    ``mmap``: memory-mapped read-only (nothing allocated)."""
    head = npy_header(path)
    if head.dtype.hasobject:
        raise InputError(f"{path} contains Python objects; refusing to unpickle")
    if not mmap:
        check_budget(path, head.nbytes, f"a {head.dtype} array of {head.shape}")
    try:
        if mmap:
            return np.load(path, mmap_mode="r", allow_pickle=False)
        with open_regular(path) as fh:
            return np.load(fh, allow_pickle=False)
    except InputError:
        raise
    except Exception as err:  # noqa: BLE001 - changed since the header was read
        raise InputError(f"{path} is not a valid .npy file: {err}"[:300]) from None


@contextlib.contextmanager
def _zip(path) -> Iterator[zipfile.ZipFile]:
    with open_regular(path) as fh:
        try:
            zf = zipfile.ZipFile(fh)
        except (zipfile.BadZipFile, OSError, ValueError) as err:
            raise InputError(f"{path}: not a readable .npz ({err})"[:300]) from None
        with zf:
            yield zf


def npz_headers(path: str | os.PathLike) -> dict[str, NpyHeader]:
    """Every array of an ``.npz`` by name, from its members' headers alone (a
    few bytes inflated of each): a member's declared size must hold the data its
    header declares."""
    out = {}
    with _zip(path) as zf:
        for info in zf.infolist():
            name = info.filename.removesuffix(".npy")
            try:
                with zf.open(info) as member:
                    head = _header(member, f"{path}: {name}")
            except InputError:
                raise
            except Exception as err:  # noqa: BLE001 - zipfile raises many kinds
                raise InputError(f"{path}: not a readable .npz ({err})"[:300]) from None
            if head.offset + head.nbytes > info.file_size:
                raise InputError(
                    f"{path}: {name} declares {head.shape} {head.dtype} but its member "
                    f"holds {info.file_size:,} bytes"
                )
            out[name] = head
    return out


def load_npz(path: str | os.PathLike, keys=None) -> dict[str, np.ndarray]:
    """The arrays ``keys`` (default: all) of an ``.npz``, after
    :func:`npz_headers`' checks and within :func:`memory_budget` together,
    before any is inflated; one holding Python objects is refused unread."""
    heads = npz_headers(path)
    keys = list(heads) if keys is None else list(keys)
    missing = [k for k in keys if k not in heads]
    if missing:
        raise InputError(f"{path}: no array {missing[0]!r} (holds {sorted(heads)})")
    if any(heads[k].dtype.hasobject for k in keys):
        raise InputError(f"{path}: refused: holds Python objects (a pickle)")
    total = sum(heads[k].nbytes for k in keys)
    check_budget(path, total, ", ".join(f"{k} {heads[k].shape}" for k in keys))
    out = {}
    with _zip(path) as zf:
        names = {i.filename.removesuffix(".npy"): i for i in zf.infolist()}
        for k in keys:
            try:
                with zf.open(names[k]) as member:
                    out[k] = np.load(member, allow_pickle=False)
            except Exception as err:  # noqa: BLE001 - a damaged member
                raise InputError(f"{path}: not a readable .npz ({err})"[:300]) from None
    return out


# ------------------------------------------------------------------------- HDF5


@contextlib.contextmanager
def open_h5(path: str | os.PathLike):
    """An ``.h5`` file opened read-only with ``h5py``, when it is a regular file
    holding no external link (a link into another file)."""
    try:
        import h5py
    except ImportError:
        raise InputError(
            f"{path}: reading .h5 needs h5py (pip install 'rhythmic-jax[hdf5]')"
        ) from None
    open_regular(path).close()
    try:
        f = h5py.File(path, "r")
    except Exception as err:  # noqa: BLE001 - h5py raises OSError, ...
        raise InputError(f"{path}: not a readable HDF5 file ({err})"[:300]) from None
    with f:
        links: list[str] = []
        f.visititems_links(
            lambda name, link: (
                links.append(name) if isinstance(link, h5py.ExternalLink) else None
            )
        )
        if links:
            raise InputError(
                f"{path}: {links[0]} is an external link into another file; only "
                "data stored in the file itself is read"
            )
        yield f


def read_h5(dataset, path: str | os.PathLike) -> np.ndarray:
    """A dataset's values, when they are stored in its own file (no external
    storage, not virtual) and fit :func:`memory_budget`."""
    if dataset.is_virtual or dataset.external:
        how = "a virtual dataset" if dataset.is_virtual else "stored in another file"
        raise InputError(
            f"{path}: {dataset.name} is {how}; only data stored in the file itself "
            "is read"
        )
    nbytes = int(np.prod(dataset.shape, dtype=object)) * dataset.dtype.itemsize
    check_budget(path, nbytes, f"dataset {dataset.name}")
    return dataset[()]
