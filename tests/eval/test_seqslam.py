"""SeqSLAM baseline against naive numpy loops, on synthetic and real routes."""

from __future__ import annotations

import numpy as np
import pytest

from rhythmic_jax.decoding.sequence import frame_offsets
from rhythmic_jax.errors import InputError
from rhythmic_jax.eval.seqslam import (
    enhance_contrast,
    seqslam_decode,
    sequence_similarity,
    similarity,
)


def _unit(a):
    return a / np.linalg.norm(a, axis=1, keepdims=True)


def naive_contrast(sim, window):
    out = np.empty_like(sim)
    half = window // 2
    for t in range(sim.shape[0]):
        for i in range(sim.shape[1]):
            patch = sim[t, max(0, i - half) : i + half + 1]
            out[t, i] = (sim[t, i] - patch.mean()) / max(patch.std(), 1e-6)
    return out


def naive_diagonal(sim, length, speed):
    frames, n = sim.shape
    out = np.zeros_like(sim)
    offs = frame_offsets(length, speed)
    for t in range(frames):
        for i in range(n):
            for step, o in enumerate(offs):
                if t - step >= 0 and 0 <= i - o < n:
                    out[t, i] += sim[t - step, i - o]
    return out


def naive_seqslam(q, x, length, speeds, window=None):
    sim = _unit(q) @ _unit(x).T
    if window is not None:
        sim = naive_contrast(sim, window)
    d = np.stack([naive_diagonal(sim, length, v) for v in speeds])  # (S, T, N)
    flat = d.transpose(1, 0, 2).reshape(len(q), -1)  # speed-major per query
    return flat.argmax(1) % x.shape[0], flat.max(1)


def _small(seed=0, frames=13, n=16, d=6):
    rng = np.random.default_rng(seed)
    return rng.normal(size=(frames, d)), rng.normal(size=(n, d))


def test_similarity_is_cosine():
    q, x = _small()
    np.testing.assert_allclose(
        np.asarray(similarity(q, x)), _unit(q) @ _unit(x).T, rtol=1e-5, atol=1e-6
    )


def test_contrast_matches_naive_loop():
    q, x = _small(1)
    sim = (_unit(q) @ _unit(x).T).astype(np.float32)
    got = np.asarray(enhance_contrast(sim, 5))
    np.testing.assert_allclose(got, naive_contrast(sim, 5), rtol=1e-4, atol=1e-4)


@pytest.mark.parametrize("speed", [1.0, 0.7, 1.5, -1.0])
def test_diagonal_sums_match_naive_loop(speed):
    q, x = _small(2)
    sim = (_unit(q) @ _unit(x).T).astype(np.float32)
    got = np.asarray(sequence_similarity(sim, 4, speed))
    np.testing.assert_allclose(got, naive_diagonal(sim, 4, speed), rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("window", [None, 5])
def test_decode_matches_naive_loop_across_chunks(window):
    q, x = _small(3)
    speeds = (0.8, 1.0, 1.5)
    index, score = seqslam_decode(
        q, x, 4, speeds, contrast_window=window, chunk=5, progress=False
    )
    want_index, want_score = naive_seqslam(q, x, 4, speeds, window)
    np.testing.assert_array_equal(np.asarray(index), want_index)
    np.testing.assert_allclose(np.asarray(score), want_score, rtol=1e-4, atol=1e-4)


def test_sequences_beat_single_frames_on_a_noisy_route():
    rng = np.random.default_rng(4)
    x = rng.normal(size=(300, 32)).astype(np.float32)
    truth = np.arange(40, 240)
    q = x[truth] + rng.normal(scale=2.0, size=(200, 32)).astype(np.float32)
    single, _ = seqslam_decode(q, x, 1, progress=False)
    seq, _ = seqslam_decode(q, x, 10, (0.9, 1.0, 1.1), progress=False)
    acc_single = np.mean(np.asarray(single) == truth)
    acc_seq = np.mean((np.asarray(seq) == truth)[9:])
    assert acc_single < 0.6 and acc_seq > 0.95, (acc_single, acc_seq)


def test_bad_inputs_raise():
    q, x = _small()
    with pytest.raises(InputError, match="share d"):
        seqslam_decode(q, x[:, :3], progress=False)
    with pytest.raises(InputError, match="length"):
        seqslam_decode(q, x, 0, progress=False)
    with pytest.raises(InputError, match="speeds"):
        seqslam_decode(q, x, 3, (), progress=False)


def _load_frames(folder):
    from skimage.io import imread

    files = sorted(folder.glob("*.png"))
    return np.stack([imread(f)[..., 0].astype(np.float32).ravel() for f in files])


def _patch_normalise(frames):
    centred = frames - frames.mean(axis=1, keepdims=True)
    return centred / np.maximum(centred.std(axis=1, keepdims=True), 1e-6)


@pytest.mark.slow
def test_nordland_summer_to_winter(nordland_root):
    """SeqSLAM on 64x32 grey pixels: summer map, winter queries, +-1 frame."""
    x = _patch_normalise(_load_frames(nordland_root / "summer"))
    q = _patch_normalise(_load_frames(nordland_root / "winter"))
    truth = np.arange(len(q))
    single, _ = seqslam_decode(q, x, 1, progress=False)
    seq, _ = seqslam_decode(q, x, 10, (0.8, 0.9, 1.0, 1.1, 1.2))
    acc_single = np.mean(np.abs(np.asarray(single) - truth) <= 1)
    acc_seq = np.mean(np.abs(np.asarray(seq) - truth) <= 1)
    print(
        f"nordland summer->winter +-1: single {acc_single:.4f} seq L=10 {acc_seq:.4f}"
    )
    assert acc_seq > 0.5 and acc_seq > acc_single + 0.3
