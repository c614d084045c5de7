"""PCA rows of the frontier against scikit-learn's PCA and numpy by hand."""

import numpy as np
import pytest

from rhythmic_jax.eval.frontier import FrontierConfig, frontier_rows, pareto_front
from rhythmic_jax.eval.frontier_pca import PcaCodes, pca_bytes, pca_dims

N, D = 120, 40


@pytest.fixture(scope="module")
def route():
    rng = np.random.default_rng(5)
    walk = np.cumsum(rng.standard_normal((N, D)), axis=0).astype(np.float32)
    ref = walk + 0.5 * rng.standard_normal((N, D)).astype(np.float32)
    qry = walk + 2.0 * rng.standard_normal((N, D)).astype(np.float32)
    return ref, qry


def _sklearn_scores(ref, qry, k):
    from sklearn.decomposition import PCA

    pca = PCA(k, svd_solver="full").fit(ref.astype(np.float64))
    return pca.transform(qry) @ pca.transform(ref).T, pca


def test_pca_codes_against_sklearn(route):
    ref, qry = route
    for k in (4, 16):
        want, pca = _sklearn_scores(ref, qry, k)
        book = PcaCodes.fit(ref, k)
        got = np.asarray(book.similarity(qry), np.float64)
        # the same subspace (axes up to sign): the same inner products
        np.testing.assert_allclose(got, want, rtol=1e-3, atol=1e-3 * abs(want).max())
        np.testing.assert_allclose(book.mean, pca.mean_, atol=1e-4)


def test_pca_int8_codes_by_hand(route):
    ref, qry = route
    want, pca = _sklearn_scores(ref, qry, 8)
    z = pca.transform(ref)
    lo, hi = z.min(0), z.max(0)
    codes = np.round((z - lo) / (hi - lo) * 255)
    back = codes / 255 * (hi - lo) + lo  # dequantised, numpy float64
    want8 = pca.transform(qry) @ back.T
    got = np.asarray(PcaCodes.fit(ref, 8, "int8").similarity(qry), np.float64)
    assert np.mean(got.argmax(1) == want8.argmax(1)) > 0.97
    np.testing.assert_allclose(got, want8, atol=2e-3 * abs(want8).max())


def test_pca_rows_recall_bytes_and_the_front(route):
    ref, qry = route
    cfg = FrontierConfig(maps=((2, 1),), bits=(), lengths=(1, 5), tolerance=1,
                         dtypes=("float32",), pca=(4, 16))  # fmt: skip
    rows = frontier_rows(ref, qry, cfg, seqslam=False)
    pca = {r["name"]: r for r in rows if r["name"].startswith("PCA")}
    assert set(pca) == {"PCA 4 float32", "PCA 4 int8", "PCA 16 float32", "PCA 16 int8"}
    for k in (4, 16):
        want, _ = _sklearn_scores(ref, qry, k)
        hit = np.abs(want.argmax(1) - np.arange(N)) <= 1
        assert pca[f"PCA {k} float32"]["recall@1 L=1"] == pytest.approx(hit.mean())
        # bytes: projection (d, k) and mean (d,) float32, and the codes
        assert pca[f"PCA {k} float32"]["storage_bytes"] == (D * k + D) * 4 + N * k * 4
        assert pca[f"PCA {k} int8"]["storage_bytes"] == (D * k + D) * 4 + N * k + 8 * k
        for dtype in ("float32", "int8"):
            row = pca[f"PCA {k} {dtype}"]
            assert row["latency_s"] > 0 and row["recall@1 L=5"] is not None
            assert row["share"] == row["storage_bytes"] / (N * D * 4)
    front = dict(zip([r["name"] for r in rows], pareto_front(rows), strict=True))
    for r in rows:  # PCA rows judged on the front like every other row
        key, size = "recall@1 L=1", "storage_bytes"
        beaten = any(
            o[size] <= r[size] and o[key] >= r[key]
            and (o[size] < r[size] or o[key] > r[key])
            for o in rows
        )  # fmt: skip
        assert front[r["name"]] == (not beaten)


def test_pca_dims_span_the_byte_range():
    n, d = 2356, 10976
    ks = pca_dims(n, d, 242 * n, 3820 * n)
    assert 2 <= len(ks) <= 4 and list(ks) == sorted(ks)
    sizes = [pca_bytes(n, d, k, t) for k in ks for t in ("float32", "int8")]
    assert min(sizes) <= 2 * 242 * n and max(sizes) >= 3820 * n / 2
    assert pca_dims(10, 4, 1e9, 2e9) == (1,)  # nothing fits: the smallest
