"""The numpy decode of a few queries equals the jitted batch decode."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from rhythmic_jax import RhythmicMap
from rhythmic_jax.decoding.hard import decode
from rhythmic_jax.decoding.small import SMALL_BATCH, SmallDecoder
from rhythmic_jax.objective import Templates
from rhythmic_jax.periods import candidate_periods, choose_periods


def _templates(d: int, periods, seed: int = 0) -> Templates:
    rng = np.random.default_rng(seed)
    p = sum(periods)
    w = rng.standard_normal((d, p), dtype=np.float32) / np.float32(np.sqrt(d))
    b = rng.standard_normal(p, dtype=np.float32) * np.float32(0.01)
    return Templates(jnp.asarray(w), jnp.asarray(b))


def _same(small, batch) -> None:
    np.testing.assert_array_equal(small.index, np.asarray(batch.index))
    found = small.index >= 0
    assert np.all(np.isneginf(small.score[~found]))
    np.testing.assert_allclose(small.score[found], np.asarray(batch.score)[found],
                               rtol=1e-4, atol=1e-5)  # fmt: skip
    np.testing.assert_allclose(small.confidence, np.asarray(batch.confidence),
                               rtol=1e-4, atol=1e-5)  # fmt: skip


@pytest.mark.parametrize("periods,n", [((100, 101), 10_000), ((7, 9, 11), 600),
                                       ((13,), 13), ((1, 5), 5)])  # fmt: skip
def test_random_queries_decode_as_the_batch(periods, n):
    params = _templates(64, periods)
    q = np.random.default_rng(1).standard_normal((500, 64), dtype=np.float32)
    small = SmallDecoder.build(params, periods, n)
    batch = decode(params, q, periods, n)
    _same(small(q), batch)
    assert [small.index(x) for x in q[:100]] == np.asarray(batch.index)[:100].tolist()
    if n < np.prod(periods):
        assert (small(q).index == -1).any()  # the no-match branch is exercised


def test_real_queries_decode_as_the_batch(nordland_patchnorm):
    summer, winter = nordland_patchnorm
    n = len(summer)
    cands = candidate_periods(n, 2, 1, 7)
    periods = choose_periods(cands, [0.0] * len(cands), n, 2)
    params = _templates(summer.shape[1], periods, seed=2)
    small = SmallDecoder.build(params, periods, n)
    _same(small(winter), decode(params, winter, periods, n))
    one = [small.index(x) for x in winter[:300]]
    assert one == small(winter[:300]).index.tolist()


def test_map_uses_it_for_few_queries():
    rng = np.random.default_rng(3)
    x = rng.standard_normal((60, 16), dtype=np.float32)
    model = RhythmicMap(r=2).fit(x, progress=False)
    q = x + 0.1 * rng.standard_normal(x.shape, dtype=np.float32)
    full = model.decode(q)  # a batch: the jitted decode
    for i in range(0, 60, 7):
        part = model.decode(q[i : i + SMALL_BATCH])
        assert isinstance(part.index, np.ndarray)  # the numpy path
        np.testing.assert_array_equal(
            part.index, np.asarray(full.index)[i : i + SMALL_BATCH]
        )
    assert model.predict(q[:1]).tolist() == [int(full.index[0])]
    for i in range(0, 60, 5):  # predict's own path: places only, in numpy
        few = model._few_places(q[i : i + 5], "hard")
        assert few.dtype == np.int64
        np.testing.assert_array_equal(few, np.asarray(full.index)[i : i + 5])
        np.testing.assert_array_equal(model.predict(q[i : i + 5]), few)
    assert model._few_places(q[:9], "hard") is None  # a batch: jitted
    assert model._few_places(q[:1], "soft") is None
    first = model._small_decoder()
    model.fit(x[::-1].copy(), progress=False)  # new templates: a new decoder
    assert model._small_decoder() is not first
