"""evaluate's rows at the map's bytes (int8 per place, PCA) and brute force on a
map's embedding, recomputed in numpy and scikit-learn from the raw arrays: the
places, recall@K, accuracy, PR-AUC, recall at 100 % precision and the bytes."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.decomposition import PCA
from sklearn.metrics import auc

from rhythmic_jax import RhythmicMap
from rhythmic_jax.eval.budget_peers import at_bytes, pca_dims
from rhythmic_jax.eval.report import evaluate_map, format_evaluation


def unit(a: np.ndarray) -> np.ndarray:
    return (a / np.linalg.norm(a, axis=1, keepdims=True)).astype(np.float32)


def route(n: int, d: int, noise: float, seed: int = 0):
    rng = np.random.default_rng(seed)
    x = unit(rng.standard_normal((n, d)))
    q = unit(x + noise * rng.standard_normal((n, d)))
    return x, q


def int8_cosine(x: np.ndarray, q: np.ndarray) -> np.ndarray:
    """faiss's 8-bit min-max codec, decoded, and the cosine, in float64."""
    x = x.astype(np.float64)
    lo, hi = x.min(0), x.max(0)
    span = np.where(hi > lo, hi - lo, 1.0)
    codes = np.floor(255 * np.clip((x - lo) / span, 0, 1))
    ref = lo + (codes + 0.5) / 255 * span
    ref /= np.linalg.norm(ref, axis=1, keepdims=True)
    qq = q / np.linalg.norm(q, axis=1, keepdims=True)
    return qq @ ref.T


def pr_loop(score, ok, n_pos):
    """VPR_Tutorial's createPR by thresholds, one at a time: (precision, recall)."""
    precision, recall = [1.0], [0.0]
    for th in np.unique(score)[::-1]:
        sel = score >= th
        tp = ok[sel].sum()
        precision.append(tp / sel.sum())
        recall.append(tp / n_pos)
    return np.array(precision), np.array(recall)


def check_row(row, sims, tol: int, size: int):
    """The row of a method whose similarities (b, n) rank the places."""
    b = len(sims)
    truth = np.arange(b)
    order = np.argsort(-sims, axis=1, kind="stable")
    best = order[:, 0]
    assert row["accuracy"] == pytest.approx(np.mean(best == truth))
    assert row["accuracy_tol"] == pytest.approx(np.mean(np.abs(best - truth) <= tol))
    for k in (1, 5, 10):
        hit = [(np.abs(order[i, :k] - i) <= tol).any() for i in range(b)]
        assert row[f"recall@{k}"] == pytest.approx(np.mean(hit)), k
    ok = np.abs(best - truth) <= tol
    precision, recall = pr_loop(sims[np.arange(b), best], ok, b)
    assert row["pr_auc"] == pytest.approx(auc(recall, precision), abs=1e-9)
    assert row["recall@100p"] == pytest.approx(recall[precision == 1.0].max())
    assert row["storage_bytes"] == size


def test_int8_per_place_when_it_fits_the_maps_bytes():
    n, d = 60, 16
    x, q = route(n, d, 0.6)
    model = RhythmicMap(r=2, level=1).fit(x)
    budget = model.storage_bytes
    assert n * d + 2 * d * 4 <= budget  # int8 fits: it is the row
    res = evaluate_map(model, q, reference=x, tolerance=1, timing=True)
    row = res["methods"]["int8/place"]
    check_row(row, int8_cosine(x, q), 1, n * d + 2 * d * 4)
    assert 0 < row["accuracy"] < 1  # the noise makes it non-trivial
    assert row["latency_median_s"] > 0 and row["queries_per_s"] > 0
    assert any(n.startswith("int8 per place:") for n in res["peer_notes"])


def test_pca_to_the_maps_bytes_when_int8_does_not_fit():
    n, d = 200, 32
    x, q = route(n, d, 0.5, seed=1)
    model = RhythmicMap(r=2, level=1).fit(x)
    budget = model.storage_bytes
    assert n * d + 2 * d * 4 > budget  # int8 is too large here
    k = pca_dims(n, d, budget)
    assert 4 * (d + d * k + n * k) <= budget < 4 * (d + d * (k + 1) + n * (k + 1))
    res = evaluate_map(model, q, reference=x, tolerance=0, timing=False)
    row = res["methods"][f"PCA {k}"]
    pca = PCA(n_components=k, svd_solver="full").fit(x.astype(np.float64))
    recon = pca.inverse_transform(pca.transform(x.astype(np.float64)))
    sims = q.astype(np.float64) @ recon.T  # inner product with the reconstruction
    check_row(row, sims, 0, 4 * (d + d * k + n * k))
    assert row["storage_bytes"] <= budget
    text = format_evaluation(res)
    assert f"PCA {k}: {k} of {d} dims in float32" in text


def test_brute_force_on_the_embedding():
    from rhythmic_jax.fitting.learn import LearnConfig, learn_embedding

    n, d = 60, 16
    x, q = route(n, d, 0.6, seed=2)
    emb, _ = learn_embedding([x, q], LearnConfig(method="pca", k=8))
    model = RhythmicMap(r=2, level=1, embedding=emb).fit(x)
    res = evaluate_map(model, q, reference=x, tolerance=1, timing=False)

    def embed(a):  # the embedding's formula, in float64
        a = a.astype(np.float64)
        z = (a - np.asarray(emb.mean)) @ np.asarray(emb.proj, np.float64)
        h = np.maximum(z @ np.asarray(emb.w1) + np.asarray(emb.b1), 0)
        z = z + h @ np.asarray(emb.w2)
        return z / np.linalg.norm(z, axis=1, keepdims=True)

    sims = embed(q) @ embed(x).T
    check_row(res["methods"]["embedded BF"], sims, 1,
              n * 8 * 4 + model.embedding_bytes)  # fmt: skip


def test_nothing_fits_a_tiny_budget():
    x, _ = route(30, 64, 0.1)
    said = at_bytes(x, 100)
    assert isinstance(said, str) and said.startswith("no baseline at the map's 100 B")


def test_two_traversals_one_database_for_every_share():
    """The map's share is over the frames brute force searches (both traversals)."""
    n, d = 60, 16
    x, q = route(n, d, 0.3, seed=3)
    second = unit(x + 0.2 * np.random.default_rng(4).standard_normal((n, d)))
    model = RhythmicMap(r=2, level=1, codes="int8").fit(x)  # int8 of both fits
    ref = np.concatenate([x, second])
    labels = np.r_[np.arange(n), np.arange(n)]
    res = evaluate_map(model, q, reference=ref, reference_labels=labels,
                       timing=False)  # fmt: skip
    assert res["database_bytes"] == res["methods"]["brute force"]["storage_bytes"]
    assert res["database_bytes"] == 2 * n * d * 4
    want = model.storage_bytes / (2 * n * d * 4)
    assert res["compression_ratio"] == pytest.approx(want)
    assert res["methods"]["map"]["storage_share"] == res["compression_ratio"]
    # int8 of both traversals, each place's best frame ranked
    sims = int8_cosine(ref, q)
    place = np.maximum(sims[:, :n], sims[:, n:])
    check_row(res["methods"]["int8/place"], place, 0, 2 * n * d + 2 * d * 4)


def test_int8_with_a_sequence_sums_z_scores_along_the_diagonal():
    """With --sequence L, the row at the map's bytes ranks its similarities
    summed over L frames, as brute force's do (a float64 loop here)."""
    n, d, L = 60, 16, 3
    x, q = route(n, d, 0.9, seed=5)
    model = RhythmicMap(r=2, level=1).fit(x)
    res = evaluate_map(model, q, reference=x, sequence=L, tolerance=1, timing=False)
    sims = int8_cosine(x, q)
    z = (sims - sims.mean(1, keepdims=True)) / sims.std(1, keepdims=True)
    acc = np.zeros_like(z)
    for t in range(n):
        for lag in range(min(L, t + 1)):
            acc[t, lag:] += z[t - lag, : n - lag]
    row = res["methods"]["int8/place"]
    for k in (1, 5):
        top = np.argsort(-acc, axis=1)[:, :k]
        want = np.mean([(np.abs(top[i] - i) <= 1).any() for i in range(n)])
        assert row[f"recall@{k}"] == pytest.approx(want), k
