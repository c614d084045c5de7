"""Fused decode: each part alone when the other's weight is zero; a loop reference."""

import numpy as np
import pytest

from rhythmic_jax.decoding.fusion import (
    code_sequence_scores,
    fused_decode,
    fused_place_scores,
    fused_sequence_decode,
    learn_weight,
)
from rhythmic_jax.decoding.sequence import sequence_decode
from rhythmic_jax.decoding.soft import soft_decode, topm_decode
from rhythmic_jax.errors import InputError

PERIODS = (5, 7)
N = 33


def _parts(b=40, seed=0):
    rng = np.random.default_rng(seed)
    scores = rng.normal(size=(b, sum(PERIODS))).astype(np.float32)
    sims = rng.integers(0, 64, size=(b, N)).astype(np.float32)
    sims += rng.random((b, N)).astype(np.float32) * 0.01  # no ties
    return scores, sims


def _z(v):
    return (v - v.mean(-1, keepdims=True)) / v.std(-1, keepdims=True)


def test_weight_one_is_the_map_and_zero_the_codes():
    scores, sims = _parts()
    for method, ref in [
        ("soft", soft_decode(scores, PERIODS, N)),
        ("topm", topm_decode(scores, PERIODS, N, 3)),
        ("hard", topm_decode(scores, PERIODS, N, 1)),
    ]:
        got = fused_decode(scores, sims, PERIODS, N, 1.0, method, 3)
        assert np.array_equal(np.asarray(got.index), np.asarray(ref.index)), method
        codes = fused_decode(scores, sims, PERIODS, N, 0.0, method, 3)
        assert np.array_equal(np.asarray(codes.index), sims.argmax(1)), method


def test_soft_fusion_matches_a_numpy_loop():
    scores, sims = _parts(seed=3)
    place = np.stack(
        [
            sum(s[o + np.arange(N) % t] for o, t in zip((0, 5), PERIODS, strict=True))
            for s in scores
        ]
    )
    for w in (0.2, 0.5, 0.8):
        ref = w * _z(place) + (1 - w) * _z(sims)
        got = fused_decode(scores, sims, PERIODS, N, w)
        assert np.array_equal(np.asarray(got.index), ref.argmax(1))
        np.testing.assert_allclose(
            np.asarray(fused_place_scores(scores, sims, PERIODS, N, w)), ref, atol=1e-5
        )


def test_topm_with_every_phase_equals_soft():
    scores, sims = _parts(seed=4)
    # n = prod(periods): the moment z-score is exact and top-m covers every place
    n = 35
    sims = np.concatenate([sims, sims[:, :2] - 0.5], axis=1)
    soft = fused_decode(scores, sims, PERIODS, n, 0.6, "soft")
    topm = fused_decode(scores, sims, PERIODS, n, 0.6, "topm", 7)
    assert np.array_equal(np.asarray(soft.index), np.asarray(topm.index))


def test_sequences_reduce_to_each_part():
    scores, sims = _parts(b=60, seed=5)
    ref, _ = sequence_decode(scores, PERIODS, N, 4, (1.0,), "soft")
    got, _ = fused_sequence_decode(scores, sims, PERIODS, N, 4, weight=1.0)
    assert np.array_equal(np.asarray(got), np.asarray(ref))
    got, _ = fused_sequence_decode(scores, sims, PERIODS, N, 4, weight=0.0)
    acc = np.asarray(code_sequence_scores(sims, 4))
    assert np.array_equal(np.asarray(got), acc.argmax(1))


def test_code_sequence_scores_by_loop():
    _, sims = _parts(b=12, seed=6)
    z = _z(sims)
    for speed in (1.0, 1.5, -1.0):
        got = np.asarray(code_sequence_scores(sims, 3, speed))
        ref = np.zeros_like(sims)
        for t in range(len(sims)):
            for step in range(3):
                o = int(np.sign(step * speed) * np.floor(abs(step * speed) + 0.5))
                for i in range(N):
                    if t - step >= 0 and 0 <= i - o < N:
                        ref[t, i] += z[t - step, i - o]
        np.testing.assert_allclose(got, ref, atol=1e-5)


def test_learn_weight_picks_the_better_part():
    rng = np.random.default_rng(7)
    gt = np.arange(N)
    sims = rng.normal(size=(N, N)).astype(np.float32)
    sims[gt, gt] += 2.5  # the codes are good, the map is noise
    scores = rng.normal(size=(N, sum(PERIODS))).astype(np.float32)
    w, table = learn_weight(scores, sims, PERIODS, N, gt, 0)
    assert table[w] == max(table.values()) > table[0.5] > table[1.0]
    assert w < 0.5 and len(table) == 21


@pytest.mark.parametrize("w", [-0.1, 1.5, "a"])
def test_bad_weight(w):
    scores, sims = _parts()
    with pytest.raises(InputError, match="fusion weight"):
        fused_decode(scores, sims, PERIODS, N, w)


def test_bad_shapes():
    scores, sims = _parts()
    with pytest.raises(InputError, match="code similarities"):
        fused_decode(scores, sims[:, :-1], PERIODS, N)


@pytest.mark.parametrize("codes", [16, "int8"])
def test_a_map_with_codes_decodes_under_jit_as_eager(codes):
    """``jax.jit(decode)``, ``place_scores`` and ``decode_sequence`` on a map
    with codes trace (the queries encoded in JAX) and give the eager answer;
    ``jax.vmap`` over two stacked maps too."""
    import jax

    import rhythmic_jax as rj

    rng = np.random.default_rng(0)
    x = rng.normal(size=(120, 32)).astype(np.float32)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    m = rj.fit(x, rj.MapConfig(codes=codes, decode="soft"))
    q = x[:20] + 0.3 * rng.normal(size=(20, 32)).astype(np.float32) / 6
    for how in ("soft", "topm") if codes == 16 else ("hard",):  # hard: soft here
        eager = rj.decode(m, q, how)
        traced = jax.jit(rj.decode, static_argnums=2)(m, q, how)
        for a, b in zip(eager, traced, strict=True):
            np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=1e-6)
    np.testing.assert_allclose(
        jax.jit(rj.place_scores)(m, q), rj.place_scores(m, q), rtol=1e-6, atol=1e-6
    )
    two = jax.tree.map(lambda a, b: jax.numpy.stack([a, b]), m, m)
    both = jax.vmap(rj.decode, in_axes=(0, None))(two, q).index
    np.testing.assert_array_equal(
        np.asarray(both[1]), np.asarray(rj.decode(m, q).index)
    )
    if codes != 16:
        return
    eager = rj.decode_sequence(m, q, 5)
    traced = jax.jit(rj.decode_sequence, static_argnums=2)(m, q, 5)
    for a, b in zip(eager, traced, strict=True):
        np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=1e-6)
