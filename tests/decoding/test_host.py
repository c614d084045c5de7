"""The host lanes (one query's place, a host batch's decode) equal the hard-decode
kernel's."""

from __future__ import annotations

import gc
import weakref
from dataclasses import replace

import jax.numpy as jnp
import numpy as np
import pytest

from rhythmic_jax import RhythmicMap
from rhythmic_jax.decoding import host, queries
from rhythmic_jax.decoding.batch import decode_queries
from rhythmic_jax.decoding.hard import decode, hard_decode
from rhythmic_jax.decoding.host import (
    GEMV_THREADED,
    SMALL_BATCH,
    SmallDecoder,
    block_rows,
    gemv_rows,
    host_decode,
    lane,
)
from rhythmic_jax.errors import InputError
from rhythmic_jax.map.groups import Groups
from rhythmic_jax.map.periods import candidate_periods, choose_periods
from rhythmic_jax.map.pytree import Map, Templates


def _templates(d: int, periods, seed: int = 0) -> Templates:
    rng = np.random.default_rng(seed)
    p = sum(periods)
    w = rng.standard_normal((d, p), dtype=np.float32) / np.float32(np.sqrt(d))
    b = rng.standard_normal(p, dtype=np.float32) * np.float32(0.01)
    return Templates(jnp.asarray(w), jnp.asarray(b))


@pytest.mark.parametrize("periods,n", [((100, 101), 10_000), ((7, 9, 11), 600),
                                       ((13,), 13), ((1, 5), 5)])  # fmt: skip
def test_random_queries_decode_as_the_batch(periods, n):
    params = _templates(64, periods)
    q = np.random.default_rng(1).standard_normal((500, 64), dtype=np.float32)
    small = SmallDecoder.build(params, periods, n)
    want = np.asarray(decode(params, jnp.asarray(q), periods, n).index).tolist()
    assert [small.place(x) for x in q] == want
    if n < np.prod(periods):
        assert -1 in want  # the no-match branch is exercised


def test_real_queries_decode_as_the_batch(nordland_patchnorm):
    summer, winter = nordland_patchnorm
    n = len(summer)
    cands = candidate_periods(n, 2, 1, 7)
    periods = choose_periods(cands, [0.0] * len(cands), n, 2)
    params = _templates(summer.shape[1], periods, seed=2)
    small = SmallDecoder.build(params, periods, n)
    want = np.asarray(decode(params, jnp.asarray(winter), periods, n).index).tolist()
    assert [small.place(x) for x in winter] == want


@pytest.mark.parametrize(
    "groups,n",
    [
        (Groups("periods", (100, 101)), 10_000),
        (Groups("periods", (7, 9, 11)), 600),
        (Groups("periods", (1, 5)), 5),
        (Groups("mixed", (7, 8, 4)), 200),
    ],
)
def test_a_host_batch_decodes_as_the_kernel(groups, n):
    """host_decode of scores equals the kernel's Decoded field by field, with
    ties (rounded scores: the first maximal phase wins, the margin is 0) and
    the no-match branch."""
    rng = np.random.default_rng(4)
    s = np.round(rng.standard_normal((300, groups.p)), 1).astype(np.float32)
    want = hard_decode(jnp.asarray(s), groups, n)
    got = host_decode(s.copy(), groups, n)
    for g, w in zip(got, want, strict=True):
        assert isinstance(g, np.ndarray) and g.dtype == np.asarray(w).dtype
        np.testing.assert_array_equal(g, np.asarray(w))
    if n < groups.capacity:
        assert (got.index == -1).any()
    assert (got.confidence == 0).any()  # ties were exercised


def test_a_float32_host_batch_on_the_cpu_takes_the_lane():
    """decode of a float32 numpy batch equals the kernel's on the same queries
    uploaded (one program per bucket there)."""
    periods, n = (45, 46), 2000
    params = _templates(32, periods, seed=5)
    q = np.random.default_rng(6).standard_normal((1000, 32), dtype=np.float32)
    got = decode_queries(params, q, periods, n)
    want = decode(params, jnp.asarray(q), periods, n)
    assert isinstance(got.index, np.ndarray)
    np.testing.assert_array_equal(got.index, np.asarray(want.index))
    np.testing.assert_allclose(got.score, np.asarray(want.score), rtol=1e-5)
    np.testing.assert_allclose(
        got.confidence, np.asarray(want.confidence), rtol=1e-4, atol=1e-5
    )


def test_predict_answers_few_queries_in_numpy():
    rng = np.random.default_rng(3)
    x = rng.standard_normal((60, 16), dtype=np.float32)
    model = RhythmicMap(r=2).fit(x, progress=False)
    q = x + 0.1 * rng.standard_normal(x.shape, dtype=np.float32)
    full = np.asarray(model.decode(q).index)  # a batch: the kernel
    assert queries.way(model.map, "hard") is queries._small
    small = lane(model.map)
    for i in range(0, 60, 5):  # predict's own path: places only, in numpy
        few = small.places(q[i : i + 5])
        assert few.dtype == np.int64
        np.testing.assert_array_equal(few, full[i : i + 5])
        np.testing.assert_array_equal(model.predict(q[i : i + 5]), few)
    assert small.places(q[: SMALL_BATCH + 1]) is None  # a batch
    assert queries.way(model.map, "soft") is queries._one_by_one
    assert queries.way(model.map, "hard", 0.5) is queries._one_by_one
    assert queries.way(model.map, "hard", None, 2) is queries._in_sequence
    assert lane(model.map) is small  # built once per map
    model.fit(x[::-1].copy(), progress=False)  # new templates: a new lane
    assert lane(model.map) is not small
    assert not hasattr(model.map, "__dict__") or not {
        k for k in vars(model.map) if k.startswith("_")
    }  # nothing written onto the frozen value


def test_rows_are_padded_onto_the_blas_thread_pool_only_where_it_pays():
    assert gemv_rows(201, 2048, cores=2) * 2048 >= GEMV_THREADED
    assert gemv_rows(201, 2048, cores=2) - 1 < GEMV_THREADED / 2048  # the fewest
    assert gemv_rows(201, 2048, cores=1) == 201  # one core: nothing to share
    assert gemv_rows(100, 2048, cores=2) == 100  # too small: padding would double
    assert gemv_rows(300, 2048, cores=2) == 300  # already threaded
    periods, n = (100, 101), 10_000
    params = _templates(2048, periods, seed=4)
    small = SmallDecoder.build(params, periods, n)
    assert small.block == block_rows(periods, 2048) == 113  # 2 x 113 >= 225 rows
    assert small.wt.shape[0] == 2 * small.block >= gemv_rows(201, 2048)
    spare = np.r_[100:113, 214:226]  # below each period's templates
    assert not small.wt[spare].any() and np.isneginf(small.b[spare]).all()
    np.testing.assert_array_equal(small.wt[113:214], np.asarray(params.w)[:, 100:].T)
    q = np.random.default_rng(5).standard_normal((200, 2048), dtype=np.float32)
    want = np.asarray(decode(params, jnp.asarray(q), periods, n).index).tolist()
    assert [small.place(x) for x in q] == want


def test_blocks_only_for_near_equal_periods():
    assert block_rows((7, 9, 11), 32, cores=2) == 11  # 33 rows for 27 templates
    assert block_rows((2, 11), 32, cores=2) is None  # 22 rows for 13: one run
    assert block_rows((100, 101), 2048, cores=1) == 101  # nothing to share
    periods, n = (2, 11), 22
    params = _templates(32, periods, seed=8)
    small = SmallDecoder.build(params, periods, n)
    assert small.block is None and small.wt.shape[0] == 13
    q = np.random.default_rng(9).standard_normal((100, 32), dtype=np.float32)
    want = np.asarray(decode(params, jnp.asarray(q), periods, n).index).tolist()
    assert [small.place(x) for x in q] == want


@pytest.mark.parametrize(
    "periods,n", [((100, 101), 10_000), ((7, 9, 11), 600), ((2, 11), 22)]
)
def test_place_rejects_non_finite_queries(periods, n):
    params = _templates(32, periods)
    small = SmallDecoder.build(params, periods, n)
    q = np.random.default_rng(6).standard_normal(32, dtype=np.float32)
    assert small.place(q) == int(decode(params, q[None], periods, n).index[0])
    for bad in (np.nan, np.inf, -np.inf):
        x = q.copy()
        x[7] = bad
        assert small.place(x) is None


def test_locate_is_predict_of_one_row():
    periods, n = (7, 9), 60
    model = RhythmicMap(r=2)  # as fit leaves it, without a fit's compiles
    params = _templates(16, periods)
    groups = Groups("periods", periods)
    model.map = Map(*params, stored=dict(params._asdict()), config=model.config,
                    groups=groups, periods=periods, n=n, d=16)  # fmt: skip
    q = np.random.default_rng(7).standard_normal((60, 16), dtype=np.float32)
    want = model.predict(q).tolist()
    assert [model.locate(row) for row in q] == want  # first call builds the lane
    assert lane(model.map) is lane(model.map)  # kept beside the map
    assert [model.locate(row) for row in q] == want
    assert model.locate(q[3].astype(np.float64)) == want[3]  # converted
    assert model.locate(q[3].tolist()) == want[3]
    bad = q[3].copy()
    bad[0] = np.nan
    with pytest.raises(InputError, match="NaN or inf"):
        model.locate(bad)
    with pytest.raises(InputError, match="one descriptor"):
        model.locate(q[:2])
    with pytest.raises(InputError, match="16-d"):
        model.locate(q[3, :8])
    model.config = replace(model.config, threshold=1e9)
    assert model.locate(q[0]) == -1  # the config's threshold holds


def test_the_lane_is_kept_beside_the_map_until_it_is_collected():
    """The lane is keyed by the map value from outside it: it does not keep
    the map alive, and goes with it."""
    periods, n = (7, 9), 60
    params = _templates(16, periods)
    m = Map(*params, stored=dict(params._asdict()), groups=Groups("periods", periods),
            periods=periods, n=n, d=16)  # fmt: skip
    small, key = lane(m), id(m)
    assert host._LANES[key] is small and not vars(m).keys() - {
        f for f in Map.__dataclass_fields__
    }
    alive = weakref.ref(m)
    del m
    gc.collect()
    assert alive() is None and key not in host._LANES
