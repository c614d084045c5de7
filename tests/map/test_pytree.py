"""The fitted map as a JAX value: leaves, jit, vmap, save and load, the one kernel."""

from __future__ import annotations

import functools
import math
from dataclasses import replace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from rhythmic_jax import RhythmicMap
from rhythmic_jax.decoding import hard, host, queries
from rhythmic_jax.decoding.hard import hard_decode
from rhythmic_jax.fitting.fit_map import fit
from rhythmic_jax.map import map_file
from rhythmic_jax.map.config import MapConfig
from rhythmic_jax.map.groups import Groups
from rhythmic_jax.map.pytree import Map


def _frames(seed: int, n: int = 80, d: int = 64) -> np.ndarray:
    x = np.random.default_rng(seed).normal(size=(n, d))
    return (x / np.linalg.norm(x, axis=1, keepdims=True)).astype(np.float32)


@pytest.fixture(scope="module")
def maps():
    """Two maps of one layout (the same configuration, different frames)."""
    cfg = MapConfig(layout="periods:9,11")
    xs = [_frames(0), _frames(1)]
    return [fit(x, cfg) for x in xs], xs


def _queries(x: np.ndarray, seed: int = 5) -> np.ndarray:
    noise = np.random.default_rng(seed).normal(scale=0.02, size=x.shape)
    return (x + noise).astype(np.float32)


def test_the_leaves_are_arrays_and_the_rest_is_static(maps):
    (m, _), _ = maps
    leaves = jax.tree_util.tree_leaves(m)
    assert leaves and all(isinstance(v, np.ndarray | jax.Array) for v in leaves)
    assert any(v is m.w for v in leaves) and any(v is m.b for v in leaves)
    _, treedef = jax.tree_util.tree_flatten(m)
    hash(treedef)  # the static fields key a jit cache
    assert m.w.shape == (64, sum(m.periods)) and m.w.dtype == jnp.float32


def test_jitted_decode_of_the_map_equals_predict(maps):
    (m, _), (x, _) = maps
    q = _queries(x)
    model = RhythmicMap()
    model.map = m
    decode = jax.jit(queries.decode, static_argnames="method")
    for method in ("hard", "soft", "topm"):
        got = decode(m, jnp.asarray(q), method=method)
        np.testing.assert_array_equal(np.asarray(got.index), model.predict(q, method))
    assert (model.predict(x) == np.arange(80)).mean() > 0.9  # a real answer


def test_jit_takes_new_template_values_without_compiling(maps):
    (m, _), (x, _) = maps
    q = jnp.asarray(_queries(x))
    decode = jax.jit(queries.decode)
    first = decode(m, q)
    programs = decode._cache_size()
    flipped = replace(m, w=-m.w, b=-m.b)  # other values, one layout
    second = decode(flipped, q)
    assert decode._cache_size() == programs
    want = queries.decode(flipped, np.asarray(q))
    np.testing.assert_array_equal(np.asarray(second.index), np.asarray(want.index))
    assert not np.array_equal(np.asarray(first.index), np.asarray(second.index))


def test_a_new_threshold_method_or_fusion_weight_compiles_nothing(maps):
    """The decode settings a map stores are leaves, not the compiled key: a map
    with another threshold, method or fusion weight reuses the program, and its
    stored method still decides its answer; an explicit method overrides it."""
    (m, _), (x, _) = maps
    q = jnp.asarray(_queries(x))
    decode = jax.jit(queries.decode)
    decode(m, q)
    programs = decode._cache_size()
    named = jax.jit(queries.decode, static_argnames="method")
    named(m, q, method="hard")
    named_programs = named._cache_size()
    for change in (dict(threshold=0.25), dict(fusion=0.8), dict(decode="soft"),
                   dict(decode="topm", threshold=-1.0)):  # fmt: skip
        other = replace(m, config=replace(m.config, **change))
        got = decode(other, q)
        want = queries.decode(other, np.asarray(q))
        np.testing.assert_array_equal(np.asarray(got.index), want.index)
        np.testing.assert_allclose(np.asarray(got.score), want.score, rtol=1e-5)
        hard = named(other, q, method="hard")
        np.testing.assert_array_equal(np.asarray(hard.index), np.asarray(named(
            m, q, method="hard").index))  # fmt: skip
    assert decode._cache_size() == programs
    assert named._cache_size() == named_programs
    leaves = jax.tree_util.tree_leaves(replace(m, config=other.config))
    assert len(leaves) == len(jax.tree_util.tree_leaves(m))  # settings: leaves
    moved = jax.device_put(other)  # the settings read back as Python values
    assert moved.config == other.config and moved.config.decode == "topm"
    assert replace(m, config=replace(m.config, top=5)).config != m.config


def test_decode_compiles_once_per_bucket(maps):
    """Device batches: one program per bucket of rows; a float32 numpy batch on
    the CPU is answered by the numpy lane and compiles nothing."""
    (m, _), (x, _) = maps
    hard._localise.clear_cache()
    for b in (3, 5, 7, 16):  # one bucket of rows
        out = hard.decode(m.params, jnp.asarray(x[:b]), m.groups, m.n)
        assert out.index.shape == (b,)
    assert hard._localise._cache_size() == 1
    hard.decode(m.params, jnp.asarray(x[:17]), m.groups, m.n)
    assert hard._localise._cache_size() == 2
    hard.hard_kernel.clear_cache()
    for b in (3, 17, 40):
        want = hard.decode(m.params, jnp.asarray(x[:b]), m.groups, m.n).index
        got = queries.decode(m, x[:b])
        np.testing.assert_array_equal(got.index, np.asarray(want))
    assert hard.hard_kernel._cache_size() == 0 and hard._localise._cache_size() == 3


def test_vmap_over_two_maps_of_one_layout_equals_two_decodes(maps):
    (m1, m2), (x1, x2) = maps
    assert m1.periods == m2.periods == (9, 11)
    q = jnp.asarray(_queries(np.concatenate([x1[:20], x2[:20]])))
    stacked = jax.tree.map(lambda *a: jnp.stack(a), m1, m2)
    out = jax.vmap(functools.partial(queries.decode, q=q, method="hard"))(stacked)
    for i, m in enumerate((m1, m2)):
        want = queries.decode(m, np.asarray(q))
        np.testing.assert_array_equal(np.asarray(out.index[i]), want.index)
        for got, ref in zip(out[1:], want[1:], strict=True):  # two products' rounding
            np.testing.assert_allclose(np.asarray(got[i]), ref, rtol=1e-5, atol=1e-6)


def test_a_saved_map_loads_equal(maps, tmp_path):
    (m, _), _ = maps
    map_file.save(tmp_path / "m.map", m)
    got = map_file.load(tmp_path / "m.map")
    assert isinstance(got, Map)
    assert jax.tree.structure(got) == jax.tree.structure(m)  # static fields equal
    for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(m), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert map_file.describe(got) == map_file.describe(m)


def test_maps_written_by_the_estimator_load_as_values(tmp_path):
    x = _frames(2, n=60)
    model = RhythmicMap(r=2, level=1, dtype="int8").fit(x)
    model.reference = {"sources": ["a.npy"]}
    model.save(tmp_path / "m.map")
    got = map_file.load(tmp_path / "m.map")
    assert got.where_from() == {"sources": ["a.npy"]}
    assert got.stored["w"].dtype == np.int8 and got.w.dtype == jnp.float32
    np.testing.assert_array_equal(queries.predict(got, x), model.predict(x))


def _brute_force(s: np.ndarray, groups: Groups, n: int) -> np.ndarray:
    """Every place below the layout's capacity tried: the one whose label in
    every group is that group's argmax (-1 when it is >= n)."""
    labels = groups.columns(groups.capacity) - np.asarray(groups.offsets)[:, None]
    out = []
    for row in s:
        best = [int(np.argmax(row[o : o + t])) for o, t in zip(groups.offsets, groups.sizes, strict=True)]  # fmt: skip  # noqa: E501
        hits = [i for i in range(groups.capacity)
                if all(labels[k, i] == j for k, j in enumerate(best))]  # fmt: skip
        assert len(hits) == 1
        out.append(hits[0] if hits[0] < n else -1)
    return np.array(out)


@pytest.mark.parametrize(
    "groups,n",
    [
        (Groups("periods", (5, 7)), 35),
        (Groups("periods", (4, 5, 7)), 101),
        (Groups("mixed", (4, 6)), 24),
        (Groups("mixed", (3, 4, 5)), 47),
    ],
)
def test_the_kernel_equals_a_brute_force_loop_over_every_place(groups, n):
    s = np.random.default_rng(7).normal(size=(300, groups.p)).astype(np.float32)
    got = hard_decode(s, groups, n)
    np.testing.assert_array_equal(np.asarray(got.index), _brute_force(s, groups, n))
    blocks = [s[:, o : o + t] for o, t in zip(groups.offsets, groups.sizes, strict=True)]  # fmt: skip  # noqa: E501
    found = np.asarray(got.index) >= 0
    total = sum(b.max(axis=1) for b in blocks)
    np.testing.assert_allclose(np.asarray(got.score)[found], total[found], rtol=1e-6)
    gap = np.min([np.diff(np.sort(b, axis=1)[:, -2:], axis=1)[:, 0] for b in blocks], 0)
    np.testing.assert_allclose(np.asarray(got.confidence)[found], gap[found], atol=1e-6)
    assert math.prod(groups.sizes) == groups.capacity


def test_the_numpy_lane_equals_the_kernel(maps):
    (m, _), (x, _) = maps
    q = _queries(x, seed=9)
    lane = host.lane(m)
    want = np.asarray(hard.decode(m.params, q, m.groups, m.n).index).tolist()
    assert [lane.place(row) for row in q] == want
    assert [queries.locate(m, row) for row in q] == want
