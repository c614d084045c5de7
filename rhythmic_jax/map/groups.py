"""How a map labels its frames: groups of classes (integer maths, no JAX).

A map keeps ``G`` groups of linear classifiers; group ``g`` has ``size_g`` classes
and labels frame ``i`` with one of them. Three layouts:

- ``periods`` (the paper, Sec. III-B): pairwise co-prime periods ``tau_g``, label
  ``i mod tau_g``. A template fires on every ``tau``-th frame, so it groups frames
  that need not look alike.
- ``mixed`` (Le, Xu, Hoang and Milford 2018, sub-linear storage growth): radices
  ``b_1 .. b_r`` (most significant first) with ``prod(b) >= n``; label ``g`` is
  digit ``g`` of ``i``, ``(i // prod(b_{g+1..r})) mod b_g``. The most significant
  digit ``i // prod(b_2..r)`` classifies contiguous segments of the route, whose
  frames look alike.
- ``hierarchical``: a coarse classifier of contiguous segments of length ``s``
  (label ``i // s``, ``ceil(n / s)`` classes) and pairwise co-prime fine periods
  ``tau_g`` with ``prod(tau) >= s`` (labels ``i mod tau_g``), which tell apart
  the places of one segment.

In every layout the labels identify a frame uniquely below :attr:`Groups.capacity`,
and the map stores ``sum(size) * (d + 1)`` numbers
(:func:`rhythmic_jax.map.periods.storage_bytes`, same accounting for every layout).

A *layout spec* is the user's string: ``periods`` (periods chosen from candidates
by training error, as the paper), ``periods:T1,T2``, ``mixed`` / ``hierarchical``
(sizes chosen from ``n``, ``r`` and ``level`` by :func:`choose_radices` and
:func:`choose_segment`), ``mixed:B1,..,Br``, ``hierarchical:S`` or
``hierarchical:S:T1,T2``.

Parsing and checking a layout is plain Python (the command line does it without
numpy); the labels and columns import numpy when they are asked for.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from rhythmic_jax.errors import InputError
from rhythmic_jax.map.periods import (
    _iroot_ceil,
    candidate_periods,
    choose_periods,
    pairwise_coprime,
    period_offsets,
)
from rhythmic_jax.validate import is_int

if TYPE_CHECKING:
    import numpy as np

__all__ = [
    "KINDS",
    "Groups",
    "LayoutSpec",
    "choose_radices",
    "choose_segment",
    "fine_periods",
    "parse_layout",
    "resolve_layout",
]

KINDS = ("periods", "mixed", "hierarchical")


def _positive_ints(values, what: str) -> tuple[int, ...]:
    try:
        out = tuple(int(v) for v in values)
    except (TypeError, ValueError):
        raise InputError(f"{what} must be integers, got {values!r}") from None
    bad = [v for v in values if isinstance(v, bool) or int(v) != v]
    if bad or not out or min(out) < 1:
        raise InputError(f"{what} must be positive integers, got {tuple(values)}")
    return out


@dataclass(frozen=True)
class Groups:
    """The classes of a fitted map: ``kind``, group ``sizes`` and ``segment``.

    Attributes:
      kind: "periods" | "mixed" | "hierarchical".
      sizes: classes per group; periods: the periods; mixed: the radices, most
        significant first; hierarchical: ``(segments, tau_1, .., tau_r)``.
      segment: hierarchical only, the segment length ``s`` (0 otherwise).

    Hashable, so it is a static argument of jitted decoders.
    """

    kind: str
    sizes: tuple[int, ...]
    segment: int = 0

    def __post_init__(self):
        if self.kind not in KINDS:
            raise InputError(f"layout kind must be one of {KINDS}, got {self.kind!r}")
        sizes = _positive_ints(self.sizes, f"{self.kind} sizes")
        object.__setattr__(self, "sizes", sizes)
        object.__setattr__(self, "segment", int(self.segment))
        if self.kind == "periods" and not pairwise_coprime(sizes):
            raise InputError(f"periods {sizes} are not pairwise co-prime")
        if self.kind == "mixed" and min(sizes) < 2:
            raise InputError(f"mixed radices must be >= 2, got {sizes}")
        if self.kind == "hierarchical":
            fine = sizes[1:]
            if len(sizes) < 2 or self.segment < 1:
                raise InputError(
                    f"a hierarchical layout needs a segment length >= 1 and fine "
                    f"periods, got segment={self.segment}, sizes={sizes}"
                )
            if not pairwise_coprime(fine) or math.prod(fine) < self.segment:
                raise InputError(
                    f"fine periods {fine} must be pairwise co-prime with a product "
                    f">= the segment length {self.segment}"
                )
        elif self.segment:
            raise InputError(f"a {self.kind} layout has no segment length")

    # ------------------------------------------------------------ structure
    @property
    def p(self) -> int:
        """Templates in all: ``sum(sizes)``."""
        return sum(self.sizes)

    @property
    def offsets(self) -> tuple[int, ...]:
        """Column offset of each group: ``(0, size_1, size_1 + size_2, ...)``."""
        return period_offsets(self.sizes)

    @property
    def capacity(self) -> int:
        """Most places the labels tell apart: ``prod(sizes)``, or ``segments * s``."""
        if self.kind == "hierarchical":
            return self.sizes[0] * self.segment
        return math.prod(self.sizes)

    def weights(self) -> tuple[int, ...]:
        """Mixed radix: place value of each digit, ``prod(b_{g+1..r})``."""
        return tuple(math.prod(self.sizes[g + 1 :]) for g in range(len(self.sizes)))

    def check(self, n: int) -> int:
        """``n`` as an int, or InputError when the labels cannot tell n places apart.

        A mixed layout also refuses a most significant radix larger than
        ``ceil(n / prod(b_2..r))`` (classes no place has), a hierarchical one more
        segments than ``ceil(n / s)``.
        """
        if not is_int(n) or n < 1:
            raise InputError(f"n must be a positive integer, got n={n!r}")
        n = int(n)
        if n > self.capacity:
            raise InputError(
                f"{self.describe()} tells apart {self.capacity} places, the map has {n}"
            )
        if self.kind == "mixed" and len(self.sizes) > 1:
            need = -(-n // self.weights()[0])
            if self.sizes[0] > need:
                raise InputError(
                    f"{self.describe()}: the most significant radix is "
                    f"{self.sizes[0]} but {n} places use {need} of its digits"
                )
        if self.kind == "hierarchical" and self.sizes[0] != -(-n // self.segment):
            raise InputError(
                f"{self.describe()}: {n} places make {-(-n // self.segment)} "
                f"segments of {self.segment}, not {self.sizes[0]}"
            )
        return n

    # --------------------------------------------------------------- labels
    def label_parts(self, index) -> list:
        """One label array per group, by ``//`` and ``%`` only (NumPy or JAX input).

        ``index`` (...,) ints -> ``G`` arrays of the same shape.
        """
        if self.kind == "periods":
            return [index % t for t in self.sizes]
        if self.kind == "mixed":
            return [
                (index // w) % b
                for w, b in zip(self.weights(), self.sizes, strict=True)
            ]
        return [index // self.segment] + [index % t for t in self.sizes[1:]]

    def labels(self, index: np.ndarray | int) -> np.ndarray:
        """Label of frame ``index`` in every group: (...,) -> (..., G) int64."""
        import numpy as np

        idx = np.asarray(index, dtype=np.int64)
        return np.stack(self.label_parts(idx), axis=-1)

    def columns(self, n: int) -> np.ndarray:
        """(G, n) int32: column of place i in group g, ``off_g + label_g(i)``."""
        import numpy as np

        lab = self.labels(np.arange(int(n)))
        return (lab + np.asarray(self.offsets)[None, :]).T.astype(np.int32)

    # -------------------------------------------------------------- display
    def describe(self) -> str:
        """A line for ``info``, e.g. ``mixed radix (48, 50)``."""
        if self.kind == "periods":
            return f"periods {self.sizes}"
        if self.kind == "mixed":
            return f"mixed radix {self.sizes}"
        return (
            f"hierarchical: {self.sizes[0]} segments of {self.segment} + fine "
            f"periods {self.sizes[1:]}"
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON form saved with a map."""
        return {"kind": self.kind, "sizes": list(self.sizes), "segment": self.segment}

    @classmethod
    def from_dict(cls, meta: dict[str, Any]) -> Groups:
        """Inverse of :meth:`to_dict`."""
        return cls(str(meta["kind"]), tuple(meta["sizes"]), int(meta.get("segment", 0)))


# ------------------------------------------------------------------ choices
def fine_periods(segment: int, r: int = 2) -> tuple[int, ...]:
    """The least-storage ``r`` pairwise co-prime periods with product >= ``segment``.

    Chosen among :func:`~rhythmic_jax.map.periods.candidate_periods` of ``segment`` at
    level 1 (e.g. ``fine_periods(50) == (8, 9)``); ``segment = 1`` needs none and
    gives ``(1,)``.
    """
    if segment < 2:
        return (1,)
    count = max(7, r + 5)
    return choose_periods(
        candidate_periods(int(segment), r, 1, count), [0.0] * count, segment, r
    )


def _budget(n: int, r: int, level: int) -> int:
    """Templates of a periods map of that ``r`` and ``level``: r level n^(1/r)."""
    for name, value, low in (("n", n, 2), ("r", r, 1), ("level", level, 1)):
        if not is_int(value):
            raise InputError(f"{name} must be an integer, got {name}={value!r}")
        if value < low:
            raise InputError(f"{name} must be >= {low}, got {name}={value}")
    return int(r) * int(level) * _iroot_ceil(int(n), int(r))


def choose_radices(n: int, r: int = 2, level: int = 1) -> tuple[int, ...]:
    """Mixed radices for ``n`` places in the storage of periods at ``r``, ``level``.

    The budget is ``r * level * ceil(n ** (1/r))`` templates (what a periods map
    of the same ``r`` and ``level`` keeps). The ``r - 1`` less significant radices
    are one value ``t``, the smallest for which ``ceil(n / t ** (r-1)) + (r-1) t``
    fits the budget: the most significant digit (the segment classifier) gets as
    many classes as the budget allows. E.g. ``choose_radices(2356, 2, 1) ==
    (55, 43)`` (98 templates); level 4 gives ``(337, 7)``.
    """
    budget = _budget(n, r, level)
    if r == 1:
        return (int(n),)
    for t in range(2, _iroot_ceil(n, r) + 1):
        top = -(-n // t ** (r - 1))
        if top + (r - 1) * t <= budget:
            return (top,) + (t,) * (r - 1)
    t = _iroot_ceil(n, r)  # unreachable: at t = root the sum is <= r * t
    return (-(-n // t ** (r - 1)),) + (t,) * (r - 1)


def choose_segment(n: int, r: int = 2, level: int = 1) -> int:
    """Segment length of a hierarchical map in the storage of periods at ``level``.

    The smallest ``s >= 2`` whose ``ceil(n / s)`` segment classes plus
    :func:`fine_periods` ``(s, r)`` fit ``r * level * ceil(n ** (1/r))``
    templates: as many segments as the budget allows. E.g.
    ``choose_segment(2356, 2, 1) == 28`` (85 + 6 + 7 = 98 templates).
    """
    budget = _budget(n, r, level)
    for s in range(2, n + 1):
        if -(-n // s) + sum(fine_periods(s, r)) <= budget:
            return s
    return n


# -------------------------------------------------------------------- specs
@dataclass(frozen=True)
class LayoutSpec:
    """A parsed layout string: ``kind`` and what the user fixed of it.

    ``sizes``: periods or radices (empty: chosen at fit); ``segment``:
    hierarchical segment length (0: chosen); ``fine``: hierarchical fine periods
    (empty: :func:`fine_periods`).
    """

    kind: str
    sizes: tuple[int, ...] = ()
    segment: int = 0
    fine: tuple[int, ...] = ()


_SYNTAX = (
    "periods | periods:T1,T2 | mixed | mixed:B1,..,Br | hierarchical | "
    "hierarchical:SEG | hierarchical:SEG:T1,T2"
)


def _ints(text: str, layout: str) -> tuple[int, ...]:
    try:
        out = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise InputError(
            f"{{opt:layout}} {layout!r}: {text!r} is not a comma-separated list "
            "of integers"
        ) from None
    if min(out) < 1:
        raise InputError(
            f"{{opt:layout}} {layout!r}: sizes must be positive, got {out}"
        )
    return out


def parse_layout(layout: str) -> LayoutSpec:
    """Parse a layout string (module docstring); one-line InputError when bad."""
    if not isinstance(layout, str):
        raise InputError(f"{{opt:layout}} must be a string ({_SYNTAX}), got {layout!r}")
    kind, colon, rest = layout.strip().partition(":")
    if kind not in KINDS:
        raise InputError(f"{{opt:layout}} {layout!r}: expected {_SYNTAX}")
    if not colon:
        return LayoutSpec(kind)
    if kind == "periods":
        sizes = _ints(rest, layout)
        Groups("periods", sizes)  # co-prime or a one-line error
        return LayoutSpec(kind, sizes)
    if kind == "mixed":
        sizes = _ints(rest, layout)
        if min(sizes) < 2:
            raise InputError(f"{{opt:layout}} {layout!r}: radices must be >= 2")
        return LayoutSpec(kind, sizes)
    seg_text, _, fine_text = rest.partition(":")
    (segment,) = _ints(seg_text, layout)[:1]
    if "," in seg_text:
        raise InputError(
            f"{{opt:layout}} {layout!r}: one segment length, then ':T1,T2'"
        )
    fine = _ints(fine_text, layout) if fine_text else ()
    if fine:
        Groups("hierarchical", (1,) + fine, segment)  # checks co-prime, product
    return LayoutSpec(kind, (), segment, fine)


def resolve_layout(spec: LayoutSpec, n: int, r: int = 2, level: int = 1) -> Groups:
    """The :class:`Groups` of a spec for ``n`` places (sizes chosen where not given).

    A ``periods`` spec without periods has no fixed answer (the map chooses them by
    training error); it is refused here.
    """
    if spec.kind == "periods":
        if not spec.sizes:
            raise InputError("layout 'periods' chooses its periods while fitting")
        groups = Groups("periods", spec.sizes)
    elif spec.kind == "mixed":
        groups = Groups("mixed", spec.sizes or choose_radices(n, r, level))
    else:
        segment = spec.segment or choose_segment(n, r, level)
        fine = spec.fine or fine_periods(segment, r)
        groups = Groups("hierarchical", (-(-n // segment),) + fine, segment)
    groups.check(n)
    return groups
