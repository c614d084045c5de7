"""The rows beside the map's: brute force summed along the diagonal at the map's
sequence length (against a float64 loop), SeqSLAM beside it."""

from __future__ import annotations

import numpy as np
import pytest

from rhythmic_jax import RhythmicMap
from rhythmic_jax.eval.report import evaluate_map
from rhythmic_jax.eval.report_text import format_evaluation

N, D = 60, 16


def unit(a: np.ndarray) -> np.ndarray:
    return (a / np.linalg.norm(a, axis=1, keepdims=True)).astype(np.float32)


@pytest.fixture(scope="module")
def case():
    """A map fitted on 60 random unit frames; noisy queries of the same places."""
    rng = np.random.default_rng(0)
    x = unit(rng.standard_normal((N, D)))
    q = unit(x + 0.3 * rng.standard_normal((N, D)))
    model = RhythmicMap().fit(x, progress=False)
    return model, x, q


def test_sequence_peers_sum_brute_force_along_the_diagonal(case):
    """With a sequence, brute force ranks its similarities summed over L frames
    (checked against a float64 loop) and SeqSLAM stands beside them."""
    from rhythmic_jax.eval.seqslam import seqslam_decode

    model, x, q = case
    L = 4
    res = evaluate_map(model, q, reference=x, sequence=L, tolerance=1, timing=False)
    assert set(res["methods"]) == {"map", "brute force", "SeqSLAM", "int8/place"}
    sims = q.astype(np.float64) @ x.astype(np.float64).T
    z = (sims - sims.mean(1, keepdims=True)) / sims.std(1, keepdims=True)
    acc = np.zeros_like(z)
    for t in range(len(q)):
        for lag in range(min(L, t + 1)):
            acc[t, lag:] += z[t - lag, : N - lag]
    top = np.argsort(-acc, axis=1)[:, :5]
    want = np.mean([(np.abs(top[i] - i) <= 1).any() for i in range(len(q))])
    assert res["methods"]["brute force"]["recall@5"] == pytest.approx(want)
    idx = seqslam_decode(q, x, L)[0]
    got = res["methods"]["SeqSLAM"]
    assert got["recall@1"] == pytest.approx(np.mean(np.abs(idx - np.arange(N)) <= 1))
    assert "recall@5" not in got and got["recall_line"].startswith("R@1: ")
    text = format_evaluation(res)
    assert "(peers at the same L=4)" in text and "single frames" not in text

