"""The order of frame names: natural order, numbers compared as numbers.

One order for every place a route's frames are named: the files of an image
folder (:func:`rhythmic_jax.io.images.list_images`) and the image names of an
hloc ``.h5`` file (:func:`rhythmic_jax.io.vpr_files.read_hloc_descriptors`),
so the same frames are the same rows whichever way they arrive.

A name is compared component by component (``/`` separates them, as in hloc's
names ``db/frame1.jpg``), each component as its runs of text and digits, the
digits read as integers (``frame2 < frame10 < frame100``), the text without
case, the last component without its suffix (``.png`` and ``.jpg`` frames are
ordered alike). Ties (``frame010`` and ``frame10``, ``A1`` and ``a1``) are
broken by the name itself, so the order is total and the same on every
machine.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterable, Sequence
from typing import TypeVar

__all__ = ["name_key", "natural_order", "natural_sorted"]

T = TypeVar("T")

_DIGITS = re.compile(r"(\d+)")


def _stem(component: str) -> str:
    """A file name without its suffix (``frame1.png`` -> ``frame1``; a name
    that is all suffix, ``.png``, is kept)."""
    head, dot, tail = component.rpartition(".")
    return head if dot and head and not tail.isdigit() else component


def _parts(component: str) -> tuple:
    """``"Frame010b"`` -> ``("frame", 10, "b")``: text at even places, ints at odd."""
    pieces = _DIGITS.split(component.lower())
    return tuple(int(p) if i % 2 else p for i, p in enumerate(pieces))


def name_key(name: str) -> tuple:
    """Sort key of a frame name (see the module): ``(natural parts, name)``.

    ``name_key("db/frame2.jpg") < name_key("db/frame10.jpg")``; distinct names
    have distinct keys.
    """
    name = str(name)
    components = name.split("/")
    components[-1] = _stem(components[-1])
    return tuple(_parts(c) for c in components), name


def natural_order(names: Sequence[str]) -> list[int]:
    """Indices that put ``names`` in natural order (:func:`name_key`)."""
    return sorted(range(len(names)), key=lambda i: name_key(names[i]))


def natural_sorted(items: Iterable[T], name: Callable[[T], str] = str) -> list[T]:
    """``items`` in the natural order of ``name(item)`` (default: the item)."""
    return sorted(items, key=lambda item: name_key(name(item)))
