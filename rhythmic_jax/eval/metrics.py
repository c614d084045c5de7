"""Place-recognition metrics: accuracy, recall@K, precision-recall.

The timing of queries (latency, throughput) is :mod:`rhythmic_jax.eval.timing`'s;
its functions are importable from here too.

Conventions (shared by every function here):

- ``pred`` (b,) int: the predicted reference index in ``[0, n)``, or ``-1`` for
  "no match" (the query was rejected).
- ``gt`` (b,) int: the true reference index of each query, or ``-1`` when the
  query's place is not in the map (an outlier that should be rejected). With
  queries taken from the map itself ``gt = arange(b)``. Or a
  :class:`~rhythmic_jax.eval.ground_truth.GroundTruth` (what
  ``rj.load_ground_truth`` reads): several right places per query, none for a
  query not in the map; "correct" is then "among the query's right places".
- ``tolerance`` (int >= 0): with index ``gt``, a prediction is correct when
  ``|pred - gt| <= tolerance`` frames (0 is the paper's exact accuracy). Reports
  should always print it; :class:`RecallAtK` carries it with the numbers. A
  ``GroundTruth`` holds its right places already, so it takes no tolerance.
- ``over`` (:data:`RECALL_OVER`): recall@K's denominator. ``"matched"``: the
  queries that have a right place (VPR_Tutorial's ``recallAtK`` drops the
  others); ``"all"``: every query (VPR-methods-evaluation divides by
  ``num_queries``; a query without a right place then counts as a miss).

The precision-recall curve follows the single-best-match convention of
VPR_Tutorial (``evaluation/metrics.py::createPR``, Schubert et al. 2023) and
VPR-Bench, with every distinct score as a threshold instead of 100 evenly
spaced ones, laid out like ``sklearn.metrics.precision_recall_curve``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.eval.timing import query_latency as query_latency
from rhythmic_jax.eval.timing import time_batch as time_batch
from rhythmic_jax.eval.timing import time_single_queries as time_single_queries
from rhythmic_jax.validate import check_int

__all__ = [
    "RECALL_OVER",
    "RecallAtK",
    "accuracy",
    "pr_auc",
    "pr_curve",
    "pr_points",
    "recall_at_100_precision",
    "recall_at_k",
    "recall_fractions",
    "recall_line",
    "time_batch",
    "time_single_queries",
]


def _indices(a, name: str, ndim: int) -> np.ndarray:
    """``a`` as an int64 array of rank ``ndim`` with every entry >= -1."""
    a = np.asarray(a)
    if a.ndim != ndim:
        raise InputError(f"{name} must have {ndim} dimension(s), got shape {a.shape}")
    if a.size and not np.issubdtype(a.dtype, np.integer):
        raise InputError(f"{name} must hold integer indices, got dtype {a.dtype}")
    a = a.astype(np.int64)
    if a.size and a.min() < -1:
        raise InputError(f"{name} has index {a.min()}; indices are >= 0, or -1")
    return a


RECALL_OVER = ("matched", "all")


def _tolerance(tolerance) -> int:
    msg = f"tolerance must be an integer >= 0, got {tolerance!r}"
    return check_int(tolerance, "tolerance", 0, msg=msg)


def _pred_gt(pred, gt) -> tuple[np.ndarray, np.ndarray]:
    pred, gt = _indices(pred, "pred", 1), _indices(gt, "gt", 1)
    if pred.shape != gt.shape:
        raise InputError(f"pred has shape {pred.shape} but gt has shape {gt.shape}")
    if pred.size == 0:
        raise InputError("pred and gt are empty: no query to evaluate")
    return pred, gt


def _ground_truth(gt, tolerance):
    """``gt`` when it is a :class:`GroundTruth` (then ``tolerance`` must be None),
    else None (index arrays: ``tolerance`` is theirs). Known by what it holds
    (``positives``, ``in_map``, ``hits``): :mod:`rhythmic_jax.eval.ground_truth`
    builds on this module, not the other way."""
    if not all(hasattr(gt, a) for a in ("positives", "in_map", "hits", "source")):
        return None
    if tolerance is not None:
        raise InputError(
            f"tolerance {tolerance!r} with a GroundTruth ({gt.source}): its right "
            "places are given; a tolerance acts on index arrays only"
        )
    return gt


def _checked_pred(pred, gt) -> np.ndarray:
    """``pred`` (b,) as int64, one per query of the GroundTruth ``gt``."""
    pred = _indices(pred, "pred", 1)
    if pred.shape[0] != len(gt):
        raise InputError(
            f"pred has {pred.shape[0]} entries but the ground truth ({gt.source}) "
            f"covers {len(gt)} queries"
        )
    if pred.size == 0:
        raise InputError("pred and gt are empty: no query to evaluate")
    return pred


def _correct(pred: np.ndarray, gt: np.ndarray, tolerance: int) -> np.ndarray:
    """(...) bool: a real match within ``tolerance`` of a place that is in the map."""
    return (pred >= 0) & (gt >= 0) & (np.abs(pred - gt) <= tolerance)


def accuracy(pred, gt, tolerance: int | None = None) -> float:
    """Fraction of queries answered correctly.

    A query whose place is in the map (``gt[i] >= 0``) is correct when
    ``pred[i] != -1`` and ``|pred[i] - gt[i]| <= tolerance``; an outlier
    (``gt[i] == -1``) is correct when it is rejected (``pred[i] == -1``).
    ``tolerance = 0`` is the paper's accuracy (Table 2: queries from the map).

    With a ``GroundTruth``, a query with right places is correct when
    ``pred[i]`` is one of them, one without when it is rejected.

    Args:
      pred: (b,) int predicted indices, -1 for no match.
      gt: (b,) int true indices, -1 for a place not in the map; or a GroundTruth.
      tolerance: frames of slack, >= 0 (index ``gt`` only; default 0).
    """
    truth = _ground_truth(gt, tolerance)
    if truth is not None:
        pred = _checked_pred(pred, truth)
        return float(np.where(truth.in_map, truth.hits(pred), pred == -1).mean())
    pred, gt = _pred_gt(pred, gt)
    tol = _tolerance(0 if tolerance is None else tolerance)
    ok = np.where(gt >= 0, _correct(pred, gt, tol), pred == -1)
    return float(ok.mean())


@dataclass(frozen=True)
class RecallAtK:
    """Recall@K for several K, with the tolerance and query count it was taken at.

    ``r[k]`` is the recall at ``k``; ``str(r)`` prints the tolerance beside it
    (or, for a ``GroundTruth`` without a frame tolerance, its source).
    ``n_queries`` is the denominator: the queries with a right place
    (``over="matched"``) or every query (``over="all"``).
    """

    recall: Mapping[int, float]
    tolerance: int | None
    n_queries: int
    over: str = "matched"
    ground_truth: str | None = None

    def __getitem__(self, k: int) -> float:
        return self.recall[k]

    def as_dict(self) -> dict[str, float | int]:
        """Flat record for a report: ``{"tolerance", "n_queries", "recall@k"...}``."""
        out: dict[str, float | int | str] = {
            "tolerance": self.tolerance,
            "n_queries": self.n_queries,
            "recall_over": self.over,
        }
        out.update({f"recall@{k}": v for k, v in self.recall.items()})
        return out

    def __str__(self) -> str:
        rs = "  ".join(f"R@{k} {v:.4f}" for k, v in self.recall.items())
        which = "with a right place" if self.over == "matched" else "in all"
        judged = (
            f"tolerance ±{self.tolerance} frames"
            if self.tolerance is not None
            else f"ground truth: {self.ground_truth}"
        )
        return f"{rs}  ({judged}, over {self.n_queries} queries {which})"


def recall_fractions(
    first, in_map, ks: Sequence[int], over: str = "matched"
) -> dict[int, float]:
    """Recall@k for each k from each query's first right rank.

    ``first`` (b,) int: the rank of the first right candidate (K or more: none);
    ``in_map`` (b,) bool: the query has a right place. ``over="matched"``
    divides the queries with a right place found within k by ``in_map.sum()``,
    ``over="all"`` by b (the queries without one are misses).
    """
    if over not in RECALL_OVER:
        raise InputError(
            f"{{opt:recall_over}} must be one of {RECALL_OVER}, got {over!r}"
        )
    first, in_map = np.asarray(first), np.asarray(in_map, bool)
    if not in_map.any():
        raise InputError("no query has a right place in the map")
    hit = first[in_map]
    total = int(in_map.sum()) if over == "matched" else len(first)
    return {int(k): int((hit < k).sum()) / total for k in ks}


def recall_at_k(
    ranked,
    gt,
    ks: Sequence[int] = (1, 5, 10),
    *,
    tolerance: int | None = None,
    over="matched",
) -> RecallAtK:
    """Recall@K: fraction of in-map queries with a correct match among the top K.

    ``recall@k = #{i : gt[i] >= 0, exists j < k, |ranked[i, j] - gt[i]| <= tol}
    / #{i : gt[i] >= 0}``. Outlier queries (``gt == -1``) are left out, as in
    VPR_Tutorial's ``recallAtK``; with ``over="all"`` the denominator is every
    query, as in VPR-methods-evaluation. ``-1`` entries of ``ranked`` never count.
    With a ``GroundTruth`` (several right places per query), a hit is a
    candidate among the query's right places and the in-map queries are those
    with at least one.

    Args:
      ranked: (b, K) int candidate indices, best first.
      gt: (b,) int true indices, -1 for a place not in the map; or a GroundTruth.
      ks: the K values, each in ``[1, K]``.
      tolerance: frames of slack, >= 0 (required with index ``gt``, so that it
        is always stated; none with a GroundTruth, which holds its right places).
      over: ``"matched"`` or ``"all"`` (:data:`RECALL_OVER`).
    """
    ranked = _indices(ranked, "ranked", 2)
    ks = tuple(int(k) for k in ks)
    if not ks or min(ks) < 1 or max(ks) > ranked.shape[1]:
        raise InputError(f"ks must lie in [1, {ranked.shape[1]}] (columns of ranked)")
    truth = _ground_truth(gt, tolerance)
    if truth is not None:
        return _recall_of_sets(ranked, truth, ks, over)
    if tolerance is None:
        raise InputError(
            "recall_at_k with index gt needs tolerance= (frames, >= 0), so that "
            "it is stated"
        )
    gt = _indices(gt, "gt", 1)
    tol = _tolerance(tolerance)
    if ranked.shape[0] != gt.shape[0]:
        raise InputError(
            f"ranked has {ranked.shape[0]} rows but gt has {gt.shape[0]} entries"
        )
    inmap = gt >= 0
    if not inmap.any():
        raise InputError("gt has no query whose place is in the map (all -1)")
    hit = _correct(ranked, gt[:, None], tol)  # (b, K), no hit where gt is -1
    first = np.where(hit.any(1), hit.argmax(1), ranked.shape[1])  # (b,)
    recall = recall_fractions(first, inmap, ks, over)
    n = int(inmap.sum()) if over == "matched" else len(gt)
    return RecallAtK(recall=recall, tolerance=tol, n_queries=n, over=over)


def _recall_of_sets(ranked: np.ndarray, truth, ks, over: str) -> RecallAtK:
    """:func:`recall_at_k` on a GroundTruth: a hit is among the right places."""
    if ranked.shape[0] != len(truth):
        raise InputError(
            f"ranked has {ranked.shape[0]} rows but the ground truth "
            f"({truth.source}) covers {len(truth)} queries"
        )
    inmap = truth.in_map
    if not inmap.any():
        raise InputError(f"{truth.source}: no query has a right place in the map")
    hit = truth.hits(ranked)  # (b, K)
    first = np.where(hit.any(1), hit.argmax(1), ranked.shape[1])  # (b,)
    recall = recall_fractions(first, inmap, ks, over)
    n = int(inmap.sum()) if over == "matched" else len(truth)
    return RecallAtK(recall=recall, tolerance=truth.tolerance_frames, n_queries=n,
                     over=over, ground_truth=truth.source)  # fmt: skip


def recall_line(row: Mapping[str, float | None], ks=(1, 5, 10, 20)) -> str:
    """Recall@K in the form VPR papers quote, in percent with one decimal:
    ``R@1: 47.3, R@5: 61.0, R@10: 66.2, R@20: 70.9`` (the line
    VPR-methods-evaluation prints). ``row`` holds ``"recall@k"`` fractions;
    a K it lacks (or holds None for) is left out. Where ``row`` names its
    denominator (``"recall_over"`` and ``"recall_queries"``) the line says it:
    ``(over 100 queries with a right place)`` or ``(over all 111 queries)``."""
    parts = [
        f"R@{k}: {100 * row[f'recall@{k}']:.1f}"
        for k in ks
        if row.get(f"recall@{k}") is not None
    ]
    line = ", ".join(parts)
    over, n = row.get("recall_over"), row.get("recall_queries")
    if parts and over is not None and n is not None:
        matched = over == "matched"
        line += f" (over {n} queries with a right place)" if matched else (
            f" (over all {n} queries)")  # fmt: skip
    return line


def pr_curve(pred, score, gt, tolerance: int | None = None) -> tuple[np.ndarray, ...]:
    """Precision-recall curve of single-best matches over a confidence threshold.

    A query is retrieved at threshold ``t`` when ``pred != -1`` and ``score >= t``
    (queries with ``pred == -1`` are never retrieved). At each distinct score
    ``t``::

        TP = #{retrieved, correct within tolerance}
        precision = TP / #{retrieved}
        recall = TP / #{i : gt[i] >= 0}

    so a retrieved outlier, or a wrong match, is a false positive, and recall
    is out of every query whose place is in the map (VPR_Tutorial ``createPR``
    with ``matching='single'``). Unlike ``sklearn.metrics.precision_recall_curve``
    (whose recall is out of the correct matches) the curve need not reach
    recall 1. Layout as in scikit-learn: thresholds increasing, and a last point
    ``(precision 1, recall 0)``.

    Args:
      pred: (b,) int best match per query, -1 for no match.
      score: (b,) float confidence of that match, higher is surer (for a
        distance, pass its negative).
      gt: (b,) int true indices, -1 for a place not in the map; or a
        GroundTruth (correct: among the query's right places; recall out of
        the queries that have one).
      tolerance: frames of slack, >= 0 (required with index ``gt``; none with
        a GroundTruth).

    Returns:
      precision (m + 1,), recall (m + 1,), thresholds (m,), m = distinct scores
      of the retrieved queries.
    """
    truth = _ground_truth(gt, tolerance)
    if truth is not None:
        pred = _checked_pred(pred, truth)
        score = np.asarray(score, dtype=np.float64)
        if score.shape != pred.shape:
            raise InputError(f"score has shape {score.shape} but pred has {pred.shape}")
        keep = pred >= 0
        return pr_points(score[keep], truth.hits(pred)[keep], int(truth.in_map.sum()))
    if tolerance is None:
        raise InputError("pr_curve with index gt needs a tolerance (frames, >= 0)")
    pred, gt = _pred_gt(pred, gt)
    tol = _tolerance(tolerance)
    score = np.asarray(score, dtype=np.float64)
    if score.shape != pred.shape:
        raise InputError(f"score has shape {score.shape} but pred has {pred.shape}")
    if not np.isfinite(score).all():
        raise InputError("score has NaN or infinite entries")
    n_pos = int((gt >= 0).sum())
    if n_pos == 0:
        raise InputError("gt has no query whose place is in the map (all -1)")
    keep = pred >= 0
    return pr_points(score[keep], _correct(pred, gt, tol)[keep], n_pos)


def pr_points(s, ok, n_pos: int) -> tuple[np.ndarray, ...]:
    """The PR curve of retrieved queries' scores ``s`` (r,) and correctness ``ok``
    (r,) bool, recall out of ``n_pos`` queries (layout of :func:`pr_curve`)."""
    s, ok = np.asarray(s, np.float64), np.asarray(ok, bool)
    if not np.isfinite(s).all():
        raise InputError("score has NaN or infinite entries")
    if n_pos < 1:
        raise InputError("no query whose place is in the map")
    order = np.argsort(-s, kind="stable")
    s, ok = s[order], ok[order]
    ends = np.r_[np.flatnonzero(np.diff(s)), s.size - 1] if s.size else np.zeros(0, int)
    tp = np.cumsum(ok)[ends]
    precision = tp / (ends + 1)
    recall = tp / n_pos
    return (
        np.r_[precision[::-1], 1.0],
        np.r_[recall[::-1], 0.0],
        s[ends][::-1].copy(),
    )


def pr_auc(pred, score, gt, tolerance: int | None = None) -> float:
    """Area under :func:`pr_curve` by the trapezoidal rule (VPR_Tutorial's AUC).

    Same arguments as :func:`pr_curve` (a GroundTruth too); equals
    ``sklearn.metrics.auc(recall, precision)`` on its points.
    """
    precision, recall, _ = pr_curve(pred, score, gt, tolerance)
    return float(np.trapezoid(precision[::-1], recall[::-1]))


def recall_at_100_precision(pred, score, gt, tolerance: int | None = None) -> float:
    """Largest recall of :func:`pr_curve` at precision exactly 1 (0 if none).

    Same arguments as :func:`pr_curve` (a GroundTruth too).
    """
    precision, recall, _ = pr_curve(pred, score, gt, tolerance)
    return float(recall[precision == 1.0].max())
