"""Outlier rejection: thresholds against brute-force scans, PR against scikit-learn,
and a threshold chosen on one half of a synthetic map's queries held on the other."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import log_softmax
from sklearn.metrics import auc, precision_recall_curve

from rhythmic_jax.errors import InputError
from rhythmic_jax.eval.metrics import pr_auc, pr_curve
from rhythmic_jax.eval.outliers import (
    CONFIDENCES,
    choose_threshold,
    decode_confidence,
    finite_confidence,
    holdout_split,
    quantile_threshold,
    reject,
)
from rhythmic_jax.rhythmic_map import RhythmicMap

N, D, NOISE = 150, 256, 1.2 / 16  # noise per coordinate: about 0.075 * sqrt(D) = 1.2


def _unit(a):
    return (a / np.linalg.norm(a, axis=1, keepdims=True)).astype(np.float32)


@pytest.fixture(scope="module")
def synthetic():
    """A map of N random unit frames; N noisy map frames and N random outliers,
    shuffled: (map, scores (2N, p), gt (2N,) with -1 for an outlier)."""
    rng = np.random.default_rng(0)
    x = _unit(rng.normal(size=(N, D)))
    model = RhythmicMap(r=2, level=1).fit(x, progress=False)
    inliers = x + NOISE * rng.normal(size=x.shape).astype(np.float32)
    outliers = _unit(rng.normal(size=(N, D)))
    q = np.concatenate([inliers, outliers])
    gt = np.r_[np.arange(N), np.full(N, -1)]
    order = rng.permutation(2 * N)
    return model, np.asarray(model.scores(q[order])), gt[order]


# ------------------------------------------------------------ brute-force references


def brute_threshold(pred, conf, gt, tol, target):
    """Scan every candidate threshold; largest recall at precision >= target."""
    correct = (pred >= 0) & (gt >= 0) & (np.abs(pred - gt) <= tol)
    n_pos = (gt >= 0).sum()
    best_t, best_r = math.inf, 0.0
    for t in np.unique(conf[pred >= 0]):
        kept = (pred >= 0) & (conf >= t)
        tp = (kept & correct).sum()
        recall, precision = tp / n_pos, tp / kept.sum()
        if precision >= target and tp > 0:
            if recall > best_r or (recall == best_r and t > best_t):
                best_t, best_r = float(t), recall
    return best_t


def _random_case(seed, b=80, n=30):
    rng = np.random.default_rng(seed)
    gt = np.where(rng.random(b) < 0.3, -1, rng.integers(0, n, b))
    pred = np.where(rng.random(b) < 0.7, gt, rng.integers(-1, n, b))
    pred = np.where(rng.random(b) < 0.1, -1, pred)
    conf = np.round(rng.normal(size=b) + 2.0 * (pred == gt), 1)  # ties on purpose
    return pred, conf, gt


# ------------------------------------------------------------------------ tests


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("target", [1.0, 0.9, 0.75])
@pytest.mark.parametrize("tol", [0, 2])
def test_choose_threshold_matches_brute_force(seed, target, tol):
    pred, conf, gt = _random_case(seed)
    got = choose_threshold(pred, conf, gt, tolerance=tol, target_precision=target)
    assert got == brute_threshold(pred, conf, gt, tol, target)


def test_choose_threshold_unreachable_target_rejects_all():
    pred, gt = np.array([3, 4, 5]), np.array([-1, -1, 5])
    conf = np.array([2.0, 1.0, 0.5])  # the only correct match is the least sure
    assert choose_threshold(pred, conf, gt, tolerance=0) == math.inf
    assert choose_threshold(pred, conf, gt, tolerance=0, target_precision=0.3) == 0.5
    assert (reject(pred, conf, math.inf) == -1).all()


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("q", [0.0, 0.5, 0.9, 0.99, 1.0])
def test_quantile_threshold_against_brute_force(seed, q):
    c = np.round(np.random.default_rng(seed).normal(size=57), 1)
    t = quantile_threshold(c, q)
    allowed = math.floor((1 - q) * c.size + 1e-9)
    assert (c >= t).sum() <= allowed
    # the lowest such threshold: every candidate below it lets through too many
    lower = [s for s in np.unique(c) if s < t]
    assert all((c >= s).sum() > allowed for s in lower)


def test_reject_matches_predict_threshold(synthetic):
    model, scores, _ = synthetic
    rng = np.random.default_rng(1)
    q = rng.normal(size=(20, D)).astype(np.float32)
    for method in ("hard", "soft"):
        out = model.decode(q, method)
        idx, conf = np.asarray(out.index), np.asarray(out.confidence)
        thr = float(np.median(conf[idx >= 0]))
        want = model.predict(q, method, threshold=thr)
        np.testing.assert_array_equal(reject(idx, conf, thr), want)
        np.testing.assert_array_equal(reject(idx, conf, None), idx)


def test_likelihood_confidence_is_calibrated_place_score(synthetic):
    model, scores, _ = synthetic
    per, n = model.periods, model.n
    idx, conf = decode_confidence(scores[:25], per, n, "soft", kind="likelihood")
    offs = np.cumsum((0,) + per[:-1])
    for s, i, c in zip(scores[:25], idx, conf, strict=True):
        blocks = [log_softmax(s[o : o + t]) for o, t in zip(offs, per, strict=True)]
        totals = [
            sum(b[j % t] for b, t in zip(blocks, per, strict=True)) for j in range(n)
        ]
        assert i == int(np.argmax(totals))
        np.testing.assert_allclose(c, max(totals), rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("method", ["hard", "soft", "topm"])
@pytest.mark.parametrize("kind", CONFIDENCES)
def test_threshold_from_one_half_holds_on_the_other(synthetic, method, kind):
    model, scores, gt = synthetic
    idx, conf = decode_confidence(scores, model.periods, model.n, method, kind=kind)
    a, b = slice(0, N), slice(N, None)
    thr = choose_threshold(idx[a], conf[a], gt[a], tolerance=0)
    kept = reject(idx[b], conf[b], thr)
    g = kept[gt[b] >= 0] == gt[b][gt[b] >= 0]
    retrieved = (kept >= 0).sum()
    assert retrieved > 0
    precision = g.sum() / retrieved
    hit = (idx[b] >= 0) & (idx[b] == gt[b])
    raw = hit.sum() / (idx[b] >= 0).sum()  # before the threshold
    assert raw < 0.6 and precision >= 0.9
    assert (kept[gt[b] < 0] == -1).mean() >= 0.9  # outliers mostly rejected
    assert g.mean() >= 0.4  # while many in-map queries are still answered


@pytest.mark.parametrize("method", ["hard", "soft"])
def test_pr_curve_agrees_with_sklearn_in_map_only(synthetic, method):
    model, scores, gt = synthetic
    inmap = gt >= 0
    idx, conf = decode_confidence(
        scores[inmap], model.periods, model.n, method, kind="margin"
    )
    g = gt[inmap]
    assert (idx >= 0).all() or method == "hard"
    keep = idx >= 0  # sklearn has no "no match": compare on the answered queries
    idx, conf, g = idx[keep], conf[keep], g[keep]
    correct = idx == g
    assert 0 < correct.sum() < len(g)  # a non-trivial curve
    p, r, t = pr_curve(idx, conf, g, tolerance=0)
    sp, sr, st = precision_recall_curve(correct, conf)
    np.testing.assert_allclose(p, sp)
    np.testing.assert_allclose(r, sr * correct.sum() / len(g))  # out of all queries
    np.testing.assert_allclose(t, st)
    want_auc = auc(sr * correct.sum() / len(g), sp)
    np.testing.assert_allclose(pr_auc(idx, conf, g, tolerance=0), want_auc)


def test_finite_confidence_keeps_order():
    c = finite_confidence([np.inf, 1.0, -np.inf, 0.0])
    assert np.isfinite(c).all()
    assert list(np.argsort(c)) == [2, 3, 1, 0]
    with pytest.raises(InputError, match="NaN"):
        finite_confidence([np.nan])


@pytest.mark.parametrize(
    "n,fraction,block,seed", [(3576, 0.2, 50, 0), (1000, 0.2, 37, 3)]
)
def test_holdout_split_blocks(n, fraction, block, seed):
    h = holdout_split(n, fraction, seed, block)
    assert np.array_equal(np.sort(np.r_[h.fit, h.held]), np.arange(n))
    assert abs(len(h.held) / n - fraction) < 0.02
    # held frames come in contiguous runs of whole blocks
    runs = np.split(h.held, np.flatnonzero(np.diff(h.held) > 1) + 1)
    assert all(
        r[0] % block == 0 and (len(r) % block == 0 or r[-1] == n - 1) for r in runs
    )
    # both halves of the route have held-out places
    assert (h.held < n // 2).any() and (h.held >= n // 2).any()
    gt = h.gt()
    assert (gt[h.held] == -1).all()
    np.testing.assert_array_equal(gt[h.fit], np.arange(len(h.fit)))
    again = holdout_split(n, fraction, seed, block)
    assert np.array_equal(again.held, h.held)
    assert not np.array_equal(holdout_split(n, fraction, seed + 1, block).held, h.held)


@pytest.mark.parametrize(
    "call",
    [
        lambda: holdout_split(100, 1.0),
        lambda: holdout_split(1, 0.2),
        lambda: holdout_split(100, 0.2, block=0),
        lambda: choose_threshold([0], [1.0], [0], tolerance=0, target_precision=0),
        lambda: quantile_threshold([], 0.5),
        lambda: quantile_threshold([1.0], 1.5),
        lambda: reject([0, 1], [1.0], 0.5),
        lambda: decode_confidence(np.zeros((2, 5)), (2, 3), 6, kind="bogus"),
        lambda: decode_confidence(np.zeros((2, 5)), (2, 3), 6, "argmax"),
    ],
)
def test_bad_input_raises_one_line(call):
    with pytest.raises(InputError) as err:
        call()
    assert "\n" not in str(err.value)
