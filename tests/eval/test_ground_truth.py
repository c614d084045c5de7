"""Ground truth as sets of right places: the index alignment agrees with the
frame-tolerance metrics of rhythmic_jax.evaluate, ragged lists and positions agree
with plain loops, and evaluate_map follows whatever ground truth it is given."""

from __future__ import annotations

import numpy as np
import pytest

from rhythmic_jax import RhythmicMap
from rhythmic_jax.decoding.sequence import sequence_scores
from rhythmic_jax.errors import InputError
from rhythmic_jax.eval.ground_truth import (
    from_indices,
    from_lists,
    from_positions,
    gt_accuracy,
    gt_pr_curve,
    gt_recall_at_k,
)
from rhythmic_jax.eval.metrics import accuracy, pr_curve, recall_at_k
from rhythmic_jax.eval.report import evaluate_map, ranked_places

RNG = np.random.default_rng(0)


def test_index_alignment_as_sets_equals_the_frame_tolerance_metrics():
    b, n = 200, 150
    gt = RNG.integers(-1, n, b)
    pred = np.where(
        RNG.random(b) < 0.2, -1, np.clip(gt + RNG.integers(-3, 4, b), 0, n - 1)
    )
    ranked = RNG.integers(-1, n, (b, 10))
    ranked[:, 0] = pred
    score = RNG.random(b)
    for tol in (0, 2):
        truth = from_indices(gt, n, tol)
        assert gt_accuracy(pred, truth) == accuracy(pred, gt, tol)
        want = recall_at_k(ranked, gt, (1, 5, 10), tolerance=tol).as_dict()
        got = gt_recall_at_k(ranked, truth, (1, 5, 10))
        assert got == {k: want[k] for k in got}
        want = pr_curve(pred, score, gt, tol)
        for a, c in zip(gt_pr_curve(pred, score, truth), want, strict=True):
            np.testing.assert_allclose(a, c)
    assert from_indices([0, 1, -1], 2).positives[2].size == 0  # beyond the map


def test_ragged_lists_follow_a_plain_loop():
    b, n = 120, 40
    lists = [RNG.choice(n, RNG.integers(0, 4), replace=False) for _ in range(b)]
    truth = from_lists(lists, n, "test lists")
    ranked = np.stack([RNG.permutation(n)[:10] for _ in range(b)])
    pred = ranked[:, 0].copy()
    pred[RNG.random(b) < 0.1] = -1
    ranked[:, 0] = pred
    score = RNG.random(b)
    in_map = [i for i in range(b) if len(lists[i])]
    for k in (1, 5, 10):
        hits = [any(r in lists[i] for r in ranked[i, :k] if r >= 0) for i in in_map]
        assert gt_recall_at_k(ranked, truth, (k,))[f"recall@{k}"] == np.mean(hits)
    ok = [p in lists[i] if len(lists[i]) else p == -1 for i, p in enumerate(pred)]
    assert gt_accuracy(pred, truth) == np.mean(ok)
    precision, recall, thr = gt_pr_curve(pred, score, truth)
    points = zip(thr, precision[:-1], recall[:-1], strict=True)
    for t, p, r in points:  # every threshold, by hand
        taken = [i for i in range(b) if pred[i] >= 0 and score[i] >= t]
        tp = sum(pred[i] in lists[i] for i in taken)
        assert p == pytest.approx(tp / len(taken)) and r == pytest.approx(
            tp / len(in_map)
        )
    with pytest.raises(InputError, match="query 1 lists place 40, outside"):
        from_lists([[0], [40]], n, "bad")


def test_positions_within_the_radius_with_places():
    ref = RNG.uniform(0, 500, (300, 2))
    qry = RNG.uniform(0, 500, (80, 2))
    labels = np.arange(300) // 3  # three frames per place
    truth = from_positions(ref, qry, 25.0, labels)
    d = np.linalg.norm(qry[:, None] - ref[None], axis=2)
    for i in range(80):
        np.testing.assert_array_equal(truth.positives[i], np.unique(labels[d[i] <= 25]))
    assert truth.tolerance_m == 25.0 and truth.describe()["tolerance_m"] == 25.0
    assert 0 < truth.in_map.mean() < 1  # some queries have no place near them
    with pytest.raises(InputError, match="tolerance_m must be positive"):
        from_positions(ref, qry, 0.0)


@pytest.fixture(scope="module")
def fitted():
    x = RNG.normal(size=(60, 24)).astype(np.float32)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    q = x + 0.3 * RNG.normal(size=x.shape).astype(np.float32)
    return RhythmicMap().fit(x, progress=False), x, q


def test_evaluate_map_follows_lists_and_the_sequence(fitted):
    model, x, q = fitted
    lists = [[i, (i + 7) % 60] for i in range(60)]
    truth = from_lists(lists, 60, "two places per query")
    res = evaluate_map(model, q, reference=x, ground_truth=truth, timing=False)
    assert res["ground_truth"]["source"] == "two places per query"
    assert res["ground_truth"]["positives_per_query_mean"] == 2.0
    pred = model.predict(q)
    assert res["methods"]["map"]["accuracy"] == np.mean(
        [p in lists[i] for i, p in enumerate(pred)]
    )
    seq = evaluate_map(model, q, ground_truth=truth, sequence=4, timing=False)
    assert seq["recall_ranks"] == "sequence scores (L=4, speed 1)"
    ranked = ranked_places(
        sequence_scores(model.scores(q), model.periods, 4), model.periods, 60, 10
    )
    hits = [any(r in lists[i] for r in ranked[i, :5]) for i in range(60)]
    assert seq["methods"]["map"]["recall@5"] == np.mean(hits)
    pred4 = model.predict(q, sequence=4)
    assert seq["methods"]["map"]["accuracy"] == np.mean(
        [p in lists[i] for i, p in enumerate(pred4)]
    )
    with pytest.raises(InputError, match="60 queries but the ground truth"):
        evaluate_map(model, q, ground_truth=from_lists(lists[:5], 60, "short"))


def test_hits_equal_a_search_per_query():
    """The one sorted search gives each query's own membership, -1 and places
    past the map never hits."""
    rng = np.random.default_rng(0)
    lists = [rng.integers(0, 50, rng.integers(0, 6)) for _ in range(300)]
    gt = from_lists(lists, 50, "drawn")
    ranked = rng.integers(-1, 52, (300, 7))
    want = np.stack(
        [np.isin(r, p) & (r >= 0) for r, p in zip(ranked, gt.positives, strict=True)]
    )
    assert want.sum() > 20
    np.testing.assert_array_equal(gt.hits(ranked), want)
    np.testing.assert_array_equal(gt.hits(ranked[:, 0]), want[:, 0])
