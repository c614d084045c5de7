"""Checks on user input: one clear :class:`InputError` line for each bad value.

Arrays (:func:`check_features`, :func:`check_labels`, and the scale a fit
needs, :func:`check_fit_scale`), single numbers (:func:`check_int`,
:func:`check_number`) and sizes in bytes (:func:`parse_bytes`). The command line
parses every numeric option with a :class:`Domain` (:func:`int_option`,
:func:`number_option`), an argparse type that states its domain in words, so a
bad value ends where it is parsed and 0 or a negative number is never read as
"unset"; every domain is bounded on both sides (:data:`INT_LIMIT`,
:data:`FLOAT_LIMIT` where it names no bound), so a huge value never reaches the
work. :func:`check_reference` keeps brute force on the map's own database.

Importing this module does not import numpy (the command line builds its parser
from it): the checks import it when a value is not a Python number or an array
is checked.
"""

from __future__ import annotations

import argparse
import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from rhythmic_jax.errors import InputError

if TYPE_CHECKING:
    import numpy as np

__all__ = [
    "FLOAT_LIMIT",
    "INT_LIMIT",
    "Domain",
    "check_features",
    "check_fit_scale",
    "check_int",
    "check_labels",
    "check_number",
    "check_reference",
    "check_sequence",
    "frames_digest",
    "int_option",
    "is_int",
    "is_number",
    "is_sparse",
    "number_option",
    "parse_bytes",
    "scale_sums",
]
_UNITS = {"": 1, "k": 2**10, "m": 2**20, "g": 2**30, "t": 2**40}


def is_int(value) -> bool:
    """True for a Python or numpy integer (``bool`` is not one)."""
    if isinstance(value, int):
        return not isinstance(value, bool)
    import numpy as np

    return isinstance(value, np.integer)


def is_number(value) -> bool:
    """True for a Python or numpy integer or float (``bool`` is not one)."""
    if isinstance(value, int | float):
        return not isinstance(value, bool)
    import numpy as np

    return isinstance(value, np.integer | np.floating)


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


def check_sequence(sequence, b: int | None = None) -> int | None:
    """A sequence length L as an int >= 1 (None: single frames), at most ``b``
    queries when ``b`` is given; else one line naming ``{opt:sequence}``."""
    if sequence is None:
        return None
    msg = f"{{opt:sequence}} length L must be an integer >= 1, got {sequence!r}"
    sequence = check_int(sequence, "sequence", 1, msg=msg)
    if b is not None and sequence > b:
        raise InputError(
            f"{{opt:sequence}} length L={sequence} is longer than the {b} queries"
        )
    return sequence


def check_number(
    value, name: str, low: float | None = None, high: float | None = None
) -> float:
    """``value`` as a finite float, inside the open interval (low, high) if given."""
    ok = is_number(value)
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


#: The largest integer an option takes where its domain names no other: the
#: largest int32 (JAX's default integer), far from int64's overflow in the
#: arithmetic a count goes through (a tolerance added to a place index).
INT_LIMIT = 2**31 - 1
#: The largest magnitude a number option takes where its domain names no
#: other: beyond it float32, the maps' precision, holds only inf.
FLOAT_LIMIT = 1e38


def _g(v: float) -> str:
    """A bound in words: integers in full (4294967295), other numbers by ``g``."""
    return str(int(v)) if float(v).is_integer() and abs(v) < 1e16 else f"{v:g}"


@dataclass(frozen=True)
class Domain:
    """The values a numeric option takes; called on its text, an argparse ``type``.

    Integers (``integer``) or finite numbers between ``low`` and ``high`` (each
    optional; a number's bound is excluded where ``open_low`` / ``open_high``),
    plus the words in ``words`` taken as they are (``--codes int8``). ``parse``
    reads the text when it is not a plain number (a size like ``1GiB``): it
    raises ``ValueError`` on text it cannot read, and the value it returns is
    checked; the option's value stays the text then.

    Every domain covers a whole range: a bound left out is :data:`INT_LIMIT`
    for integers (above; below, an integer domain names its least value) and
    :data:`FLOAT_LIMIT` for numbers (either side), so a huge value is refused
    where it is parsed, never met as an overflow in the work.

    ``Domain(True, 2)`` is "an integer in [2, 2147483647]", ``Domain(False, 0,
    1, True, True)`` "a number in (0, 1)", ``Domain(False, 0, 1)`` "a number in
    [0, 1]".
    """

    integer: bool
    low: float | None = None
    high: float | None = None
    open_low: bool = False
    open_high: bool = False
    words: tuple[str, ...] = ()
    parse: Callable[[str], float] | None = None
    what: str = ""  # what ``parse`` reads, for "expected ..." lines

    @property
    def __name__(self) -> str:  # argparse names a type by it
        return self.what or ("an integer" if self.integer else "a number")

    def limits(self) -> tuple[float, float]:
        """``(low, high)`` with the bounds left out filled in (:data:`INT_LIMIT`,
        :data:`FLOAT_LIMIT`)."""
        limit = INT_LIMIT if self.integer else FLOAT_LIMIT
        low = -limit if self.low is None else self.low
        return low, limit if self.high is None else self.high

    def bounds(self, whole: bool = True) -> str:
        """``"in [2, 2147483647]"``, ``"in (0, 1)"``; with ``whole`` False, the
        declared bounds alone (``">= 2"``, ``""`` when unbounded)."""
        lo, hi = self.limits() if whole else (self.low, self.high)
        open_low = self.open_low and self.low is not None and not self.integer
        open_high = self.open_high and self.high is not None and not self.integer
        if lo is not None and hi is not None:
            left, right = "(" if open_low else "[", ")" if open_high else "]"
            return f"in {left}{_g(lo)}, {_g(hi)}{right}"
        if lo is not None:
            return f"{'>' if open_low else '>='} {_g(lo)}"
        if hi is not None:
            return f"{'<' if open_high else '<='} {_g(hi)}"
        return ""

    def text(self, whole: bool = True) -> str:
        """The domain in words, as ``--help`` states it (``whole`` False: its
        declared bounds alone, as a value below them is told)."""
        kind = self.__name__
        if not self.integer and not self.parse and not self.bounds(whole):
            kind = "a finite number"
        words = "".join(f" or {w}" for w in self.words)
        return " ".join(filter(None, (kind, self.bounds(whole)))) + words

    def check(self, value) -> float:
        """``value`` if it lies in the domain, else :class:`InputError` ("must be
        ..., got ..."); a value past a bound left out is told the whole range."""
        if self.integer:
            if is_int(value) and self._inside(value):
                return int(value)
            whole = not is_int(value) or value > self.limits()[1] or (
                self.low is None and value < self.limits()[0])  # fmt: skip
            raise InputError(f"must be {self.text(whole)}, got {value}")
        if not is_number(value) or not math.isfinite(value):
            raise InputError(f"must be a finite number, got {value}")
        if not self._inside(value):
            lo, hi = self.limits()
            whole = value > hi or value < lo and self.low is None
            if whole and self.low is None and self.high is None:
                raise InputError(f"must be a finite number {self.bounds()}, got "
                                 f"{_told(value)}")  # fmt: skip
            raise InputError(f"must be {self.bounds(whole)}, got {_told(value)}")
        return float(value)

    def _inside(self, v) -> bool:
        shut = self.integer
        lo, hi = self.limits()
        above = v > lo or (v == lo and not (self.open_low and not shut and
                                            self.low is not None))  # fmt: skip
        below = v < hi or (v == hi and not (self.open_high and not shut and
                                            self.high is not None))  # fmt: skip
        return above and below

    def __call__(self, text: str):
        if text in self.words:
            return text
        try:
            value = (self.parse or (int if self.integer else float))(text)
        except (ValueError, OverflowError):
            words = "".join(f" or {w}" for w in self.words)
            raise argparse.ArgumentTypeError(
                f"expected {self.__name__}{words}, got {text!r}"
            ) from None
        try:
            checked = self.check(value)
        except InputError as err:
            raise argparse.ArgumentTypeError(str(err)) from None
        return text if self.parse else checked


def _told(value: float) -> str:
    """``value`` short (``1e+38``) where that reads back as it, else exactly
    (``1.0000000000000002e+38``, just past a bound shown as ``1e+38``)."""
    short = f"{value:g}"
    return short if float(short) == value else repr(float(value))


def int_option(least: int = 1, most: int | None = None) -> Domain:
    """An argparse ``type``: the text of an integer in [least, most]."""
    return Domain(True, least, most)


def number_option(
    low: float | None = None,
    high: float | None = None,
    closed: bool = False,
) -> Domain:
    """An argparse ``type``: the text of a finite number in (low, high), or in
    [low, high] when ``closed``."""
    return Domain(False, low, high, not closed, not closed)


def parse_bytes(text: str) -> int:
    """``"1GiB"``, ``"800M"``, ``"1.5g"``, ``"123456"`` -> bytes (``--memory``)."""
    m = re.fullmatch(r"\s*([0-9.]+)\s*([kmgt]?)(i?b)?\s*", str(text).lower())
    if not m:
        raise InputError(
            f"{{opt:memory}}: expected a size like 1GiB or 800M, got {text!r}"
        )
    return int(float(m.group(1)) * _UNITS[m.group(2)])


def frames_digest(x) -> str:
    """The sha256 of frames x (n, d) as float32 rows, their shape included: what
    a map fitted on descriptor files records of its database."""
    import hashlib

    import numpy as np

    x = np.ascontiguousarray(np.asarray(x, np.float32))
    return hashlib.sha256(repr(x.shape).encode() + x.tobytes()).hexdigest()


def check_reference(
    found: int, fitted: int, source: str, digest: str | None = None,
    recorded: str | None = None,
) -> None:  # fmt: skip
    """Refuse (one :class:`InputError` line naming ``{opt:reference}``) a
    brute-force reference of ``found`` frames for a map fitted on ``fitted``,
    or, where the map recorded its frames' digest (``recorded``,
    :func:`frames_digest`), frames of another ``digest``: brute force must
    search the map's own database, or the table would set two different
    routes side by side as if they were one."""
    if found != fitted:
        raise InputError(
            f"{{opt:reference}} {source}: {found} frames, but the map was fitted on "
            f"{fitted}; give the map's reference frames (its database) or leave "
            "{opt:reference} out"
        )
    if recorded is not None and digest is not None and digest != recorded:
        raise InputError(
            f"{{opt:reference}} {source}: not the frames the map was fitted on "
            f"(the same count, {found}, other values); give the map's reference "
            "frames (its database) or leave {opt:reference} out"
        )


def is_sparse(x) -> bool:
    """True for a sparse matrix or array (scipy.sparse, pydata sparse, JAX's
    BCOO): what ``np.asarray`` would wrap as one object, not convert."""
    module = type(x).__module__ or ""
    top = ("scipy.sparse", "sparse", "jax.experimental.sparse")
    return any(module == m or module.startswith(m + ".") for m in top)


def check_features(x, name: str = "features", d: int | None = None) -> np.ndarray:
    """Return ``x`` as a finite float32 (n, d) array, or raise :class:`InputError`.

    Complex values and sparse matrices are refused (one line naming them), not
    cut to their real part or read as one object.

    Args:
      x: array-like of shape (n, d).
      name: what to call it in the message (a file name, "queries", ...).
      d: the dimension it must have (a map's), when known.
    """
    import numpy as np

    if is_sparse(x):
        raise InputError(
            f"{name}: a sparse matrix ({type(x).__name__} of shape {x.shape}); "
            "sparse input is not supported: pass a dense array (x.toarray())"
        )
    try:
        arr = np.asarray(x)
    except Exception as err:  # noqa: BLE001 - ragged or exotic input
        raise InputError(f"{name}: not an array ({err})") from None
    if np.iscomplexobj(arr):
        raise InputError(
            f"{name}: Complex data not supported (dtype {arr.dtype}); the map "
            "takes real features: pass x.real or abs(x), whichever they mean"
        )
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
    import numpy as np

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


# The mean frame's length above which a fit is refused (see check_fit_scale).
FIT_OFFSET_LIMIT = 4.0


def scale_sums(x) -> np.ndarray:
    """What :func:`check_fit_scale` needs of frames x (n, d), as sums that add
    over blocks of rows and over processes: (d + 2,) float64 holding the column
    sums (d,), the sum of squared row norms and the row count."""
    import numpy as np

    x = np.asarray(x)
    out = np.zeros(x.shape[1] + 2)
    for lo in range(0, len(x), 65536):  # float64 a block at a time, not a copy of x
        block = np.asarray(x[lo : lo + 65536], np.float64)
        out[:-2] += block.sum(axis=0)
        out[-2] += np.einsum("ij,ij->", block, block)
    out[-1] = len(x)
    return out


def check_fit_scale(sums, largest: float, name: str = "reference features") -> None:
    """Refuse (one :class:`InputError` line) features on a scale the solvers
    cannot fit: frames that share an offset far from the origin, as unscaled
    8-bit descriptors (0-255) do.

    The objective regularises the bias like the weights
    (:mod:`rhythmic_jax.solvers.objective`), so a common offset puts the bias
    column almost in the span of the features: for 60 x 16 frames of integers
    0-253, ``Xa^T Xa`` (``Xa = [X, 1]``) has an eigenvalue ~7e-8 of its largest,
    the penalty is nearly a hard margin, and the float32 solvers end in NaN or
    stop far from the optimum. Every fit (in memory, ``--solver lbfgs``,
    streamed, on several processes) calls this before it compiles or solves.

    The statistic is the length ``m`` of the mean frame, refused when above
    :data:`FIT_OFFSET_LIMIT` (4) *and* above half the frames' RMS distance
    ``s`` from it. L2-normalised rows (every descriptor this package computes)
    have ``m <= 1``. The second condition spares centred features: n frames of
    noise have a mean of length about ``s / sqrt(n)``, no offset they share.
    Measured with the default solver (gap 1e-7, C = log n) on integers
    uniform in 0..k against ``sklearn.svm.LinearSVC(loss="squared_hinge")``
    (``m = k sqrt(d) / 2``, ``m / s`` about 1 to 1.7); "fit": the objective
    within 1e-8 of liblinear's, "x%": that far above it::

        n    d    k=1    2     4     8     16    32    64    128   255
        60   16   fit    fit   fit   fit   fit   fit   fit   fit   NaN
        60   64   fit    fit   fit   1%    31%   107%  NaN   NaN   NaN
        60   256  fit    0.4%  4%    19%   21%   NaN   ..    ..    ..
        500  16   fit    fit   fit   fit   NaN   fit   ..    ..    NaN
        500  64   fit    fit   fit   fit   NaN   NaN   NaN   NaN   NaN
        500  256  0.06%  6%    ..

    Every failure has ``m >= 8``; every ``m <= 4`` fits (also 0/0.5 features
    at n = 500, d = 256), hence the limit with a factor 2 to spare. The check
    is conservative: some frames past it fit (90 x 16 points of a random walk,
    ``m`` 23 and ``s`` 16, reach liblinear's optimum; 1000 x 32, ``m`` 101,
    give NaN), and nothing short of the solve tells them apart.

    Args:
      sums: :func:`scale_sums` of every frame (summed over blocks, processes).
      largest: the largest ``|feature|``, named in the message.
      name: what to call the features.
    """
    import numpy as np

    sums = np.asarray(sums, np.float64)
    n = max(float(sums[-1]), 1.0)
    mean = sums[:-2] / n
    m = float(np.sqrt(np.sum(np.square(mean))))
    spread = float(np.sqrt(max(float(sums[-2]) / n - m * m, 0.0)))
    if m <= FIT_OFFSET_LIMIT or m <= spread / 2:
        return
    eight_bit = 32 <= largest <= 255
    hint = " (8-bit scale?)" if eight_bit else ""
    scale = "divide them by 255" if eight_bit else "scale them down"
    raise InputError(
        f"{name}: values up to {largest:.4g}{hint}, their mean frame "
        f"{m:.4g} from the origin; the solvers expect features of order one: "
        f"{scale} or L2-normalise each row"
    )
