"""Checks on user input: one clear :class:`InputError` line for each bad value.

Arrays (:func:`check_features`, :func:`check_labels`) and single numbers
(:func:`check_int`, :func:`check_number`). The command line parses every numeric
option with :func:`int_option` or :func:`number_option`, argparse types built on
the same two checks, so a bad value ends where it is parsed and 0 or a negative
number is never read as "unset".
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

import numpy as np

from rhythmic_jax.errors import InputError

__all__ = [
    "check_features",
    "check_int",
    "check_labels",
    "check_number",
    "int_option",
    "is_int",
    "number_option",
]


def is_int(value) -> bool:
    """True for a Python or numpy integer (``bool`` is not one)."""
    return isinstance(value, int | np.integer) and not isinstance(value, bool)


def check_int(
    value, name: str, low: int | None = None, high: int | None = None, msg: str = ""
) -> int:
    """``value`` as an ``int`` in ``[low, high]`` (bounds optional), else InputError.

    ``msg`` replaces the default line ``"{name} must be an integer >= {low}, got
    {name}={value!r}"`` when the caller has a clearer one.
    """
    ok = is_int(value) and (low is None or value >= low)
    if ok and (high is None or value <= high):
        return int(value)
    if not msg:
        if high is not None:
            msg = f"{name} must be an integer in [{low}, {high}], got {name}={value!r}"
        elif low is not None:
            msg = f"{name} must be an integer >= {low}, got {name}={value!r}"
        else:
            msg = f"{name} must be an integer, got {name}={value!r}"
    raise InputError(msg)


def check_number(
    value, name: str, low: float | None = None, high: float | None = None
) -> float:
    """``value`` as a finite float, inside the open interval (low, high) if given."""
    ok = isinstance(value, int | float | np.integer | np.floating)
    ok = ok and not isinstance(value, bool)
    value = float(value) if ok else value
    if not ok or not math.isfinite(value):
        raise InputError(f"{name} must be a finite number, got {value!r}")
    too_low = low is not None and value <= low
    if too_low or (high is not None and value >= high):
        if low is not None and high is not None:
            where = f"in ({low:g}, {high:g})"
        else:
            where = f"> {low:g}" if low is not None else f"< {high:g}"
        raise InputError(f"{name} must be {where}, got {value:g}")
    return value


def _option(check: Callable, parse: Callable, what: str) -> Callable[[str], object]:
    def option(text: str):
        try:
            value = parse(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
        try:
            return check(value)
        except InputError as err:  # "value must be ..." -> "must be ..."
            raise argparse.ArgumentTypeError(str(err).removeprefix("value ")) from None

    option.__name__ = what
    return option


def int_option(least: int = 1) -> Callable[[str], int]:
    """An argparse ``type``: the text of an integer >= ``least``."""

    def check(v: int) -> int:
        msg = f"must be an integer >= {least}, got {v}"
        return check_int(v, "value", least, msg=msg)

    return _option(check, int, "an integer")


def number_option(
    low: float | None = None, high: float | None = None
) -> Callable[[str], float]:
    """An argparse ``type``: the text of a finite number in (low, high)."""
    return _option(lambda v: check_number(v, "value", low, high), float, "a number")


def check_features(x, name: str = "features", d: int | None = None) -> np.ndarray:
    """Return ``x`` as a finite float32 (n, d) array, or raise :class:`InputError`.

    Args:
      x: array-like of shape (n, d).
      name: what to call it in the message (a file name, "queries", ...).
      d: the dimension it must have (a map's), when known.
    """
    try:
        arr = np.asarray(x)
    except Exception as err:  # noqa: BLE001 - ragged or exotic input
        raise InputError(f"{name}: not an array ({err})") from None
    if arr.dtype == object or not np.issubdtype(arr.dtype, np.number):
        raise InputError(f"{name}: expected numbers, got dtype {arr.dtype}")
    if arr.ndim != 2:
        raise InputError(
            f"{name}: expected a 2-D array (frames x features), got shape {arr.shape}"
        )
    if arr.shape[0] == 0 or arr.shape[1] == 0:
        raise InputError(f"{name}: empty array of shape {arr.shape}")
    if d is not None and arr.shape[1] != d:
        raise InputError(
            f"{name}: {arr.shape[1]}-d features but the map was built for {d}-d"
        )
    arr = arr.astype(np.float32, copy=False)
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        row = int(np.flatnonzero(bad)[0])
        raise InputError(
            f"{name}: {int(bad.sum())} rows hold NaN or inf (first: row {row})"
        )
    return arr


def check_labels(labels, n: int) -> np.ndarray:
    """Place labels (n,) as non-negative int64, every place 0 .. max present."""
    lab = np.asarray(labels)
    if lab.shape != (n,):
        raise InputError(f"labels: expected shape ({n},), got {lab.shape}")
    if not np.issubdtype(lab.dtype, np.integer):
        raise InputError(f"labels: expected integers, got dtype {lab.dtype}")
    if lab.size == 0:
        raise InputError("labels: empty; a map needs at least one frame per place")
    if lab.min() < 0:
        raise InputError("labels: place labels must be >= 0")
    missing = np.setdiff1d(np.arange(int(lab.max()) + 1), lab)
    if missing.size:
        raise InputError(
            f"labels: places must be numbered 0 .. {int(lab.max())} without gaps; "
            f"{missing.size} missing (first: {int(missing[0])})"
        )
    return lab.astype(np.int64)
