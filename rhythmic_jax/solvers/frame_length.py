"""The length of the frames a solve takes: the penalty ``C = log N`` and the
solvers' float32 products expect frames of order one.

:func:`check_length` refuses, in one line, frames whose RMS length lies outside
:data:`LENGTH_RANGE`, and says by how much to scale them. The in-memory fit
(:func:`rhythmic_jax.fitting.fit_map.fit`), the fit from files
(:mod:`rhythmic_jax.fitting.scale_fit`) and the estimator's ``scale="auto"``
(:func:`rhythmic_jax.estimator_inputs.not_of_order_one`) all ask it.

Shapes: sums as :func:`rhythmic_jax.validate.scale_sums` gives them.
"""

from __future__ import annotations

import numpy as np

from rhythmic_jax.errors import InputError

__all__ = ["LENGTH_RANGE", "check_length"]

# The RMS length of the frames (rows) the solver fits, C = log N taken as it is.
# Measured on 300 Nordland summer frames (patch-normalised, length 1) scaled by
# s, the default map's share of its own frames placed: s = 1e-30..1e-6: 0.003
# (templates of zero: every frame answers place 0), 1e-4: 0.45, 1e-3..1e-2:
# 0.48, 0.1: 0.77, 1: 0.99, 10..100: 0.98 (100: 37x the time of 1), 1e3 and
# beyond: the solve ends in NaN; 1e30: 0.003. Inside the range a fit works,
# outside it the frames are refused, and told by how much to scale them.
LENGTH_RANGE = (1e-3, 1e2)


def check_length(sums, name: str = "reference features") -> None:
    """Refuse (one :class:`InputError` line) frames whose RMS length (from
    :func:`rhythmic_jax.validate.scale_sums`) lies outside :data:`LENGTH_RANGE`:
    the solver's float32 products overflow above it, and below it the penalty
    ``C = log N`` leaves templates of zero (every frame placed at 0)."""
    sums = np.asarray(sums, np.float64)
    length = float(np.sqrt(sums[-2] / max(float(sums[-1]), 1.0)))
    lo, hi = LENGTH_RANGE
    if lo <= length <= hi or not np.isfinite(length) or length == 0.0:
        return  # zero or non-finite frames: the features' own checks say so
    raise InputError(
        f"{name}: frames of RMS length {length:.1e}, outside [{lo:g}, {hi:g}]: the "
        "solvers expect features of order one (the penalty C = log N takes frames "
        f"of length about 1); multiply them by about {1 / length:.0e} (or "
        "L2-normalise each frame) and scale queries alike"
    )
