"""Large batches decoded on the device in fixed chunks: the same answers as one
pass over the whole batch, one program per bucket of chunks, no (b, p) scores."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_batch import compiles

import rhythmic_jax as rj
from rhythmic_jax.decoding import batch, buckets, fusion, hard, queries
from rhythmic_jax.decoding.batch import decode_queries, sequence_queries
from rhythmic_jax.decoding.dispatch import decode_scores
from rhythmic_jax.decoding.hard import decode
from rhythmic_jax.decoding.sequence import sequence_decode
from rhythmic_jax.map.groups import Groups
from rhythmic_jax.solvers.objective import Templates, scores

SMALL = 32  # the chunk the tests decode by: batches of 33-64 rows take 2 chunks

LAYOUTS = [
    (Groups("periods", (5, 7)), 33),
    (Groups("mixed", (5, 4, 5)), 83),
    (Groups("hierarchical", (7, 2, 3), 6), 40),
]


@pytest.fixture
def small_chunks(monkeypatch):
    monkeypatch.setattr(buckets, "CHUNK", SMALL)


def _templates(d: int, p: int, seed: int = 0) -> Templates:
    rng = np.random.default_rng(seed)
    return Templates(
        jnp.asarray(rng.normal(size=(d, p)), jnp.float32),
        jnp.asarray(rng.normal(size=p), jnp.float32),
    )


def _queries(b: int, d: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=(b, d)).astype(np.float32)


def _same(got, want, rtol=1e-5):
    """Equal places; scores to ``rtol``: XLA's CPU product of a 32-row chunk
    sums in another order than one of the whole batch (measured: 4e-6
    relative on a score of 0.05)."""
    np.testing.assert_array_equal(np.asarray(got[0]), np.asarray(want[0]))
    for g, w in zip(got[1:], want[1:], strict=True):
        assert np.shape(g) == np.shape(w)
        np.testing.assert_allclose(np.asarray(g), np.asarray(w), rtol=rtol)


def test_chunk_is_a_power_of_two_bucket():
    assert buckets.CHUNK & (buckets.CHUNK - 1) == 0
    assert buckets.bucket(buckets.CHUNK) == buckets.CHUNK
    assert [buckets.chunk_count(b, 32) for b in (0, 1, 32, 33, 64, 65)] == [
        1, 1, 1, 2, 2, 3,
    ]  # fmt: skip


@pytest.mark.parametrize(("groups", "n"), LAYOUTS)
@pytest.mark.parametrize("method", ["hard", "soft", "topm"])
@pytest.mark.parametrize("b", [31, 33, 64, 65, 129])
def test_chunked_decode_equals_one_pass(small_chunks, groups, n, method, b):
    """Batches on both sides of a chunk and of a bucket (64: 2 chunks, 65: 3
    chunks in a bucket of 4, one of them padding)."""
    params = _templates(6, groups.p, seed=b)
    q = _queries(b, 6, seed=b + 1)
    want = decode_scores(scores(params, jnp.asarray(q)), groups, n, method, 2)
    _same(decode_queries(params, q, groups, n, method, 2), want)
    if method == "hard":  # the kernel's own entry: a device batch and float64
        _same(decode(params, jnp.asarray(q), groups, n), want)
        _same(decode(params, q.astype(np.float64), groups, n), want)


@pytest.mark.parametrize(("groups", "n"), LAYOUTS)
@pytest.mark.parametrize("method", ["soft", "hard"])
def test_chunked_sequence_decode_equals_one_pass(small_chunks, groups, n, method):
    """Every chunk sees the ``length - 1`` frames before it (here across two
    chunk boundaries), and the first frames none."""
    params = _templates(4, groups.p, seed=3)
    q = _queries(75, 4, seed=4)
    speeds = (0.9, 1.0, 1.2)
    idx, conf = sequence_queries(params, q, groups, n, 5, speeds, method)
    want = sequence_decode(scores(params, jnp.asarray(q)), groups, n, 5, speeds, method)
    assert idx.shape == (75,)
    np.testing.assert_array_equal(np.asarray(idx), np.asarray(want[0]))
    atol = 16 * np.finfo(np.float32).eps  # as test_batch: sums in another order
    np.testing.assert_allclose(conf, want[1], rtol=1e-6, atol=atol)


def test_a_sequence_longer_than_a_chunk(small_chunks):
    groups, n = Groups("periods", (5, 7)), 35
    params = _templates(4, 12, seed=5)
    q = _queries(100, 4, seed=6)
    idx, conf = sequence_queries(params, q, groups, n, 40, (1.0,), "soft")
    want = sequence_decode(scores(params, jnp.asarray(q)), groups, n, 40)
    np.testing.assert_array_equal(np.asarray(idx), np.asarray(want[0]))
    np.testing.assert_allclose(conf, want[1], rtol=1e-5, atol=1e-5)


def test_one_program_per_bucket_of_chunks(small_chunks):
    groups, n = Groups("periods", (7, 11)), 70  # a layout no other test uses
    params = _templates(9, 18, seed=7)
    hard._localise.clear_cache()
    batch._decode_jit.clear_cache()
    for b in (33, 40, 64):  # 2 chunks each: one bucket
        decode(params, jnp.asarray(_queries(b, 9, b)), groups, n)
        decode_queries(params, _queries(b, 9, b), groups, n, "soft")
    assert hard._localise._cache_size() == 1
    assert batch._decode_jit._cache_size() == 1
    with compiles() as seen:
        for b in (65, 100, 128):  # 3-4 chunks: the next bucket, one program
            decode(params, jnp.asarray(_queries(b, 9, b)), groups, n)
        first = len(seen)
    assert first >= 1 and hard._localise._cache_size() == 2


def test_the_program_holds_one_chunk_of_scores():
    """At the real chunk size: a 100,000-query batch (bucket 131,072 rows)
    compiles a loop whose scores are (CHUNK, p), never (rows, p)."""
    groups, n, p = Groups("periods", (5, 7)), 35, 12
    params = _templates(3, p, seed=8)
    rows, chunk = buckets.bucket(100_000), buckets.CHUNK
    q = jax.ShapeDtypeStruct((rows, 3), jnp.float32)
    text = hard._localise.lower(params, q, 13, groups, n, chunk).as_text()
    assert f"tensor<{chunk}x{p}xf32>" in text and "stablehlo.while" in text
    assert f"tensor<{rows}x{p}xf32>" not in text


def test_a_large_batch_equals_the_host_decode():
    """100,000 device queries (13 chunks of a bucket of 16) against the CPU's
    numpy-product path (one pass), and float64 numpy scores as the reference."""
    periods, n = (5, 7), 35
    params = _templates(3, 12, seed=9)
    q = _queries(100_000, 3, seed=10)
    got = decode(params, jnp.asarray(q), periods, n)
    want = decode_queries(params, q, periods, n)  # the host batch lane
    s = q.astype(np.float64) @ np.asarray(params.w, np.float64) + np.asarray(
        params.b, np.float64
    )
    phases = [s[:, :5].argmax(1), s[:, 5:].argmax(1)]
    place = (21 * phases[0] + 15 * phases[1]) % 35  # CRT for (5, 7)
    assert got.index.shape == (100_000,)
    np.testing.assert_array_equal(np.asarray(got.index), np.asarray(want.index))
    assert (np.asarray(got.index) == place).mean() > 0.9999  # float32 ties aside


def test_jitted_decode_of_a_chunked_batch_equals_predict(small_chunks):
    rng = np.random.default_rng(11)
    x = np.cumsum(rng.normal(size=(90, 12)), axis=0).astype(np.float32)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    model = rj.RhythmicMap(r=2, level=1).fit(x, progress=False)
    q = (x + rng.normal(scale=0.01, size=x.shape)).astype(np.float32)
    for method in ("hard", "soft", "topm"):
        got = jax.jit(queries.decode, static_argnames="method")(
            model.map, jnp.asarray(q), method=method
        )
        np.testing.assert_array_equal(np.asarray(got.index), model.predict(q, method))


@pytest.fixture(scope="module")
def hybrid():
    rng = np.random.default_rng(12)
    x = np.cumsum(rng.normal(size=(120, 16)), axis=0).astype(np.float32)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    model = rj.RhythmicMap(r=2, level=1, codes=16, method="soft").fit(x, progress=False)
    q = (x + rng.normal(scale=0.05, size=x.shape)).astype(np.float32)
    return model, q


@pytest.mark.parametrize("method", ["soft", "topm", "hard"])
def test_the_fused_decode_of_a_bucket_equals_the_unpadded_one(hybrid, method):
    model, q = hybrid
    m = model.map
    for b in (5, 16, 17, 100):
        x = q[:b]
        s = scores(m.params, jnp.asarray(x))
        sims = m.codebook.similarity(x)
        got = fusion.fused_decode(s, sims, m.periods, m.n, 0.4, method, 2)
        per, mm = m.periods, (1 if method == "hard" else 2)
        how = "topm" if method == "hard" else method
        want = fusion._fused_jit(
            s, jnp.asarray(sims), jnp.float32(0.4), per, m.n, how, mm, True, 0, 256
        )  # the program on the b rows themselves
        _same(got, want)
        through_map = queries.decode(m, x, method, 2)
        np.testing.assert_array_equal(
            np.asarray(through_map.index),
            np.asarray(
                fusion.fused_decode(
                    s, sims, per, m.n, m.config.fusion,
                    "soft" if method == "hard" else method, 2,
                ).index
            ),
        )  # fmt: skip


def test_the_fused_decode_compiles_once_per_bucket(hybrid):
    model, q = hybrid
    model.predict(q[:3])
    model.predict(q[:20], sequence=3)
    with compiles() as seen:
        for b in (5, 7, 11, 16):
            assert model.predict(q[:b]).shape == (b,)
        for b in (21, 30):
            assert model.predict(q[:b], sequence=3).shape == (b,)
    assert seen == []
