"""Phase-domain sequence decoding against explicitly shifted and summed scores."""

from __future__ import annotations

import numpy as np
import pytest

from rhythmic_jax.decoding.sequence import (
    frame_offsets,
    sequence_decode,
    sequence_scores,
)
from rhythmic_jax.decoding.soft import soft_decode, topm_decode
from rhythmic_jax.errors import InputError


def naive_sequence_scores(scores, periods, length, speed):
    """Loop over end frames and window frames; np.roll per period block."""
    frames = len(scores)
    offs = np.cumsum((0,) + tuple(periods[:-1]))
    out = np.zeros_like(scores)
    for t in range(frames):
        for step in range(min(length, t + 1)):
            shift = frame_offsets(length, speed)[step]
            for o, tau in zip(offs, periods, strict=True):
                # a frame seen `step` ago at phase j - shift predicts phase j now
                out[t, o : o + tau] += np.roll(scores[t - step, o : o + tau], shift)
    return out


def _route(periods, n, frames, speed, scale, seed):
    """Scores of a traversal at `speed` map frames per query frame: true phase +1."""
    rng = np.random.default_rng(seed)
    start = int(rng.integers(0, n - int(np.ceil(speed * frames)) - 1))
    truth = start + np.floor(speed * np.arange(frames) + 0.5).astype(int)
    scores = rng.normal(scale=scale, size=(frames, sum(periods))).astype(np.float32)
    offs = np.cumsum((0,) + tuple(periods[:-1]))
    for o, tau in zip(offs, periods, strict=True):
        scores[np.arange(frames), o + truth % tau] += 1.0
    return scores, truth


def test_frame_offsets_round_half_away_from_zero():
    assert frame_offsets(5, 1.2) == (0, 1, 2, 4, 5)
    assert frame_offsets(5, 0.9) == (0, 1, 2, 3, 4)
    assert frame_offsets(4, 0.5) == (0, 1, 1, 2)
    assert frame_offsets(3, -1.0) == (0, -1, -2)


@pytest.mark.parametrize(
    "periods,length,speed",
    [((5, 7), 4, 1.0), ((5, 7), 6, 1.2), ((3, 4, 5), 5, 0.8), ((3, 4, 5), 3, -1.0)],
)
def test_sequence_scores_match_naive_loop(periods, length, speed):
    scores = np.random.default_rng(length).normal(size=(17, sum(periods)))
    scores = scores.astype(np.float32)
    got = np.asarray(sequence_scores(scores, periods, length, speed))
    want = naive_sequence_scores(scores, periods, length, speed)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)


def test_length_one_is_identity():
    scores = np.random.default_rng(0).normal(size=(9, 12)).astype(np.float32)
    np.testing.assert_array_equal(
        np.asarray(sequence_scores(scores, (5, 7), 1)), scores
    )


def test_soft_sequence_decode_matches_decoding_naive_sums_over_speeds():
    periods, n, length, speeds = (5, 7), 30, 5, (0.8, 1.0, 1.3)
    scores = np.random.default_rng(2).normal(size=(25, 12)).astype(np.float32)
    per_speed = [
        soft_decode(naive_sequence_scores(scores, periods, length, v), periods, n)
        for v in speeds
    ]
    best = np.argmax(np.stack([np.asarray(d.score) for d in per_speed]), axis=0)
    want_index = np.choose(best, [np.asarray(d.index) for d in per_speed])
    want_conf = np.choose(best, [np.asarray(d.confidence) for d in per_speed])
    index, conf = sequence_decode(scores, periods, n, length, speeds)
    np.testing.assert_array_equal(np.asarray(index), want_index)
    np.testing.assert_allclose(np.asarray(conf), want_conf, rtol=1e-4, atol=1e-5)


def test_speed_one_grid_is_plain_decode_of_accumulated_scores():
    periods, n, length = (3, 4, 5), 50, 4
    scores = np.random.default_rng(3).normal(size=(15, 12)).astype(np.float32)
    acc = naive_sequence_scores(scores, periods, length, 1.0)
    index, conf = sequence_decode(
        scores, periods, n, length, (1.0,), method="topm", top=2
    )
    want = topm_decode(acc, periods, n, 2)
    np.testing.assert_array_equal(np.asarray(index), np.asarray(want.index))
    np.testing.assert_allclose(np.asarray(conf), np.asarray(want.confidence), rtol=1e-4)


def test_hard_sequence_decode_is_argmax_per_period_and_crt():
    periods, n, length = (5, 7), 30, 3
    scores = np.random.default_rng(4).normal(size=(30, 12)).astype(np.float32)
    acc = naive_sequence_scores(scores, periods, length, 1.0)
    index, conf = sequence_decode(scores, periods, n, length, method="hard")
    want, gaps = [], []
    for a in acc:
        blocks = (a[:5], a[5:])
        i = next(
            i
            for i in range(35)
            if i % 5 == blocks[0].argmax() and i % 7 == blocks[1].argmax()
        )
        want.append(i if i < n else -1)
        gaps.append(
            min(np.sort(b)[-1] - np.sort(b)[-2] for b in blocks) if i < n else 0
        )
    np.testing.assert_array_equal(np.asarray(index), want)
    np.testing.assert_allclose(np.asarray(conf), gaps, rtol=1e-4, atol=1e-5)


def test_sequence_recovers_places_single_frames_miss():
    periods, n, length = (23, 25), 500, 10
    scores, truth = _route(periods, n, 300, 1.0, scale=0.7, seed=5)
    single = np.asarray(soft_decode(scores, periods, n).index) == truth
    index, _ = sequence_decode(scores, periods, n, length)
    seq = (np.asarray(index) == truth)[length - 1 :]
    assert single.mean() < 0.3 and seq.mean() > 0.95, (single.mean(), seq.mean())


def test_speed_grid_recovers_a_faster_traversal():
    periods, n, length = (23, 25), 500, 10
    scores, truth = _route(periods, n, 200, 1.2, scale=0.6, seed=6)
    plain, _ = sequence_decode(scores, periods, n, length, (1.0,))
    grid, _ = sequence_decode(scores, periods, n, length, (0.8, 1.0, 1.2))
    ok_plain = (np.abs(np.asarray(plain) - truth) <= 1)[length - 1 :].mean()
    ok_grid = (np.abs(np.asarray(grid) - truth) <= 1)[length - 1 :].mean()
    assert ok_grid > ok_plain + 0.2 and ok_grid > 0.75, (ok_plain, ok_grid)


@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"length": 0}, "length"),
        ({"speeds": ()}, "speeds"),
        ({"method": "viterbi"}, "method"),
        ({"method": "topm", "top": 0}, "top must"),
    ],
)
def test_bad_options_raise(kwargs, match):
    args = {"length": 3} | kwargs
    with pytest.raises(InputError, match=match):
        sequence_decode(np.zeros((4, 12), np.float32), (5, 7), 30, **args)


def test_bad_scores_shape_raises():
    with pytest.raises(InputError, match="shape"):
        sequence_scores(np.zeros((2, 4, 12), np.float32), (5, 7), 3)
