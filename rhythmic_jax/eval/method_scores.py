"""One method's row of an evaluation: accuracy, recall@K, the PR figures and,
for the figures, its curves, from its answers and one ground truth.

:func:`method_scores` is the one function every row of
:func:`rhythmic_jax.eval.report.evaluate_map` is scored by (the map, brute
force, SeqSLAM and the peers at the map's bytes), so each printed figure is
defined once.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["CURVE", "KS", "method_scores"]

KS = (1, 5, 10, 20)
CURVE = 20  # recall at every N = 1 .. CURVE, for the figures (curves=True)


def method_scores(
    pred, conf, ranked, truth, exact, ks, over="matched"
) -> dict[str, Any]:
    """Accuracy, recall@K (out of the queries ``over`` names), PR-AUC and recall
    at 100 % precision of one method."""
    from rhythmic_jax.eval.ground_truth import gt_accuracy, gt_pr_curve, gt_recall_at_k

    precision, recall, _ = gt_pr_curve(pred, conf, truth)
    row = {
        "accuracy": gt_accuracy(pred, exact if exact is not None else truth),
        "accuracy_tol": gt_accuracy(pred, truth) if exact is not None else None,
        **gt_recall_at_k(ranked, truth, ks, over),
        "recall_over": over,
        "recall_queries": int(truth.in_map.sum()) if over == "matched" else len(truth),
        "tolerance": truth.tolerance_frames
        if truth.tolerance_m is None
        else truth.tolerance_m,
        "n_queries": int(truth.in_map.sum()),
        "pr_auc": float(np.trapezoid(precision[::-1], recall[::-1])),
        "recall@100p": float(recall[precision == 1.0].max()),
    }
    row["_pr"] = (precision, recall)
    ranked = np.asarray(ranked)
    if ranked.ndim == 1:
        ranked = ranked[:, None]
    curve = gt_recall_at_k(ranked, truth, range(1, min(CURVE, ranked.shape[1]) + 1))
    row["_route"] = {  # for the figures of a route: kept with curves=True
        "recall_curve": list(curve.values()),
        "predictions": np.asarray(pred).astype(int).tolist(),
        "confidence": [float(c) if np.isfinite(c) else None
                       for c in np.asarray(conf, np.float64)],
        "correct": np.where(truth.in_map, truth.hits(np.asarray(pred, np.int64)),
                            np.asarray(pred) == -1).tolist(),
    }  # fmt: skip
    return row
