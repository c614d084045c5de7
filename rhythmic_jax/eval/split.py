"""Splits by place: what is learned never sees the places that are scored.

A route is cut into a *training segment* and a disjoint *test segment* with a gap
between them, so that neighbouring frames (which look alike) do not leak from one
into the other. Everything learned (an embedding, a calibration, decode weights,
thresholds, a chosen setting) sees the training places only; maps are fitted and
queried on the test places. For tiled aerial pairs the unit held out is the whole
image pair.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.validate import check_int

__all__ = ["NORDLAND_SPLIT", "PlaceSplit", "route_split"]


@dataclass(frozen=True)
class PlaceSplit:
    """Disjoint place indices of one route.

    Attributes:
      train: int64 (n_train,) places that learning may see, in route order.
      test: int64 (n_test,) places that are scored, in route order.
      gap: places left out between the two segments (0 for pair splits).
    """

    train: np.ndarray
    test: np.ndarray
    gap: int

    def __post_init__(self):
        for name in ("train", "test"):
            idx = np.asarray(getattr(self, name))
            if idx.ndim != 1 or idx.size == 0:
                raise InputError(f"split: {name} must be a non-empty 1-D index array")
        shared = np.intersect1d(self.train, self.test)
        if shared.size:
            raise InputError(
                f"split: {shared.size} places are both train and test "
                f"(first: {int(shared[0])})"
            )

    def distance(self) -> int:
        """Smallest |i - j| between a training place i and a test place j."""
        train, test = np.sort(self.train), np.sort(self.test)
        pos = np.clip(np.searchsorted(train, test), 1, len(train)) - 1
        near = np.minimum(
            np.abs(test - train[pos]),
            np.abs(test - train[np.minimum(pos + 1, len(train) - 1)]),
        )
        return int(near.min())


def route_split(n: int, train_end: int, gap: int) -> PlaceSplit:
    """Places ``0 .. train_end-1`` train, ``train_end+gap .. n-1`` test.

    Args:
      n: places on the route.
      train_end: first place after the training segment, ``1 <= train_end < n``.
      gap: places dropped between the segments, ``>= 0``; a test place is then at
        least ``gap + 1`` indices from every training place.
    """
    for name, value, low in (("n", n, 2), ("train_end", train_end, 1), ("gap", gap, 0)):
        msg = f"split: {name} must be an integer >= {low}, got {value}"
        check_int(value, name, low, msg=msg)
    if train_end + gap >= n:
        raise InputError(
            f"split: train_end + gap = {train_end + gap} leaves no test place of n={n}"
        )
    return PlaceSplit(
        train=np.arange(train_end, dtype=np.int64),
        test=np.arange(train_end + gap, n, dtype=np.int64),
        gap=int(gap),
    )


#: Nordland (3576 places a season): places 0-1199 train, 1220-3575 test.
NORDLAND_SPLIT = route_split(3576, train_end=1200, gap=20)
