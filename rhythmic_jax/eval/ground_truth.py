"""Ground truth as a set of right places per query, and the metrics that follow it.

A :class:`GroundTruth` holds, for each of b queries, the sorted map places that
count as a correct answer (several for VPR-Bench lists or positions within a
radius; none when the query's place is not in the map). It comes from

* the index alignment "query i is place i", with a frame tolerance
  (:func:`from_indices`, what ``evaluate`` uses when given nothing else);
* per-query lists (:func:`from_lists`, e.g. VPR-Bench's ``ground_truth_new.npy``);
* positions in metres within ``tolerance_m`` (:func:`from_positions`, the
  Pittsburgh / Tokyo 24/7 convention of 25 m).

The metrics follow :mod:`rhythmic_jax.eval.metrics` with "correct" meaning "among the
query's positives": a query with no positives is right only when rejected
(accuracy) and is left out of recall@K, and the PR curve counts a retrieved one
as a false positive (VPR_Tutorial's ``createPR``, ``matching='single'``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.fitting.places import checked_positions

__all__ = [
    "GroundTruth",
    "from_indices",
    "from_lists",
    "from_positions",
    "gt_accuracy",
    "gt_pr_curve",
    "gt_recall_at_k",
]


@dataclass(frozen=True, eq=False)
class GroundTruth:
    """Right places per query.

    Attributes:
      positives: b sorted int64 arrays of map places (empty: not in the map).
      n_places: places of the map (every positive is below it).
      source: where it came from, said in reports.
      tolerance_m: the radius in metres, for ground truth from positions.
      tolerance_frames: the frame tolerance, for index-aligned ground truth.
    """

    positives: tuple[np.ndarray, ...]
    n_places: int
    source: str
    tolerance_m: float | None = None
    tolerance_frames: int | None = None

    def __len__(self) -> int:
        return len(self.positives)

    @property
    def in_map(self) -> np.ndarray:
        """(b,) bool: the query has at least one right place."""
        return np.array([len(p) > 0 for p in self.positives], bool)

    def hits(self, ranked) -> np.ndarray:
        """(b, K) candidate places (-1: none) -> (b, K) bool: among the positives."""
        ranked = np.asarray(ranked)
        if ranked.ndim == 1:
            return self.hits(ranked[:, None])[:, 0]
        if ranked.shape[0] != len(self):
            raise InputError(
                f"{ranked.shape[0]} queries but the ground truth ({self.source}) "
                f"covers {len(self)}"
            )
        # one sorted search over (query, place) keys, not a search per query
        n = max(self.n_places, 1)
        sizes = [len(p) for p in self.positives]
        rows = np.repeat(np.arange(len(sizes), dtype=np.int64), sizes)
        keys = rows * n + np.concatenate([np.empty(0, np.int64), *self.positives])
        ranked = ranked.astype(np.int64)
        inside = (ranked >= 0) & (ranked < n)
        asked = np.arange(len(sizes), dtype=np.int64)[:, None] * n + ranked
        return np.isin(asked, keys) & inside

    def describe(self) -> dict:
        """Source and tolerance, as ``evaluate --json`` reports them."""
        sizes = np.array([len(p) for p in self.positives])
        return {
            "source": self.source,
            "tolerance_m": self.tolerance_m,
            "tolerance_frames": self.tolerance_frames,
            "queries": len(self),
            "queries_in_map": int((sizes > 0).sum()),
            "positives_per_query_mean": float(sizes.mean()) if len(sizes) else 0.0,
        }


def from_lists(
    lists: Sequence[Sequence[int]], n_places: int, source: str
) -> GroundTruth:
    """Ground truth from one list of right places per query (ragged)."""
    out = []
    for i, row in enumerate(lists):
        p = np.unique(np.asarray(row, dtype=np.int64).reshape(-1))
        if p.size and (p[0] < 0 or p[-1] >= n_places):
            bad = p[0] if p[0] < 0 else p[-1]
            raise InputError(
                f"{source}: query {i} lists place {bad}, outside the map's "
                f"0..{n_places - 1}"
            )
        out.append(p)
    return GroundTruth(tuple(out), int(n_places), source)


def from_indices(gt, n_places: int, tolerance: int = 0) -> GroundTruth:
    """Query i is place ``gt[i]`` (-1: not in the map), give or take ``tolerance``
    frames: the convention of :mod:`rhythmic_jax.eval.metrics` as sets."""
    from rhythmic_jax.eval.metrics import _indices, _tolerance

    gt, tol = _indices(gt, "gt", 1), _tolerance(tolerance)
    lists = [
        np.arange(max(0, g - tol), min(n_places, g + tol + 1)) if g >= 0 else []
        for g in gt
    ]
    src = "index-aligned (query i is place i)"
    return GroundTruth(
        from_lists(lists, n_places, src).positives, n_places, src, None, tol
    )


def from_positions(
    reference_xy,
    query_xy,
    tolerance_m: float,
    reference_labels=None,
    source: str = "positions",
) -> GroundTruth:
    """Places with a reference frame within ``tolerance_m`` metres of each query.

    Args:
      reference_xy: (m, 2) positions of the reference frames in metres.
      query_xy: (b, 2) positions of the queries in metres.
      reference_labels: (m,) map place of each reference frame (default arange).
    """
    from scipy.spatial import cKDTree

    ref = checked_positions(reference_xy, "reference")
    qry = checked_positions(query_xy, "queries")
    if not tolerance_m > 0:
        raise InputError(f"{{opt:tolerance_m}} must be positive, got {tolerance_m}")
    labels = np.arange(len(ref)) if reference_labels is None else reference_labels
    labels = np.asarray(labels, np.int64)
    if labels.shape != (len(ref),):
        raise InputError(
            f"{len(ref)} reference positions but {labels.shape[0]} reference frames"
        )
    near = cKDTree(ref).query_ball_point(qry, r=float(tolerance_m))
    lists = [np.unique(labels[np.asarray(i, np.int64)]) for i in near]
    gt = from_lists(lists, int(labels.max()) + 1, source)
    return GroundTruth(gt.positives, gt.n_places, source, float(tolerance_m))


def gt_accuracy(pred, gt: GroundTruth) -> float:
    """Fraction right: a positive for in-map queries, a rejection (-1) otherwise."""
    pred = np.asarray(pred, np.int64)
    ok = np.where(gt.in_map, gt.hits(pred), pred == -1)
    return float(ok.mean())


def gt_recall_at_k(
    ranked, gt: GroundTruth, ks: Sequence[int], over: str = "matched"
) -> dict[str, float]:
    """``{"recall@k": ...}``: queries with a positive among the top k, out of
    the in-map queries (``over="matched"``) or of every query (``"all"``;
    :func:`rhythmic_jax.eval.metrics.recall_fractions`)."""
    from rhythmic_jax.eval.metrics import recall_fractions

    ranked = np.asarray(ranked, np.int64)
    if not gt.in_map.any():
        raise InputError(f"{gt.source}: no query has a right place in the map")
    hit = gt.hits(ranked)
    first = np.where(hit.any(1), hit.argmax(1), ranked.shape[1])
    got = recall_fractions(first, gt.in_map, ks, over)
    return {f"recall@{k}": v for k, v in got.items()}


def gt_pr_curve(pred, score, gt: GroundTruth) -> tuple[np.ndarray, ...]:
    """:func:`rhythmic_jax.eval.metrics.pr_curve`, "correct" = among the positives."""
    from rhythmic_jax.eval.metrics import pr_points

    pred = np.asarray(pred, np.int64)
    keep = pred >= 0
    return pr_points(
        np.asarray(score, np.float64)[keep], gt.hits(pred)[keep], int(gt.in_map.sum())
    )
