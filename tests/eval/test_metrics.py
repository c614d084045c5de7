"""Metrics against scikit-learn, brute-force loops and hand-computed cases."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest
from sklearn.metrics import auc, precision_recall_curve, top_k_accuracy_score

from rhythmic_jax.errors import InputError
from rhythmic_jax.eval.metrics import (
    accuracy,
    pr_auc,
    pr_curve,
    recall_at_100_precision,
    recall_at_k,
)
from rhythmic_jax.map.periods import database_bytes, storage_bytes


def random_case(b: int, n: int, seed: int, p_reject=0.0, p_outlier=0.0):
    """pred (b,), score (b,) with ties, gt (b,) with outliers (-1)."""
    rng = np.random.default_rng(seed)
    gt = rng.integers(0, n, b)
    gt[rng.random(b) < p_outlier] = -1
    pred = np.where(rng.random(b) < 0.6, gt, rng.integers(0, n, b))
    pred[rng.random(b) < p_reject] = -1
    score = rng.integers(0, 12, b) / 4.0  # few distinct values: many ties
    return pred, score, gt


# Hand case: q3 rejected, q4 an outlier that is (wrongly) matched, ties at 0.8.
PRED = np.array([0, 5, 2, -1, 7, 4])
GT = np.array([0, 1, 2, 3, -1, 4])
SCORE = np.array([0.9, 0.8, 0.8, 0.95, 0.5, 0.1])


def test_accuracy_hand_case():
    assert accuracy(PRED, GT) == pytest.approx(3 / 6)
    assert accuracy(PRED, GT, tolerance=4) == pytest.approx(4 / 6)
    # a rejected outlier is right, a rejected in-map query is wrong at any tolerance
    assert accuracy([-1, -1], [-1, 3], tolerance=100) == 0.5


def test_accuracy_matches_loop():
    pred, _, gt = random_case(300, 50, seed=3, p_reject=0.2, p_outlier=0.2)
    for tol in (0, 1, 3):
        ok = []
        for p, g in zip(pred, gt, strict=True):
            ok.append(p == -1 if g == -1 else (p != -1 and abs(p - g) <= tol))
        assert accuracy(pred, gt, tol) == pytest.approx(np.mean(ok))
    assert accuracy(jnp.asarray(pred), jnp.asarray(gt)) == accuracy(pred, gt)


def test_recall_at_k_matches_sklearn_top_k_accuracy():
    rng = np.random.default_rng(4)
    b, n = 200, 30
    S = rng.standard_normal((b, n))
    gt = rng.integers(0, n, b)
    S[np.arange(b), gt] += 1.5  # make the true place likely near the top
    ranked = np.argsort(-S, axis=1)[:, :10]
    r = recall_at_k(ranked, gt, ks=(1, 5, 10), tolerance=0)
    for k in (1, 5, 10):
        ref = top_k_accuracy_score(gt, S, k=k, labels=np.arange(n))
        assert r[k] == pytest.approx(ref)
    assert r.n_queries == b and r.tolerance == 0


def test_recall_at_k_tolerance_outliers_and_loop():
    rng = np.random.default_rng(5)
    b, n, K = 150, 40, 6
    ranked = rng.integers(-1, n, (b, K))
    gt = rng.integers(0, n, b)
    gt[::7] = -1
    for tol in (0, 2):
        r = recall_at_k(ranked, gt, ks=(1, 3, 6), tolerance=tol)
        for k in (1, 3, 6):
            hits = [
                any(c != -1 and abs(c - g) <= tol for c in row[:k])
                for row, g in zip(ranked, gt, strict=True)
                if g != -1
            ]
            assert r[k] == pytest.approx(np.mean(hits))
        assert r[1] <= r[3] <= r[6]
        assert r.n_queries == int((gt != -1).sum())
        assert f"±{tol}" in str(r) and r.as_dict()["tolerance"] == tol


def test_pr_curve_hand_case_with_ties_and_outlier():
    precision, recall, thresholds = pr_curve(PRED, SCORE, GT, tolerance=0)
    # retrieved at 0.9: {q0 ok}; at 0.8: + {q1 wrong, q2 ok}; at 0.5: + {q4
    # outlier}; at 0.1: + {q5 ok}. Five queries have a place in the map.
    np.testing.assert_allclose(thresholds, [0.1, 0.5, 0.8, 0.9])
    np.testing.assert_allclose(precision, [3 / 5, 2 / 4, 2 / 3, 1, 1])
    np.testing.assert_allclose(recall, [3 / 5, 2 / 5, 2 / 5, 1 / 5, 0])
    area = 0.2 * 1 + 0.2 * (1 + 2 / 3) / 2 + 0.2 * (0.5 + 0.6) / 2
    assert pr_auc(PRED, SCORE, GT, 0) == pytest.approx(area)
    assert recall_at_100_precision(PRED, SCORE, GT, 0) == pytest.approx(0.2)
    # with 4 frames of tolerance q1 (5 for 1) is right: precision 1 down to 0.8
    assert recall_at_100_precision(PRED, SCORE, GT, 4) == pytest.approx(0.6)


def test_pr_curve_matches_sklearn_when_all_queries_are_in_the_map():
    """Every query matched and in the map: precision and thresholds are
    scikit-learn's; its recall is out of the correct matches, ours out of all
    queries, so ours is scikit-learn's times (#correct / #queries)."""
    pred, score, gt = random_case(400, 60, seed=6)
    correct = pred == gt
    p_sk, r_sk, t_sk = precision_recall_curve(correct, score)
    p, r, t = pr_curve(pred, score, gt, tolerance=0)
    np.testing.assert_allclose(t, t_sk)
    np.testing.assert_allclose(p, p_sk)
    np.testing.assert_allclose(r, r_sk * correct.mean())
    assert pr_auc(pred, score, gt, 0) == pytest.approx(auc(r_sk * correct.mean(), p_sk))


def test_pr_curve_matches_sklearn_with_unretrievable_positives():
    """General case (rejections, outliers, tolerance): each in-map query without a
    correct retrieved match is a positive that no threshold retrieves, i.e. a
    positive scored below every real score; drop scikit-learn's point there."""
    pred, score, gt = random_case(500, 80, seed=7, p_reject=0.15, p_outlier=0.2)
    tol = 2
    retrieved = pred >= 0
    ok = retrieved & (gt >= 0) & (np.abs(pred - gt) <= tol)
    missed = int(((gt >= 0) & ~ok).sum())
    y = np.r_[ok[retrieved], np.ones(missed, bool)]
    s = np.r_[score[retrieved], np.full(missed, score.min() - 1.0)]
    p_sk, r_sk, t_sk = precision_recall_curve(y, s)
    p, r, t = pr_curve(pred, score, gt, tolerance=tol)
    np.testing.assert_allclose(t, t_sk[1:])
    np.testing.assert_allclose(p, p_sk[1:])
    np.testing.assert_allclose(r, r_sk[1:])
    assert pr_auc(pred, score, gt, tol) == pytest.approx(auc(r_sk[1:], p_sk[1:]))
    best = r_sk[1:][p_sk[1:] == 1].max()
    assert recall_at_100_precision(pred, score, gt, tol) == pytest.approx(best)


def test_pr_curve_nothing_retrieved():
    p, r, t = pr_curve([-1, -1], [0.3, 0.2], [0, 1], tolerance=0)
    assert t.size == 0 and p.tolist() == [1.0] and r.tolist() == [0.0]
    assert pr_auc([-1, -1], [0.3, 0.2], [0, 1], 0) == 0.0


def test_storage_reproduces_paper_table_1():
    # Nordland summer: N 7403, periods 88 + 93, d 4096 (paper Table 1)
    assert database_bytes(7403, 4096) == 121_290_752
    assert storage_bytes((88, 93), 4096) == 2_966_228
    ratio = storage_bytes((88, 93), 4096) / database_bytes(7403, 4096)
    assert round(ratio, 4) == 0.0245  # the paper prints 0.0246
    # Aerial Brisbane: N 3705, periods 62 + 63
    got = (database_bytes(3705, 4096), storage_bytes([62, 63], 4096))
    assert got == (60_702_720, 2_048_500)
    assert storage_bytes((2, 5), 3, itemsize=2) == 7 * 4 * 2


def test_bad_input_raises_input_error():
    with pytest.raises(InputError, match="shape"):
        accuracy([0, 1], [0])
    with pytest.raises(InputError, match="integer"):
        accuracy([0.0, 1.0], [0, 1])
    with pytest.raises(InputError, match="tolerance"):
        accuracy([0], [0], tolerance=-1)
    with pytest.raises(InputError, match="ks"):
        recall_at_k(np.zeros((3, 2), int), [0, 1, 2], ks=(1, 5), tolerance=0)
    with pytest.raises(InputError, match="in the map"):
        pr_curve([0, 1], [0.1, 0.2], [-1, -1], tolerance=0)
    with pytest.raises(InputError, match="NaN"):
        pr_curve([0, 1], [np.nan, 0.2], [0, 1], tolerance=0)
    with pytest.raises(InputError, match="needs tolerance"):
        recall_at_k(np.zeros((3, 2), int), [0, 1, 2], (1,))  # tolerance required
    with pytest.raises(InputError, match="needs a tolerance"):
        pr_auc([0, 1], [0.1, 0.2], [0, 1])


# ------------------------------------------- recall's denominator, as the peers


def _vpr_methods_evaluation_recalls(predictions, positives, values):
    """VPR-methods-evaluation's main.py, as written there: a query counts from
    the first N of ``values`` whose predictions hold a positive, and the counts
    are divided by ``num_queries``, every query (in percent there)."""
    recalls = np.zeros(len(values))
    for query_index, preds in enumerate(predictions):
        for i, n in enumerate(values):
            if np.any(np.isin(preds[:n], positives[query_index])):
                recalls[i:] += 1
                break
    return recalls / len(predictions)


def _vpr_tutorial_recall_at_k(S, GT, K):
    """VPR_Tutorial's evaluation/metrics.py recallAtK, as written there: the
    columns (queries) without a match are dropped, then the top K of each."""
    GT = GT.astype("bool")
    j = GT.sum(0) > 0
    S = S[:, j]
    GT = GT[:, j]
    i = S.argsort(0)[-K:, :]
    j = np.tile(np.arange(i.shape[1]), [K, 1])
    GT = GT[i, j]
    return np.sum(GT.sum(0) > 0) / GT.shape[1]


def _corridor_like():
    """111 queries of 100 places, 11 with no right place (the VPR-Bench corridor's
    counts), 35 of the other 100 closest to a right place: R@1 35/111 = 0.3153
    over all, 35/100 = 0.350 over the matched."""
    rng = np.random.default_rng(11)
    n, d, b = 100, 64, 111
    ref = rng.standard_normal((n, d))
    ref /= np.linalg.norm(ref, axis=1, keepdims=True)
    place = rng.integers(0, n, b)
    lists = [sorted({p, min(p + 1, n - 1)}) for p in place]
    for j in rng.choice(b, 11, replace=False):
        lists[j] = []
    matched = [j for j in range(b) if lists[j]]
    right = set(matched[:35])
    seen = np.empty((b, d))
    for j in range(b):
        p = place[j] if j in right else (place[j] + 50) % n  # far from its place
        seen[j] = ref[p] + 0.3 * rng.standard_normal(d) / np.sqrt(d)
    seen /= np.linalg.norm(seen, axis=1, keepdims=True)
    return ref.astype(np.float32), seen.astype(np.float32), lists


def test_recall_over_all_and_matched_equal_each_peers_formula():
    """``over="all"`` is VPR-methods-evaluation's recall, ``"matched"``
    VPR_Tutorial's, to 4 decimals (here exactly), on the same ranking."""
    from rhythmic_jax import RhythmicMap
    from rhythmic_jax.eval.ground_truth import from_lists
    from rhythmic_jax.eval.report import evaluate_map, format_evaluation

    ref, qry, lists = _corridor_like()
    ks = (1, 5, 10, 20)
    sims = qry.astype(np.float64) @ ref.T.astype(np.float64)  # (b, n)
    # the L2 ranking VPR-methods-evaluation's faiss IndexFlatL2 gives (unit rows)
    dist = ((qry[:, None, :] - ref[None]) ** 2).sum(-1)
    predictions = np.argsort(dist, axis=1, kind="stable")[:, :20]
    want_all = _vpr_methods_evaluation_recalls(predictions, lists, ks)
    GT = np.zeros((len(ref), len(qry)), bool)
    for j, row in enumerate(lists):
        GT[row, j] = True
    want_matched = [_vpr_tutorial_recall_at_k(sims.T, GT, k) for k in ks]
    assert want_all[0] == pytest.approx(35 / 111) and want_matched[0] == 0.35

    truth = from_lists(lists, len(ref), "corridor-like lists")
    model = RhythmicMap().fit(ref, progress=False)
    rows = {}
    for over, want in (("all", want_all), ("matched", want_matched)):
        res = evaluate_map(model, qry, reference=ref, ground_truth=truth,
                           timing=False, recall_over=over)  # fmt: skip
        brute, rows[over] = res["methods"]["brute force"], res["methods"]["map"]
        for k, w in zip(ks, want, strict=True):
            assert brute[f"recall@{k}"] == pytest.approx(w, abs=5e-5), (over, k)
        n = 111 if over == "all" else 100
        assert res["recall_over"] == brute["recall_over"] == over
        assert res["recall_queries"] == brute["recall_queries"] == n
        text = format_evaluation(res)
        line = next(x for x in text.splitlines() if x.startswith("brute force: R@"))
        assert line.startswith(f"brute force: R@1: {100 * want[0]:.1f}, ")
        if over == "all":
            assert line.endswith("(over all 111 queries)")
            assert "over all 111 queries, the 11 without a right place" in text
        else:
            assert line.endswith("(over 100 queries with a right place)")
            assert "over the 100 of 111 queries that have a right place" in text
    # the map's own recall follows the same denominators: all = matched * 100/111
    for k in ks:
        assert rows["all"][f"recall@{k}"] == pytest.approx(
            rows["matched"][f"recall@{k}"] * 100 / 111
        )


def test_recall_at_k_over_all_counts_outliers_as_misses():
    gt = np.array([0, 1, -1, 3])
    ranked = np.array([[0, 9], [5, 1], [2, 3], [7, 8]])
    matched = recall_at_k(ranked, gt, (1, 2), tolerance=0)
    every = recall_at_k(ranked, gt, (1, 2), tolerance=0, over="all")
    assert (matched[1], matched[2]) == (1 / 3, 2 / 3) and matched.n_queries == 3
    assert (every[1], every[2]) == (1 / 4, 2 / 4) and every.n_queries == 4
    assert "over 4 queries in all" in str(every)
    assert every.as_dict()["recall_over"] == "all"
    with pytest.raises(InputError, match="recall_over must be one of"):
        recall_at_k(ranked, gt, (1,), tolerance=0, over="some")


# ------------------------------------------- the public metrics on a GroundTruth


def _sets_case(seed: int, b: int = 60, n: int = 40, k: int = 8):
    """Ragged right places per query (some none), ranked candidates with -1s,
    a hard answer per query and its confidence."""
    rng = np.random.default_rng(seed)
    lists = [
        [] if rng.random() < 0.15 else rng.choice(n, rng.integers(1, 5), False).tolist()
        for _ in range(b)
    ]
    ranked = np.stack([rng.permutation(n)[:k] for _ in range(b)])
    first = np.array([row[0] if row else 0 for row in lists])
    ranked[:, 0] = np.where(rng.random(b) < 0.4, first, ranked[:, 0])
    ranked[rng.random(b) < 0.1, -1] = -1
    pred = ranked[:, 0].copy()
    pred[rng.random(b) < 0.1] = -1
    score = rng.integers(0, 9, b) / 3.0
    return lists, ranked, pred, score


def _sets_reference(lists, ranked, pred, score, ks):
    """The same figures by plain loops over the sets (no package code)."""
    right = [set(r) for r in lists]
    inmap = [i for i, r in enumerate(right) if r]
    recall = {
        k: sum(any(c in right[i] for c in ranked[i, :k] if c >= 0) for i in inmap)
        / len(inmap)
        for k in ks
    }
    acc = np.mean([(pred[i] in r) if r else pred[i] == -1 for i, r in enumerate(right)])
    done = [i for i in range(len(pred)) if pred[i] >= 0]
    points = [(1.0, 0.0)]  # (precision, recall), each distinct score a threshold
    for t in sorted({score[i] for i in done}, reverse=True):
        got = [i for i in done if score[i] >= t]
        tp = sum(pred[i] in right[i] for i in got)
        points.append((tp / len(got), tp / len(inmap)))
    r100 = max(r for p, r in points if p == 1.0)
    area = sum(
        (r1 - r0) * (p0 + p1) / 2
        for (p0, r0), (p1, r1) in zip(points, points[1:], strict=False)
    )
    return recall, acc, r100, area


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_public_metrics_take_a_ground_truth_with_several_right_places(seed):
    """``recall_at_k``, ``accuracy``, R@100P and PR-AUC of a GroundTruth with
    several right places per query agree with loops over the sets, and with
    the package's multi-positive metrics the command line prints."""
    from rhythmic_jax.eval.ground_truth import (
        from_lists,
        gt_accuracy,
        gt_pr_curve,
        gt_recall_at_k,
    )

    lists, ranked, pred, score = _sets_case(seed)
    gt = from_lists(lists, 40, "test lists")
    ks = (1, 5, 8)
    recall, acc, r100, area = _sets_reference(lists, ranked, pred, score, ks)
    got = recall_at_k(ranked, gt, ks)
    assert got.n_queries == sum(bool(r) for r in lists)
    for k in ks:
        assert got[k] == pytest.approx(recall[k])
    private = gt_recall_at_k(ranked, gt, ks)
    assert all(private[f"recall@{k}"] == got[k] for k in ks)
    assert accuracy(pred, gt) == pytest.approx(acc) == gt_accuracy(pred, gt)
    assert recall_at_100_precision(pred, score, gt) == pytest.approx(r100)
    assert pr_auc(pred, score, gt) == pytest.approx(area)
    p, r, _ = gt_pr_curve(pred, score, gt)
    np.testing.assert_array_equal(pr_curve(pred, score, gt)[0], p)
    np.testing.assert_array_equal(pr_curve(pred, score, gt)[1], r)
    assert "tolerance ±None" not in str(got) and "test lists" in str(got)
    everyone = recall_at_k(ranked, gt, ks, over="all")
    assert everyone[1] == pytest.approx(recall[1] * got.n_queries / len(lists))


def test_a_ground_truth_from_indices_gives_the_index_arrays_figures():
    """``from_indices(gt, n, tol)`` through the public metrics is the index
    arrays' figure at that tolerance (the two conventions agree)."""
    from rhythmic_jax.eval.ground_truth import from_indices

    pred, score, gt = random_case(200, 30, seed=4, p_reject=0.1, p_outlier=0.1)
    ranked = np.stack([pred, (pred + 3) % 30, (pred + 1) % 30], 1)
    ranked[pred < 0] = -1
    sets = from_indices(gt, 30, tolerance=1)
    assert recall_at_k(ranked, sets, (1, 3)).recall == (
        recall_at_k(ranked, gt, (1, 3), tolerance=1).recall
    )
    assert str(recall_at_k(ranked, sets, (1,))).count("±1 frames") == 1
    assert accuracy(pred, sets) == accuracy(pred, gt, 1)
    assert pr_auc(pred, score, sets) == pr_auc(pred, score, gt, 1)
    assert recall_at_100_precision(pred, score, sets) == recall_at_100_precision(
        pred, score, gt, 1
    )


def test_a_ground_truth_refuses_a_tolerance_and_a_wrong_count():
    from rhythmic_jax.eval.ground_truth import from_lists

    gt = from_lists([[0, 1], [2], []], 5, "three queries")
    ranked = np.array([[1, 0], [0, 2], [3, 4]])
    with pytest.raises(InputError, match="tolerance .*GroundTruth"):
        recall_at_k(ranked, gt, (1,), tolerance=1)
    with pytest.raises(InputError, match="tolerance .*GroundTruth"):
        accuracy(ranked[:, 0], gt, 2)
    with pytest.raises(InputError, match="covers 3 queries"):
        recall_at_k(ranked[:2], gt, (1,))
    with pytest.raises(InputError, match="covers 3 queries"):
        accuracy(np.array([0, 1]), gt)
    with pytest.raises(InputError, match="needs tolerance"):
        recall_at_k(ranked, np.array([0, 2, -1]), (1,))
    assert recall_at_k(ranked, gt, (1, 2))[2] == 1.0
    assert recall_at_k(ranked, gt, (1, 2))[1] == 0.5


def test_the_documented_call_on_loaded_ground_truth(tmp_path):
    """``gt = rj.load_ground_truth(...)`` then ``rj.recall_at_k(ranked, gt, ks)``,
    as a user writes it, on a VPR-Bench ground-truth file."""
    import rhythmic_jax as rj

    n = 6
    rows = np.empty(n, dtype=object)
    for i in range(n):
        rows[i] = [i, list(range(max(0, i - 1), min(n, i + 2)))]
    np.save(tmp_path / "ground_truth_new.npy", rows, allow_pickle=True)
    gt = rj.load_ground_truth([str(tmp_path / "ground_truth_new.npy")],
                              n_queries=n, n_places=n, query_source="q")  # fmt: skip
    # right places: i-1..i+1; hits at 1: q0 q1 q3 q4, at 2: q2 too, q5 none
    ranked = np.array([[1, 0], [1, 4], [0, 2], [3, 0], [4, 1], [0, 1]])
    got = rj.recall_at_k(ranked, gt, (1, 2))
    assert got[1] == pytest.approx(4 / 6) and got[2] == pytest.approx(5 / 6)
