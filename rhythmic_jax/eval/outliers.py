"""Outlier rejection: a confidence per query, a threshold chosen on held-out frames.

A rhythmic map always answers with some place (or "no match" when the hard
decode's phases combine to an index ``>= n``); a query from a place the map never
saw must be rejected by a threshold on a confidence. Two confidences of a decoded
query, both higher-is-surer:

- ``"margin"``: ``best - runner_up`` of the :class:`~rhythmic_jax.decoding.hard.Decoded`
  result (soft / top-m: best summed phase score minus the best rival place more
  than ``exclude`` frames away; hard: the smallest per-period top-2 gap, the
  paper's "lower bound of decision value").
- ``"likelihood"``: the decode run on :func:`~rhythmic_jax.decoding.soft.calibrate`-d
  scores, confidence = the decoded place's summed per-period log-probability
  ``sum_k log softmax(s_k)[i mod tau_k]``.

The threshold is chosen on queries with known ground truth (in-map and out-of-map
ones, ``gt = -1``) that were not used to fit the map. :func:`choose_threshold`
takes the point of :func:`rhythmic_jax.eval.metrics.pr_curve` with the largest
recall among those with precision ``>= target_precision``;
:func:`quantile_threshold` needs only out-of-map queries and lets through at most
a fraction ``1 - quantile`` of them. :func:`reject` applies a threshold the way
``RhythmicMap.predict(threshold=)`` does: a query is kept when ``confidence >=
threshold``.

:func:`holdout_split` is the protocol that makes out-of-map queries from a route:
contiguous blocks of frames are left out of the fit (places outside the map); the
map is fitted on the kept frames, renumbered ``0 .. n_fit - 1``, and
:meth:`Holdout.gt` gives each route frame's map index, -1 for a held-out one.

Shapes: b queries, p = sum(periods) scores per query, n route frames.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import jax
import numpy as np

from rhythmic_jax.decoding.dispatch import DECODERS, decode_scores
from rhythmic_jax.decoding.hard import Decoded, check_scores
from rhythmic_jax.decoding.soft import calibrate, soft_decode, topm_decode
from rhythmic_jax.errors import InputError
from rhythmic_jax.eval.metrics import pr_curve
from rhythmic_jax.jit_options import jit
from rhythmic_jax.validate import check_int

__all__ = [
    "CONFIDENCES",
    "Holdout",
    "choose_threshold",
    "decode_confidence",
    "finite_confidence",
    "holdout_split",
    "quantile_threshold",
    "reject",
]

CONFIDENCES = ("margin", "likelihood")

_BIG = float(np.finfo(np.float64).max)

# the per-period log-softmax as one program (periods static), not one per op
_calibrated = jit(calibrate, static_argnums=1)


def finite_confidence(confidence) -> np.ndarray:
    """float64 copy with ``+inf -> float64 max`` and ``-inf -> -max`` (order kept).

    A soft decode without a rival place has ``confidence = inf``; the PR curve and
    threshold search need finite numbers.
    """
    c = np.asarray(confidence, np.float64)
    if np.isnan(c).any():
        raise InputError("confidence has NaN entries")
    return np.clip(c, -_BIG, _BIG)


def _decode(
    scores, periods: tuple[int, ...], n: int, method: str, top: int, exclude: int
) -> Decoded:
    if method == "soft":
        return soft_decode(scores, periods, n, exclude=exclude)
    if method == "topm":
        return topm_decode(scores, periods, n, top, exclude=exclude)
    return decode_scores(scores, periods, n, "hard")


def decode_confidence(
    scores,
    periods: Sequence[int],
    n: int,
    method: str = "soft",
    *,
    kind: str = "margin",
    top: int = 3,
    exclude: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Decode (b, p) scores and give every query a confidence.

    Args:
      scores: (b, p) decision values of single frames, or accumulated sequence
        scores (:func:`rhythmic_jax.decoding.sequence.sequence_scores`).
      periods, n: the map's periods and number of places.
      method: "hard" | "soft" | "topm" (``top`` phases per period).
      kind: "margin" (best minus runner-up) or "likelihood" (summed per-period
        log-probability of the decoded place, after ``calibrate``).
      exclude: rivals of soft / top-m must be more than ``exclude`` places away
        from the best (neighbours along a route look alike).

    Returns:
      index (b,) int64 (-1 = no match) and confidence (b,) finite float64,
      higher is surer (see :func:`finite_confidence`).
    """
    if method not in DECODERS:
        raise InputError(f"method must be one of {DECODERS}, got method={method!r}")
    if kind not in CONFIDENCES:
        raise InputError(f"kind must be one of {CONFIDENCES}, got kind={kind!r}")
    per = tuple(int(t) for t in periods)
    scores = scores if isinstance(scores, jax.Array) else jax.device_put(scores)
    if kind == "likelihood":
        check_scores(scores, per)  # one-line errors before the program
        scores = _calibrated(scores, per)
    out = _decode(scores, per, n, method, top, exclude)
    conf = out.confidence if kind == "margin" else out.score
    index = np.asarray(out.index).astype(np.int64)
    return index, finite_confidence(conf)


def reject(index, confidence, threshold: float | None) -> np.ndarray:
    """index (b,) with -1 where ``confidence < threshold`` (None keeps every query).

    The rule of ``RhythmicMap.predict(threshold=)``: a query is kept when
    ``confidence >= threshold``. Returns int64 (b,).
    """
    index = np.asarray(index)
    conf = np.asarray(confidence, np.float64)
    if index.shape != conf.shape or index.ndim != 1:
        raise InputError(
            f"index and confidence must be (b,) arrays of one shape, got "
            f"{index.shape} and {conf.shape}"
        )
    index = index.astype(np.int64)
    if threshold is None:
        return index
    if math.isnan(threshold):
        raise InputError("threshold is NaN")
    return np.where(conf >= threshold, index, -1)


def choose_threshold(
    pred, confidence, gt, *, tolerance: int, target_precision: float = 1.0
) -> float:
    """The threshold of largest recall at precision ``>= target_precision``.

    Measured on held-out queries with known ground truth (``gt = -1`` for a place
    outside the map): over the points of :func:`rhythmic_jax.eval.metrics.pr_curve`
    (every distinct confidence of a retrieved query is a threshold ``t``, kept
    when ``confidence >= t``) it returns the ``t`` with the largest recall among
    those with ``precision >= target_precision``; on a tie in recall, the larger
    ``t``. ``inf`` (reject everything) when no threshold reaches the target.

    Args:
      pred: (b,) int best match, -1 for no match (never retrieved).
      confidence: (b,) confidence of that match, higher is surer.
      gt: (b,) int true index, -1 for a place not in the map.
      tolerance: frames of slack for a correct match.
      target_precision: in (0, 1].
    """
    if not 0.0 < target_precision <= 1.0:
        raise InputError(
            f"target_precision must lie in (0, 1], got {target_precision!r}"
        )
    precision, recall, thresholds = pr_curve(
        pred, finite_confidence(confidence), gt, tolerance
    )
    precision, recall = precision[:-1], recall[:-1]  # drop the (1, 0) end point
    ok = (precision >= target_precision) & (recall > 0)
    if not ok.any():
        return math.inf
    best = recall[ok].max()
    return float(thresholds[ok & (recall == best)].max())


def quantile_threshold(outlier_confidence, quantile: float = 0.99) -> float:
    """The lowest threshold that lets through at most ``1 - quantile`` of outliers.

    With ``c`` the confidences of out-of-map queries (b,) sorted in decreasing
    order and ``k = floor((1 - quantile) * b)``, the threshold is the next float
    above ``c[k]``: at most ``k`` outliers have ``confidence >= threshold``.
    """
    c = finite_confidence(outlier_confidence)
    if c.ndim != 1 or c.size == 0:
        raise InputError(
            f"outlier_confidence must be a non-empty (b,) array, got {c.shape}"
        )
    if not 0.0 <= quantile <= 1.0:
        raise InputError(f"quantile must lie in [0, 1], got {quantile!r}")
    k = int(math.floor((1.0 - quantile) * c.size + 1e-9))
    if k >= c.size:
        return -math.inf
    c = np.sort(c)[::-1]
    return float(np.nextafter(c[k], math.inf))


class Holdout(NamedTuple):
    """Route frames split into a fitted map and held-out places.

    fit: (n_fit,) sorted int64 route indices the map is fitted on (map index
    ``j`` is route frame ``fit[j]``). held: (n_held,) sorted int64 route indices
    left out, in contiguous blocks.
    """

    fit: np.ndarray
    held: np.ndarray

    def gt(self) -> np.ndarray:
        """(n,) int64 map index of every route frame, -1 for a held-out one."""
        out = np.full(len(self.fit) + len(self.held), -1, np.int64)
        out[self.fit] = np.arange(len(self.fit))
        return out


def holdout_split(n: int, fraction: float = 0.2, seed: int = 0, block: int = 50):
    """Hold out contiguous blocks of a route of ``n`` frames (places not mapped).

    The route is cut into ``ceil(n / block)`` slots of ``block`` frames (the last
    may be shorter); ``k = round(fraction * n / block)`` slots are held out, one
    drawn at random from each of ``k`` equal strata of the slots, so held-out
    places are spread along the whole route (both halves get some when ``k >=
    2``). Deterministic for a ``seed``.

    Returns:
      :class:`Holdout` with the kept and held-out route indices.
    """
    for name, v in (("n", n), ("block", block), ("seed", seed)):
        check_int(v, name, msg=f"holdout_split: {name} must be an integer, got {v!r}")
    if n < 2 or block < 1 or seed < 0:
        raise InputError(
            f"holdout_split needs n >= 2, block >= 1, seed >= 0; got n={n}, "
            f"block={block}, seed={seed}"
        )
    if not 0.0 <= fraction < 1.0:
        raise InputError(f"holdout_split: fraction must lie in [0, 1), got {fraction}")
    slots = -(-n // block)
    k = min(int(round(fraction * n / block)), slots - 1)
    rng = np.random.default_rng(seed)
    edges = np.linspace(0, slots, k + 1).round().astype(int)
    chosen = [
        int(rng.integers(lo, hi)) for lo, hi in zip(edges[:-1], edges[1:], strict=True)
    ]
    held = np.zeros(n, bool)
    for s in chosen:
        held[s * block : (s + 1) * block] = True
    return Holdout(np.flatnonzero(~held), np.flatnonzero(held))
