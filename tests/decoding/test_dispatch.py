"""Decoding by name: each method reached, checked arguments, any leading shape."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rhythmic_jax.decoding.dispatch import DECODERS, decode_scores
from rhythmic_jax.decoding.hard import hard_kernel
from rhythmic_jax.errors import InputError
from rhythmic_jax.map.periods import period_offsets


def encode(index: np.ndarray, periods, noise: float, seed: int) -> np.ndarray:
    """(b, p) scores: one-hot phases of ``index`` in every period, plus noise."""
    rng = np.random.default_rng(seed)
    s = rng.normal(scale=noise, size=(len(index), sum(periods))).astype(np.float32)
    for off, t in zip(period_offsets(periods), periods, strict=True):
        s[np.arange(len(index)), off + index % t] += 1.0
    return s


def test_unknown_method():
    s = encode(np.arange(12), (3, 4), 0.1, seed=1)
    with pytest.raises(InputError, match="unknown decode method 'nearest'"):
        decode_scores(s, (3, 4), 12, method="nearest")
    assert DECODERS == ("hard", "soft", "topm")


@pytest.mark.parametrize("method", DECODERS)
@pytest.mark.parametrize(
    "periods,n,width",
    [
        ((4, 6), 20, 10),  # not co-prime
        ((3, 4), 12, 8),  # too many columns
        ((3, 4), 12, 6),  # too few
        ((3, 4), 13, 7),  # n > prod(periods)
        ((3, 4), 0, 7),
    ],
)
def test_bad_arguments(method, periods, n, width):
    s = np.zeros((5, width), np.float32)
    with pytest.raises(InputError):
        decode_scores(s, periods, n, method=method)


@pytest.mark.parametrize("periods,n", [((3, 4), 12), ((5, 7, 9), 315)])
def test_soft_and_topm_agree_with_hard_on_clean_scores(periods, n):
    every = np.arange(math.prod(periods))
    s = encode(every, periods, 0.0, seed=0)
    hard = np.asarray(decode_scores(s, periods, n).index)
    np.testing.assert_array_equal(hard, every)
    for method, top in [("soft", 3), ("topm", 1), ("topm", 3)]:
        got = np.asarray(decode_scores(s, periods, n, method=method, top=top).index)
        np.testing.assert_array_equal(got, hard, err_msg=f"{method} top={top}")


def test_soft_and_topm_below_product():
    periods, n = (5, 7), 20
    every = np.arange(35)
    s = encode(every, periods, 0.0, seed=0)
    hard = np.asarray(decode_scores(s, periods, n, "hard").index)
    top1 = np.asarray(decode_scores(s, periods, n, "topm", top=1).index)
    soft = np.asarray(decode_scores(s, periods, n, "soft").index)
    np.testing.assert_array_equal(hard, np.where(every < n, every, -1))
    np.testing.assert_array_equal(top1, hard)  # top = 1 is the paper's decode
    np.testing.assert_array_equal(soft[:n], every[:n])
    assert (soft[n:] >= 0).all() and (soft[n:] < n).all()  # soft always answers


def test_leading_dims_and_empty_batch():
    periods, n = (3, 4), 10
    s = encode(np.arange(12), periods, 0.3, seed=4)
    flat = decode_scores(s, periods, n)
    got = decode_scores(s.reshape(3, 4, 7), periods, n)
    assert got.index.shape == (3, 4)
    for a, b in zip(got, flat, strict=True):
        np.testing.assert_array_equal(np.asarray(a).ravel(), np.asarray(b))
    one = decode_scores(s[5], periods, n)
    assert one.index.shape == () and int(one.index) == int(flat.index[5])
    empty = decode_scores(np.zeros((0, 7), np.float32), periods, n)
    assert empty.index.shape == (0,)


def test_hard_decode_does_not_recompile():
    periods, n = (5, 7), 33
    decode_scores(encode(np.arange(35), periods, 0.1, seed=5), periods, n)
    size = hard_kernel._cache_size()
    decode_scores(encode(np.arange(35), periods, 0.2, seed=6), list(periods), n)
    assert hard_kernel._cache_size() == size
