"""The paper's hard decode, exhaustively against a brute-force loop over every index."""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
import pytest

from rhythmic_jax.decoding.dispatch import decode_scores
from rhythmic_jax.decoding.hard import decode, hard_decode
from rhythmic_jax.map.pytree import Templates

# (periods, n): n equal to and below the product; a period of 1; r = 2, 3, 4
CASES = [
    ((3, 4), 12),
    ((3, 4), 7),
    ((5, 7), 35),
    ((5, 7), 20),
    ((7, 9, 11), 693),
    ((7, 9, 11), 500),
    ((2, 3, 5, 7), 210),
    ((2, 3, 5, 7), 101),
    ((1, 5), 5),
    ((1, 5), 3),
]


def _blocks(s: np.ndarray, periods):
    offs = np.cumsum((0,) + tuple(periods[:-1]))
    return [s[..., o : o + t] for o, t in zip(offs, periods, strict=True)]


def encode(index: np.ndarray, periods, noise: float, seed: int) -> np.ndarray:
    """(b, p) scores: one-hot phases of ``index`` in every period, plus noise."""
    rng = np.random.default_rng(seed)
    s = rng.normal(scale=noise, size=(len(index), sum(periods))).astype(np.float32)
    for block, t in zip(_blocks(s, periods), periods, strict=True):
        block[np.arange(len(index)), index % t] += 1.0
    return s


def brute_force(scores: np.ndarray, periods, n: int):
    """Per row: argmax phases, then the j < n with j mod tau_g == phase_g for all g.

    Returns index (-1 when no j), the sum of per-period maxima, and the confidence
    min_g (top1_g - top2_g) over periods with at least two phases.
    """
    residues = np.arange(n)[:, None] % np.array(periods)[None, :]  # (n, r): j mod tau
    index, total, conf = [], [], []
    for s in scores:
        blocks = _blocks(s, periods)
        ph = np.array([int(np.argmax(b)) for b in blocks])
        hits = np.flatnonzero(np.all(residues == ph[None, :], axis=1))  # every j < n
        assert len(hits) <= 1  # co-prime periods: at most one frame per phase set
        index.append(int(hits[0]) if len(hits) else -1)
        total.append(sum(float(np.max(b)) for b in blocks))
        margins = [float(np.sort(b)[-1] - np.sort(b)[-2]) for b in blocks if len(b) > 1]
        conf.append(min(margins, default=np.inf))
    return np.array(index), np.array(total), np.array(conf)


def _check(got, scores, periods, n):
    index, total, conf = brute_force(scores, periods, n)
    np.testing.assert_array_equal(np.asarray(got.index), index)
    found = index >= 0
    score = np.asarray(got.score)
    np.testing.assert_allclose(score[found], total[found], rtol=1e-5, atol=1e-5)
    assert np.all(np.isneginf(score[~found]))
    c = np.asarray(got.confidence)
    np.testing.assert_allclose(c[found], conf[found], rtol=1e-4, atol=1e-5)
    np.testing.assert_array_equal(c[~found], 0.0)
    return index


@pytest.mark.parametrize("periods,n", CASES)
def test_hard_decode_exhaustive(periods, n):
    m = math.prod(periods)
    every = np.arange(m)  # every index below the product, encoded
    clean = encode(every, periods, 0.1, seed=m + n)
    rand = np.random.default_rng(n).normal(size=(64, sum(periods))).astype(np.float32)
    scores = np.concatenate([clean, rand])
    got = decode_scores(scores, periods, n)
    index = _check(got, scores, periods, n)
    # the encoded indices decode to themselves, or to "no match" at or beyond n
    np.testing.assert_array_equal(index[:m], np.where(every < n, every, -1))
    assert got.index.dtype == jnp.int32
    if periods == (3, 4):  # the undecorated function is the same computation
        plain = hard_decode(jnp.asarray(scores), periods, n)
        for a, b in zip(plain, got, strict=True):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_confidence_is_weakest_margin():
    periods = (3, 4)
    s = np.array(
        [
            [0.0, 2.0, 1.5, 5.0, 1.0, 0.0, 0.0],  # margins 0.5, 4.0 -> 0.5
            [3.0, 0.0, 0.0, 0.0, 1.0, 0.9, 0.0],  # margins 3.0, 0.1 -> 0.1
            [1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 2.0],  # a tie: argmax takes phase 0
        ],
        np.float32,
    )
    got = decode_scores(s, periods, 12)
    np.testing.assert_array_equal(np.asarray(got.index), [4, 9, 3])
    np.testing.assert_allclose(np.asarray(got.confidence), [0.5, 0.1, 0.0], atol=1e-6)
    np.testing.assert_allclose(np.asarray(got.score), [7.0, 4.0, 3.0])


def test_no_match_beyond_n():
    s = encode(np.array([10, 11, 3]), (3, 4), 0.0, seed=0)
    got = decode_scores(s, (3, 4), 10)
    np.testing.assert_array_equal(np.asarray(got.index), [-1, -1, 3])
    assert np.isneginf(np.asarray(got.score)[:2]).all()
    np.testing.assert_array_equal(np.asarray(got.confidence), [0.0, 0.0, 1.0])


@pytest.mark.parametrize("periods,n", [((5, 7), 35), ((7, 9, 11), 600)])
def test_decode_templates_equals_decode_of_scores(periods, n):
    rng = np.random.default_rng(3)
    d, p = 8, sum(periods)
    params = Templates(
        jnp.asarray(rng.normal(size=(d, p)).astype(np.float32)),
        jnp.asarray(rng.normal(size=(p,)).astype(np.float32)),
    )
    q = rng.normal(size=(300, d)).astype(np.float32)
    got = decode(params, q, list(periods), n)
    s = q @ np.asarray(params.w) + np.asarray(params.b)[None, :]
    want = decode_scores(s, periods, n)
    np.testing.assert_array_equal(np.asarray(got.index), np.asarray(want.index))
    np.testing.assert_allclose(
        np.asarray(got.score), np.asarray(want.score), rtol=1e-5, atol=1e-5
    )
    np.testing.assert_allclose(
        np.asarray(got.confidence), np.asarray(want.confidence), rtol=1e-4, atol=1e-5
    )
    _check(got, s, periods, n)
