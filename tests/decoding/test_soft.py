"""Soft and top-m decoding against brute-force loops over every place below n."""

from __future__ import annotations

import itertools

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.special import log_softmax

from rhythmic_jax.decoding.soft import (
    _soft_jit,
    calibrate,
    soft_decode,
    topm_combinations,
    topm_decode,
)
from rhythmic_jax.errors import InputError

CASES = [((3, 5), 13), ((4, 5), 20), ((2, 3, 5), 29), ((5, 7, 9), 300)]


def _scores(periods, b=24, seed=0):
    rng = np.random.default_rng(seed)
    return rng.normal(size=(b, sum(periods))).astype(np.float32)


def _blocks(s, periods):
    offs = np.cumsum((0,) + tuple(periods[:-1]))
    return [s[o : o + t] for o, t in zip(offs, periods, strict=True)]


def _place_score(s, periods, i):
    return sum(
        float(b[i % t]) for b, t in zip(_blocks(s, periods), periods, strict=True)
    )


def _best_two(cands, exclude, rivals=None):
    """cands: list of (index, score); best (ties: smaller index) and its rival
    among ``rivals`` (default: cands)."""
    if not cands:
        return -1, -np.inf, -np.inf
    best_i, best_s = min(cands, key=lambda c: (-c[1], c[0]))
    rivals = cands if rivals is None else rivals
    rivals = [s for i, s in rivals if abs(i - best_i) > exclude]
    return best_i, best_s, max(rivals, default=-np.inf)


def brute_soft(scores, periods, n, exclude=0):
    out = []
    for s in scores:
        cands = [(i, _place_score(s, periods, i)) for i in range(n)]
        out.append(_best_two(cands, exclude))
    return [np.array(x) for x in zip(*out, strict=True)]


def brute_topm(scores, periods, n, top, exclude=0):
    """The best of the top-m combinations, its rival among those of the
    max(top, 2) best phases of every period (every one for top 1, else the
    places)."""
    out = []
    wide = max(top, 2)
    for s in scores:
        tops = [np.argsort(-b, kind="stable")[:wide] for b in _blocks(s, periods)]
        cands, rivals = [], []
        for ranks in itertools.product(*(range(len(t)) for t in tops)):
            phases = [t[k] for t, k in zip(tops, ranks, strict=True)]
            i = next(
                i
                for i in range(int(np.prod(periods)))
                if all(i % t == j for t, j in zip(periods, phases, strict=True))
            )
            if i < n or top == 1:  # top 1: rivals a place or not, as hard
                rivals.append((i, _place_score(s, periods, i)))
                if max(ranks) < top and i < n:
                    cands.append(rivals[-1])
        out.append(_best_two(cands, exclude, rivals))
    return [np.array(x) for x in zip(*out, strict=True)]


def _assert_matches(got, ref):
    np.testing.assert_array_equal(np.asarray(got.index), ref[0])
    np.testing.assert_allclose(np.asarray(got.score), ref[1], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(np.asarray(got.runner_up), ref[2], rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize(
    "periods,n,exclude", [c + (0,) for c in CASES] + [((3, 5), 13, 2)]
)
def test_soft_matches_brute_force(periods, n, exclude):
    scores = _scores(periods, seed=n)
    _assert_matches(
        soft_decode(scores, periods, n, exclude=exclude),
        brute_soft(scores, periods, n, exclude),
    )


@pytest.mark.parametrize("periods", [(3, 5), (2, 3, 5), (5, 7, 9)])
@pytest.mark.parametrize("top", [1, 2, 4])
def test_topm_combinations_are_every_product_of_the_best_phases(periods, top):
    """Every combination of each period's ``top`` best phases, the last period
    fastest: its summed score and the place with those phases."""
    s = _scores(periods, b=1, seed=top)[0]
    score, index = topm_combinations(jnp.asarray(s), periods, top)
    tops = [np.argsort(-b, kind="stable")[:top] for b in _blocks(s, periods)]
    combos = list(itertools.product(*tops))
    place = [
        next(
            i
            for i in range(int(np.prod(periods)))
            if all(i % t == j for t, j in zip(periods, phases, strict=True))
        )
        for phases in combos
    ]
    np.testing.assert_array_equal(np.asarray(index), place)
    np.testing.assert_allclose(
        np.asarray(score),
        [_place_score(s, periods, i) for i in place],
        rtol=1e-5,
        atol=1e-5,
    )


@pytest.mark.parametrize("periods,n", CASES)
@pytest.mark.parametrize("top", [1, 3])
def test_topm_matches_brute_force(periods, n, top):
    scores = _scores(periods, seed=7 * n + top)
    _assert_matches(
        topm_decode(scores, periods, n, top, exclude=1),
        brute_topm(scores, periods, n, top, exclude=1),
    )


@pytest.mark.parametrize("periods,n", CASES)
def test_topm_with_every_phase_is_soft_exactly(periods, n):
    scores = _scores(periods, b=64, seed=3)
    soft = soft_decode(scores, periods, n)
    full = topm_decode(scores, periods, n, max(periods) + 2)
    for a, b in zip(soft, full, strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_top1_is_paper_hard_decode_with_no_match():
    periods, n = (5, 7, 9), 200
    scores = _scores(periods, b=200, seed=11)
    got = np.asarray(topm_decode(scores, periods, n, 1).index)
    want = []
    for s in scores:
        phases = [int(np.argmax(b)) for b in _blocks(s, periods)]
        i = next(
            i
            for i in range(315)
            if all(i % t == j for t, j in zip(periods, phases, strict=True))
        )
        want.append(i if i < n else -1)
    np.testing.assert_array_equal(got, want)
    assert (got == -1).any() and (got >= 0).any()


def _noisy(periods, n, b, scale, seed):
    rng = np.random.default_rng(seed)
    truth = rng.integers(0, n, b)
    scores = rng.normal(scale=scale, size=(b, sum(periods))).astype(np.float32)
    offs = np.cumsum((0,) + periods[:-1])
    for o, t in zip(offs, periods, strict=True):
        scores[np.arange(b), o + truth % t] += 1.0
    return scores, truth


def test_soft_rescues_hard_no_match_when_n_below_product():
    periods, n = (11, 13), 60
    scores, truth = _noisy(periods, n, 400, 0.45, seed=5)
    soft = np.mean(np.asarray(soft_decode(scores, periods, n).index) == truth)
    hard = np.mean(np.asarray(topm_decode(scores, periods, n, 1).index) == truth)
    assert soft > hard + 0.1, (soft, hard)


def test_soft_equals_hard_when_every_combination_is_a_place():
    # sum_g s_g[j_g] is separable, so with n = prod(tau) its argmax is the
    # per-period argmax: soft decoding changes the answer only through n < M.
    periods = (11, 13)
    scores, _ = _noisy(periods, 143, 400, 0.45, seed=6)
    soft = np.asarray(soft_decode(scores, periods, 143).index)
    hard = np.asarray(topm_decode(scores, periods, 143, 1).index)
    np.testing.assert_array_equal(soft, hard)


def test_leading_dims_and_confidence():
    periods, n = (4, 5), 20
    scores = _scores(periods, b=12).reshape(3, 4, 9)
    got = soft_decode(scores, periods, n)
    flat = soft_decode(scores.reshape(12, 9), periods, n)
    assert got.index.shape == (3, 4)
    np.testing.assert_array_equal(np.asarray(got.index).ravel(), np.asarray(flat.index))
    conf = np.asarray(got.confidence)
    np.testing.assert_allclose(conf, np.asarray(got.score - got.runner_up))
    assert (conf >= 0).all()


def test_no_match_and_a_place_without_rival_have_confidence_zero():
    periods = (2, 3)
    scores = np.array([[0.0, 5.0, 0.0, 0.0, 9.0]], np.float32)  # argmax: place 5
    hard = topm_decode(scores, periods, 3, 1)
    assert int(hard.index[0]) == -1 and float(hard.confidence[0]) == 0.0
    one = soft_decode(scores, periods, 1)  # one place: no rival, confidence 0
    assert int(one.index[0]) == 0 and float(one.confidence[0]) == 0.0


def test_calibrate_is_per_period_log_softmax():
    periods = (3, 5, 7)
    scores = _scores(periods, b=6)
    got = np.asarray(calibrate(scores, periods))
    want = np.concatenate(
        [
            log_softmax(scores[:, :3], -1),
            log_softmax(scores[:, 3:8], -1),
            log_softmax(scores[:, 8:], -1),
        ],
        axis=1,
    )
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)


def test_jitted_decode_does_not_recompile():
    periods, n = (3, 5), 13
    soft_decode(_scores(periods, seed=1), periods, n, exclude=3)
    size = _soft_jit._cache_size()
    soft_decode(_scores(periods, seed=2), list(periods), n, exclude=3)
    assert _soft_jit._cache_size() == size


@pytest.mark.parametrize(
    "periods,n,shape",
    [
        ((4, 6), 20, (2, 10)),
        ((3, 5), 16, (2, 8)),
        ((3, 5), 10, (2, 7)),
        ((3, 5), 0, (2, 8)),
    ],
)
def test_bad_input_raises(periods, n, shape):
    with pytest.raises(InputError):
        soft_decode(jnp.zeros(shape), periods, n)


def test_bad_top_raises():
    with pytest.raises(InputError, match="top must"):
        topm_decode(jnp.zeros((2, 8)), (3, 5), 10, 0)
