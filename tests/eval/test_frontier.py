"""Recall per byte: byte counts by hand, crossovers, frontier rows against faiss."""

import faiss
import numpy as np
import pytest

from rhythmic_jax.eval.frontier import (
    SEQUENCE_SCORERS,
    FrontierConfig,
    budget_table,
    crossover_n,
    fitted_codes,
    frontier_rows,
    projected_bytes,
    projection_rows,
    recall_at_full_precision,
    similarity_recalls,
)
from rhythmic_jax.map.codes import code_bytes, one_thread


def test_projected_bytes_by_hand():
    # N = 10^4, r = 2: candidates from 100; 100 and 101 are co-prime, 100*101 >= N
    assert projected_bytes(10**4, 256, 2) == (100 + 101) * 257 * 4
    # N = 10^6, r = 3: 100, 101, 103 (102 shares 2 with 100)
    assert projected_bytes(10**6, 256, 3) == (100 + 101 + 103) * 257 * 4
    # level 2 doubles the start
    assert projected_bytes(10**4, 256, 2, 2) == (200 + 201) * 257 * 4


def test_crossover_is_where_the_sizes_cross():
    until, since = crossover_n(10976, 64, 2)
    assert until is not None and since is not None and until < since
    for n, smaller in [(until, True), (since, True), (since // 2, False)]:
        assert (
            projected_bytes(n, 10976) < code_bytes(n, 10976, 64)["total"]
        ) == smaller
    # at d = 256, r = 3 a map is smaller than 512-bit codes at every N
    assert crossover_n(256, 512, 3) == (10**12, 100)


def test_similarity_recalls_diagonal_by_hand():
    sims = np.full((6, 6), 0.0, np.float32)
    sims[np.arange(6), np.arange(6)] = 1.0
    sims[3] = 0.0
    sims[3, 0] = 0.5  # frame 3 alone is wrong; with its two predecessors it is right
    got = similarity_recalls(sims, (1, 3), 0)
    assert got[1] == pytest.approx(5 / 6) and got[3] == 1.0


def test_budget_table_picks_the_best_within_each_budget():
    rows = [
        {"kind": "codes", "name": "ITQ c", "share": 0.03, "recall@1 L=1": 0.2},
        {"kind": "codes", "name": "PCA 4 int8", "share": 0.02, "recall@1 L=1": 0.25},
        {"kind": "map", "name": "m", "share": 0.05, "recall@1 L=1": 0.1},
        {"kind": "hybrid", "name": "h", "share": 0.08, "recall@1 L=1": 0.3},
    ]
    b = budget_table(rows, (0.04, 0.06, 0.1))
    assert b[0]["own"] is None and b[0]["own_minus_itq"] == pytest.approx(-0.2)
    assert b[1]["best"]["name"] == "PCA 4 int8" and b[1]["own"]["name"] == "m"
    assert b[1]["itq"]["name"] == "ITQ c"  # ITQ's best, not any code's
    assert b[2]["best"]["name"] == "h" and b[2]["own_minus_itq"] == pytest.approx(0.1)


@pytest.mark.slow
def test_frontier_rows_against_faiss(tmp_path):
    rng = np.random.default_rng(0)
    x = rng.normal(size=(150, 32)).astype(np.float32)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    q = x + 0.1 * rng.normal(size=x.shape).astype(np.float32)
    cfg = FrontierConfig(maps=((2, 1),), bits=(16,), lengths=(1,), tolerance=0)
    listed = frontier_rows(x, q, cfg, cache=tmp_path)

    timed = ("latency_s", "latency_p95_s", "queries_per_s", "batch_s")

    def untimed(rows):  # latency is measured anew on every call
        return [{k: v for k, v in r.items() if k not in timed} for r in rows]

    again = frontier_rows(x, q, cfg, cache=tmp_path)
    assert untimed(again) == untimed(listed)  # fits kept, reused
    assert len(list(tmp_path.glob("*.npz"))) == 1  # the codes
    assert len(list(tmp_path.glob("map-*/map.json"))) == 1  # a map folder
    for r in listed:  # every row but SeqSLAM timed from the query descriptors
        assert (r["kind"] == "SeqSLAM") == (r.get("latency_s") is None), r["name"]
        if r["kind"] != "SeqSLAM":
            assert r["latency_s"] > 0 and r["queries_per_s"] > 0
    maps = {r["dtype"]: r for r in listed if r["kind"] == "map"}
    p = sum(maps["float32"]["periods"])
    assert maps["float32"]["storage_bytes"] == p * 33 * 4
    assert maps["int8"]["storage_bytes"] == p * 33 + 4 * p  # int8 + a scale each
    rows = {r["kind"]: r for r in listed if not r["name"].startswith("PCA")}
    assert rows["SeqSLAM"]["storage_bytes"] == 150 * 32 * 4
    # brute force and the codes against faiss on the same data
    _, top = faiss.knn(q, x, 1, faiss.METRIC_INNER_PRODUCT)
    assert rows["brute force"]["recall@1 L=1"] == np.mean(top[:, 0] == np.arange(150))
    itq = _faiss_itq_one_thread(x, 16)  # the codes' fit runs on one thread
    dist, idx = itq.search(q, 150)  # Hamming distance to every place
    full = np.empty((150, 150))
    np.put_along_axis(full, idx, dist, axis=1)
    assert rows["codes"]["recall@1 L=1"] == np.mean(full.argmin(1) == np.arange(150))
    assert rows["codes"]["storage_bytes"] == 150 * 2 + (16 * 32 + 32) * 4
    assert rows["hybrid"]["storage_bytes"] == (
        rows["map"]["storage_bytes"] + rows["codes"]["storage_bytes"]
    )
    assert rows["hybrid"]["weight"] == 0.5  # no training places: the fixed weight


def test_projection_rows_by_hand():
    (row,) = projection_rows((256,), (10**4,), (64,), rs=(2,))
    assert row["map N=1e+04"] == (100 + 101) * 257 * 4
    assert (row["until 64"], row["since 64"]) == crossover_n(256, 64, 2)


def test_recall_at_full_precision_against_sklearn():
    from sklearn.metrics import precision_recall_curve

    rng = np.random.default_rng(1)
    idx = np.where(rng.random(50) < 0.7, np.arange(50), rng.integers(0, 50, 50))
    conf = rng.random(50)
    ok = idx == np.arange(50)
    p, r, _ = precision_recall_curve(ok, conf)
    want = r[p == 1.0].max() * ok.sum() / 50  # sklearn's recall is out of ok.sum()
    assert recall_at_full_precision(idx, conf, 0) == pytest.approx(want)


def _faiss_itq_one_thread(x, bits):
    """faiss's ITQ + LSH index fitted on x (n, d) on one thread, the reference."""
    itq = faiss.IndexPreTransform(
        faiss.ITQTransform(x.shape[1], bits, True),
        faiss.IndexLSH(bits, bits, False, False),
    )
    with one_thread():
        itq.train(x)
    itq.add(x)
    return itq


def test_fitted_codes_do_not_depend_on_the_callers_threads():
    """A fit on one thread and one on two gave other codes on these frames; the
    fit pins one thread and leaves the caller's count as it was."""
    from threadpoolctl import threadpool_limits

    rng = np.random.default_rng(0)
    x = np.cumsum(rng.standard_normal((200, 300)), axis=0).astype(np.float32)
    before = faiss.omp_get_max_threads()
    books = []
    try:
        for threads in (1, 2):
            with threadpool_limits(limits=threads):
                faiss.omp_set_num_threads(threads)
                books.append(fitted_codes(x, 16))
                assert faiss.omp_get_max_threads() == threads
    finally:
        faiss.omp_set_num_threads(before)
    one, two = books
    np.testing.assert_array_equal(one.transform.projection, two.transform.projection)
    np.testing.assert_array_equal(one.codes, two.codes)
    # the same codes as faiss's own ITQ + LSH index fitted on one thread
    itq = _faiss_itq_one_thread(x, 16)
    want = itq.sa_encode(x)  # (200, 2) packed, least significant bit first
    np.testing.assert_array_equal(np.packbits(one.codes, 1, "little"), want)


def _diagonal_recall(sims, length):
    """numpy float64: per-frame z-scored similarities (T, n) summed along the
    diagonal over the last ``length`` frames; recall@1 (query t is place t) as
    (place t the only best, place t among the best): codes' sums tie exactly."""
    sims = np.asarray(sims, np.float64)
    z = (sims - sims.mean(1, keepdims=True)) / sims.std(1, keepdims=True)
    t, n = z.shape
    acc = np.zeros_like(z)
    for step in range(length):
        acc[step:, step:] += z[: t - step, : n - step]
    own = acc[np.arange(t), np.arange(t)]
    best = np.sort(acc, axis=1)
    near = 1e-6 * np.abs(best[:, -1]).max()
    among = own >= best[:, -1] - near
    alone = among & (best[:, -2] < best[:, -1] - near)
    return np.mean(alone), np.mean(among)


def test_frontier_sequence_rows_sum_along_the_diagonal_against_numpy():
    rng = np.random.default_rng(3)
    x = rng.standard_normal((120, 48)).astype(np.float32)
    q = x + 3.0 * rng.standard_normal(x.shape).astype(np.float32)
    cfg = FrontierConfig(maps=(), bits=(32,), lengths=(1, 4), tolerance=0)
    listed = frontier_rows(x, q, cfg)
    rows = {r["kind"]: r for r in listed if not r["name"].startswith("PCA")}
    for kind, row in rows.items():
        assert row["sequence_scorer"] == SEQUENCE_SCORERS[kind]
    assert rows["codes"]["sequence_scorer"] == "diagonal sum"
    assert rows["SeqSLAM"]["sequence_scorer"] == "SeqSLAM"
    # brute force: inner products in float64
    brute = q.astype(np.float64) @ x.astype(np.float64).T
    low, high = _diagonal_recall(brute, 4)
    assert low == high == pytest.approx(rows["brute force"]["recall@1 L=4"])
    # codes: bits shared with each place, from faiss's Hamming distances
    itq = _faiss_itq_one_thread(x, 32)
    dist, idx = itq.search(q, 120)
    shared = np.empty((120, 120))
    np.put_along_axis(shared, idx, 32 - dist, axis=1)
    got = rows["codes"]["recall@1 L=4"]
    low, high = _diagonal_recall(shared, 4)
    assert low - 1e-12 <= got <= high + 1e-12 and high - low < 0.02
    assert got > rows["codes"]["recall@1 L=1"]  # the sequence helps these queries
    single = frontier_rows(x, q, FrontierConfig(maps=(), bits=(32,), lengths=(1,)))
    assert all(r["sequence_scorer"] is None for r in single)
