"""evaluate_map and ranked_places against plain numpy loops and scikit-learn's
exact cosine nearest neighbours."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.neighbors import NearestNeighbors

from rhythmic_jax import RhythmicMap
from rhythmic_jax.eval.report import evaluate_map, format_evaluation, ranked_places
from rhythmic_jax.map.periods import period_offsets

N, D = 60, 16


def unit(a: np.ndarray) -> np.ndarray:
    return (a / np.linalg.norm(a, axis=1, keepdims=True)).astype(np.float32)


def summed_scores(scores, periods, n: int) -> np.ndarray:
    """(b, n) totals ``sum_k scores[:, offset_k + i % tau_k]``, one place at a time."""
    scores = np.asarray(scores, np.float64)
    offs = period_offsets(periods)
    total = np.zeros((scores.shape[0], n))
    for i in range(n):
        for off, tau in zip(offs, periods, strict=True):
            total[:, i] += scores[:, off + i % tau]
    return total


def top_k(total: np.ndarray, k: int) -> np.ndarray:
    return np.argsort(-total, axis=1, kind="stable")[:, :k]


def recall_loop(ranked, gt, k: int, tol: int) -> float:
    hits = [
        any(abs(int(c) - int(g)) <= tol for c in row[:k])
        for row, g in zip(ranked, gt, strict=True)
        if g != -1
    ]
    return float(np.mean(hits))


def accuracy_loop(pred, gt, tol: int) -> float:
    ok = [
        p == -1 if g == -1 else (p != -1 and abs(int(p) - int(g)) <= tol)
        for p, g in zip(pred, gt, strict=True)
    ]
    return float(np.mean(ok))


@pytest.fixture(scope="module")
def case():
    """A map fitted on 60 random unit frames; noisy queries of the same places."""
    rng = np.random.default_rng(0)
    x = unit(rng.standard_normal((N, D)))
    q = unit(x + 0.3 * rng.standard_normal((N, D)))
    model = RhythmicMap().fit(x, progress=False)
    return model, x, q


# ---------------------------------------------------------------- ranked_places
@pytest.mark.parametrize(
    ("periods", "n", "seed"), [((5, 7), 30, 1), ((3, 4, 5), 50, 2), ((6, 11), 66, 3)]
)
def test_ranked_places_matches_numpy_loop(periods, n, seed):
    rng = np.random.default_rng(seed)
    scores = rng.standard_normal((9, sum(periods))).astype(np.float32)
    got = ranked_places(scores, periods, n, k=10)
    total = summed_scores(scores, periods, n)
    assert got.shape == (9, 10)
    np.testing.assert_array_equal(got, top_k(total, 10))
    # best first: the totals of the returned places are the sorted top totals
    np.testing.assert_allclose(
        np.take_along_axis(total, got, axis=1),
        -np.sort(-total, axis=1)[:, :10],
        rtol=1e-5,
        atol=1e-5,
    )


def test_ranked_places_k_clipped_to_n_and_default_k():
    rng = np.random.default_rng(4)
    scores = rng.standard_normal((5, 5)).astype(np.float32)
    got = ranked_places(scores, [2, 3], 4, k=10)
    assert got.shape == (5, 4)
    assert all(sorted(row) == [0, 1, 2, 3] for row in got.tolist())
    np.testing.assert_array_equal(got, top_k(summed_scores(scores, (2, 3), 4), 4))
    assert ranked_places(scores, (2, 3), 6).shape == (5, 6)
    wide = rng.standard_normal((3, 12)).astype(np.float32)
    assert ranked_places(wide, (5, 7), 35).shape == (3, 10)  # k defaults to 10


def test_ranked_places_of_a_map_matches_loop(case):
    model, _, q = case
    scores = np.asarray(model.scores(q))
    got = ranked_places(scores, model.periods, model.n, k=5)
    total = summed_scores(scores, model.periods, model.n)
    np.testing.assert_array_equal(got, top_k(total, 5))


# ------------------------------------------------------------------ evaluate_map
def test_map_row_matches_predict_and_ranked_loop(case):
    model, _, q = case
    gt = np.arange(N)
    res = evaluate_map(model, q, tolerance=2, timing=False)
    row = res["methods"]["map"]
    pred = model.predict(q)
    assert row["accuracy"] == pytest.approx((pred == gt).mean())
    # the hard decode answers -1 when the periods disagree: never within tolerance
    assert (pred == -1).any()
    near = (pred != -1) & (np.abs(pred - gt) <= 2)
    assert row["accuracy_tol"] == pytest.approx(near.mean())
    assert row["accuracy"] <= row["accuracy_tol"]
    ranked = top_k(summed_scores(model.scores(q), model.periods, model.n), 10)
    for k in (1, 5, 10):
        assert row[f"recall@{k}"] == pytest.approx(recall_loop(ranked, gt, k, 2))
    assert row["recall@1"] <= row["recall@5"] <= row["recall@10"]
    assert row["tolerance"] == 2 and row["n_queries"] == N
    assert row["storage_bytes"] == sum(model.periods) * (D + 1) * 4
    assert row["periods"] == list(model.periods)
    assert "latency_median_s" not in row and "queries_per_s" not in row
    assert list(res["methods"]) == ["map"]  # no reference: no brute-force row


def test_result_header_fields(case):
    model, _, q = case
    res = evaluate_map(model, q[:25], tolerance=1, timing=False)
    assert res["n"] == N and res["d"] == D and res["n_queries"] == 25
    assert res["tolerance"] == 1
    assert res["decode"] == "hard" and res["sequence"] is None
    assert res["database_bytes"] == N * D * 4
    assert res["compression_ratio"] == pytest.approx(
        sum(model.periods) * (D + 1) / (N * D)
    )
    assert res["compression_ratio"] == pytest.approx(
        res["methods"]["map"]["storage_bytes"] / res["database_bytes"]
    )


def test_map_row_with_given_gt_and_decode(case):
    """gt given (a shuffled query order, one outlier) and another decode."""
    model, _, q = case
    rng = np.random.default_rng(5)
    order = rng.permutation(N)
    gt = order.copy()
    gt[7] = -1
    res = evaluate_map(model, q[order], gt=gt, method="soft", timing=False)
    assert res["decode"] == "soft"
    row = res["methods"]["map"]
    pred = model.predict(q[order], "soft")
    assert row["accuracy"] == pytest.approx((pred == gt).mean())
    ranked = top_k(summed_scores(model.scores(q[order]), model.periods, N), 10)
    for k in (1, 5, 10):
        assert row[f"recall@{k}"] == pytest.approx(recall_loop(ranked, gt, k, 0))
    assert row["n_queries"] == N - 1  # the outlier is left out of recall


def test_a_top_m_decode_without_rivals_is_scored(case):
    """A top-m decode whose kept phases leave a query one candidate place has
    confidence 0 (no rival, finite): the PR curve ranks it last, not an error."""
    model, _, q = case
    out = model.decode(q, "topm")
    conf = np.asarray(out.confidence)
    alone = (np.asarray(out.index) >= 0) & np.isneginf(np.asarray(out.runner_up))
    assert alone.any() and (conf[alone] == 0).all()  # the case this covers
    assert np.isfinite(conf).all()
    res = evaluate_map(model, q, method="topm", timing=False)
    row = res["methods"]["map"]
    assert row["accuracy"] == pytest.approx(
        (model.predict(q, "topm") == np.arange(N)).mean()
    )
    assert 0.0 <= row["pr_auc"] <= 1.0


@pytest.mark.parametrize("tol", [0, 3])
def test_brute_force_row_matches_sklearn_cosine(case, tol):
    model, x, q = case
    gt = np.arange(N)
    res = evaluate_map(model, q, reference=x, tolerance=tol, timing=False)
    row = res["methods"]["brute force"]
    nn = NearestNeighbors(metric="cosine", algorithm="brute").fit(x)
    idx = nn.kneighbors(q, n_neighbors=10, return_distance=False)
    # the same neighbours as a plain argmax of normalised dot products
    np.testing.assert_array_equal(idx[:, 0], np.argmax(unit(q) @ unit(x).T, axis=1))
    assert row["accuracy"] == pytest.approx(accuracy_loop(idx[:, 0], gt, 0))
    assert row["accuracy_tol"] == pytest.approx(accuracy_loop(idx[:, 0], gt, tol))
    for k in (1, 5, 10):
        assert row[f"recall@{k}"] == pytest.approx(recall_loop(idx, gt, k, tol))
    assert row["recall@1"] == pytest.approx(row["accuracy_tol"])
    assert row["storage_bytes"] == N * D * 4
    assert row["tolerance"] == tol and row["n_queries"] == N
    assert 0 < row["accuracy"] < 1  # the noise makes the case non-trivial
    assert list(res["methods"])[:2] == ["map", "brute force"]


def test_brute_force_row_with_reference_labels(case):
    """Two shuffled traversals of the route: references map to places by label."""
    model, x, q = case
    rng = np.random.default_rng(6)
    second = unit(x + 0.15 * rng.standard_normal((N, D)))
    perm = rng.permutation(2 * N)
    reference = np.concatenate([x, second])[perm]
    labels = np.concatenate([np.arange(N), np.arange(N)])[perm]
    gt = np.arange(N)
    res = evaluate_map(
        model,
        q,
        reference=reference,
        reference_labels=labels,
        tolerance=1,
        timing=False,
    )
    row = res["methods"]["brute force"]
    nn = NearestNeighbors(metric="cosine", algorithm="brute").fit(reference)
    places = labels[nn.kneighbors(q, n_neighbors=10, return_distance=False)]
    assert row["accuracy"] == pytest.approx(accuracy_loop(places[:, 0], gt, 0))
    assert row["accuracy_tol"] == pytest.approx(accuracy_loop(places[:, 0], gt, 1))
    for k in (1, 5, 10):
        assert row[f"recall@{k}"] == pytest.approx(recall_loop(places, gt, k, 1))
    assert row["storage_bytes"] == 2 * N * D * 4
    # without the labels the row indices are compared with gt: a different answer
    plain = evaluate_map(model, q, reference=reference, tolerance=1, timing=False)
    raw = nn.kneighbors(q, n_neighbors=1, return_distance=False)[:, 0]
    assert plain["methods"]["brute force"]["accuracy"] == pytest.approx(
        accuracy_loop(raw, gt, 0)
    )
    assert plain["methods"]["brute force"]["accuracy"] < row["accuracy"]


def test_timing_adds_positive_latency_and_throughput(case):
    model, x, q = case
    res = evaluate_map(model, q[:12], reference=x, timing=True)
    for name in ("map", "brute force"):
        row = res["methods"][name]
        for key in ("latency_median_s", "latency_p95_s", "queries_per_s"):
            assert row[key] > 0, (name, key)
        assert row["latency_median_s"] <= row["latency_p95_s"]


def test_the_embedding_is_counted_and_a_fusion_of_zero_is_the_codes_alone(case):
    """A map with an embedding: its share, its bytes in the table and every
    part of its recall-per-byte rows count the embedding's bytes; at a fusion
    weight of 0 the row is named for what decides, the codes alone."""
    from rhythmic_jax.fitting.learn import LearnConfig, learn_embedding

    _, x, q = case
    emb, _ = learn_embedding([x, q], LearnConfig(method="pca", k=8))
    model = RhythmicMap(codes=8, fusion=0.0, embedding=emb).fit(x)
    res = evaluate_map(model, q, reference=x, timing=False, curves=True)
    row, extra = res["methods"]["map"], model.embedding_bytes
    assert extra > 0
    total = model.storage_bytes + extra
    assert row["storage_share"] == pytest.approx(total / (N * D * 4))
    assert res["compression_ratio"] == pytest.approx(row["storage_share"])
    assert row["label"] == "codes alone"
    table = format_evaluation(res).split("\n")
    assert table[5].startswith(f"{'codes alone':<12}") and f"{total:,}" in table[5]
    assert any(line.startswith("bytes: what a query needs") for line in table)
    parts = {r["kind"]: r for r in res["frontier"]}
    assert parts["hybrid"]["name"] == "codes alone (fusion 0) + embedding"
    assert parts["hybrid"]["storage_bytes"] == total
    assert min(parts[k]["storage_bytes"] for k in ("codes", "map")) > extra
    plain = RhythmicMap(codes=8, fusion=0.5).fit(x)
    assert evaluate_map(plain, q, timing=False)["methods"]["map"]["label"] == (
        "map + codes"
    )


def test_every_timed_function_maps_query_descriptors_to_that_rows_places(
    case, monkeypatch
):
    """What each row's latency times: a function of the raw query descriptors
    (the very array evaluate_map was given) that returns the row's own places,
    so a map's time includes its template product and embedding, a code's its
    encoding, brute force's its label lookup."""
    from rhythmic_jax.eval import peer_rows, report
    from rhythmic_jax.fitting.learn import LearnConfig, learn_embedding

    _, x, q = case
    rng = np.random.default_rng(8)
    second = unit(x + 0.1 * rng.standard_normal((N, D)))
    emb, _ = learn_embedding([x, q], LearnConfig(method="pca", k=8))
    timed = []

    def record(fn, queries):
        timed.append((fn, queries))
        return {"latency_median_s": 1.0, "queries_per_s": 1.0}

    monkeypatch.setattr(report, "query_latency", record)
    monkeypatch.setattr(peer_rows, "query_latency", record)
    for model in (RhythmicMap(r=2, level=1, codes="int8").fit(x),
                  RhythmicMap(r=2, level=1, embedding=emb).fit(x)):  # fmt: skip
        timed.clear()
        res = evaluate_map(model, q, reference=np.concatenate([x, second]),
                           reference_labels=np.r_[np.arange(N), np.arange(N)],
                           curves=True)  # fmt: skip
        rows = res["methods"]
        assert len(timed) == len(rows) >= 3
        for (fn, got), (name, row) in zip(timed, rows.items(), strict=True):
            assert np.array_equal(np.asarray(got), q), name  # raw descriptors
            places = np.asarray(fn(got)).reshape(-1)
            np.testing.assert_array_equal(places, row["predictions"], err_msg=name)
        if model.embedding is not None:
            assert "embedded BF" in rows
