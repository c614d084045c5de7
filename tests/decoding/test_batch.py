"""Query batches padded to power-of-two buckets: same answers, one program."""

from __future__ import annotations

import contextlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rhythmic_jax as rj
from rhythmic_jax.decoding import batch, buckets, hard
from rhythmic_jax.decoding.batch import decode_queries, sequence_queries
from rhythmic_jax.decoding.dispatch import decode_scores
from rhythmic_jax.decoding.hard import Decoded, decode
from rhythmic_jax.decoding.sequence import sequence_decode
from rhythmic_jax.map.groups import Groups
from rhythmic_jax.solvers.objective import Templates, scores

_EVENT = "/jax/core/compile/backend_compile_duration"


@contextlib.contextmanager
def compiles():
    """A list that gets one entry per XLA program compiled in the block."""
    seen: list[float] = []

    def listen(event, secs, **_):
        if event == _EVENT:
            seen.append(secs)

    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        yield seen
    finally:
        jax._src.monitoring.unregister_event_duration_listener(listen)


def _templates(d: int, p: int, seed: int = 0) -> Templates:
    rng = np.random.default_rng(seed)
    return Templates(
        jnp.asarray(rng.normal(size=(d, p)), jnp.float32),
        jnp.asarray(rng.normal(size=p), jnp.float32),
    )


def test_buckets_are_powers_of_two_from_the_smallest():
    assert [buckets.bucket(b) for b in (0, 1, 3, 16, 17, 100_000)] == [
        16, 16, 16, 16, 32, 131_072,
    ]  # fmt: skip
    x = np.arange(10.0, dtype=np.float32).reshape(5, 2)
    padded, b = buckets.pad_rows(x)
    assert b == 5 and isinstance(padded, np.ndarray) and padded.shape == (16, 2)
    np.testing.assert_array_equal(padded[:5], x)
    assert not padded[5:].any()
    dev, _ = buckets.pad_rows(jnp.asarray(x))
    np.testing.assert_array_equal(np.asarray(dev), padded)


@pytest.mark.parametrize("method", ["hard", "soft", "topm"])
@pytest.mark.parametrize("b", [5, 16, 17])
def test_decode_queries_equals_the_unpadded_decode(method, b):
    periods, n = (5, 7), 33
    params = _templates(6, 12)
    q = np.random.default_rng(b).normal(size=(b, 6)).astype(np.float32)
    groups = Groups("periods", periods)
    got = decode_queries(params, q, groups, n, method, 2)
    want = decode_scores(scores(params, jnp.asarray(q)), groups, n, method, 2)
    for g, w in zip(got, want, strict=True):
        assert g.shape == (b,)
        np.testing.assert_allclose(np.asarray(g), np.asarray(w), rtol=1e-6)


def test_sequence_queries_equals_the_unpadded_sequence_decode():
    periods, n = (5, 7), 35
    params = _templates(4, 12, seed=3)
    q = np.random.default_rng(4).normal(size=(19, 4)).astype(np.float32)
    groups = Groups("periods", periods)
    for method in ("soft", "hard"):
        idx, conf = sequence_queries(params, q, groups, n, 4, (0.9, 1.0), method)
        want = sequence_decode(
            scores(params, jnp.asarray(q)), periods, n, 4, (0.9, 1.0), method
        )
        assert idx.shape == (19,)
        np.testing.assert_array_equal(np.asarray(idx), np.asarray(want[0]))
        # Confidences in [0, 1] are ratios of float32 sums taken in another order
        # by the two programs (a GPU measured 8 ulps of 1.0): 16 ulps absolute.
        atol = 16 * np.finfo(np.float32).eps
        np.testing.assert_allclose(conf, want[1], rtol=1e-6, atol=atol)


def test_batches_of_3_5_7_compile_one_program():
    periods, n = (7, 9), 60  # shapes no other test uses: nothing cached
    params = _templates(11, 16, seed=5)
    groups = Groups("periods", periods)
    rng = np.random.default_rng(6)
    batch._decode_jit.clear_cache()
    with compiles() as seen:
        decode_queries(params, rng.normal(size=(3, 11)), groups, n, "soft")
        first = len(seen)
        for b in (5, 7):
            out = decode_queries(params, rng.normal(size=(b, 11)), groups, n, "soft")
            assert out.index.shape == (b,)
            out.confidence  # noqa: B018 (computed on the host: no program)
        assert len(seen) == first
    assert batch._decode_jit._cache_size() == 1
    decode_queries(params, rng.normal(size=(17, 11)), groups, n, "soft")
    assert batch._decode_jit._cache_size() == 2  # the next bucket: a program


def test_jitted_hard_decode_pads_device_batches():
    periods, n = (5, 7), 35
    params = _templates(8, 12, seed=7)
    rng = np.random.default_rng(8)
    hard._localise.clear_cache()
    for b in (3, 5, 7):
        q = rng.normal(size=(b, 8)).astype(np.float32)
        got = decode(params, jnp.asarray(q), periods, n)  # device: the jitted path
        want = decode_queries(params, q, periods, n)  # numpy on the CPU: host
        np.testing.assert_array_equal(np.asarray(got.index), np.asarray(want.index))
        assert isinstance(want.index, np.ndarray)
        f64 = decode_queries(params, q.astype(np.float64), periods, n)  # the kernel
        np.testing.assert_array_equal(np.asarray(f64.index), np.asarray(want.index))
        assert got.index.shape == (b,)
    assert hard._localise._cache_size() == 1


def test_confidence_on_the_host_equals_the_device_formula():
    out = Decoded(
        jnp.asarray([3, -1, 0], jnp.int32),
        jnp.asarray([2.0, -np.inf, 1.0], jnp.float32),
        jnp.asarray([1.5, -np.inf, -np.inf], jnp.float32),
    )
    traced = jax.jit(lambda d: d.confidence)(out)
    np.testing.assert_array_equal(np.asarray(out.confidence), np.asarray(traced))
    assert out.confidence.dtype == jnp.float32
    # no match and no rival: 0, finite both
    np.testing.assert_array_equal(np.asarray(out.confidence), [0.5, 0.0, 0.0])


def test_predict_with_new_batch_sizes_compiles_nothing_within_a_bucket():
    rng = np.random.default_rng(9)
    x = np.cumsum(rng.normal(size=(90, 12)), axis=0).astype(np.float32)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    m = rj.RhythmicMap(r=2, level=1).fit(x)
    m.predict(x[:3] + 0.01, "soft")
    m.predict(x[:20], "soft", sequence=3)
    with compiles() as seen:
        for b in (5, 7, 11):
            assert m.predict(x[:b] + 0.01, "soft").shape == (b,)
        for b in (21, 30):
            assert m.predict(x[:b], "soft", sequence=3).shape == (b,)
    assert seen == []
