"""The library's faces under a trace: ``rj.predict`` (host output) refuses
``jax.jit`` and ``jax.vmap`` in one line naming ``rj.decode``; under
``jax.jit(rj.decode)`` a query of the wrong width, rank, emptiness or dtype is
refused at trace time in the eager words, and a query holding a NaN or inf
decodes to no match (-1) inside the program, its confidence 0. A hypothesis
family draws shapes, dtypes and non-finite entries under ``jit`` and ``vmap``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import rhythmic_jax as rj
from rhythmic_jax.errors import InputError

N, D = 60, 16


@pytest.fixture(scope="module")
def route():
    rng = np.random.default_rng(11)
    x = rng.normal(size=(N, D)).astype(np.float32)
    q = (x + 0.1 * rng.normal(size=x.shape)).astype(np.float32)
    return x, q


@pytest.fixture(scope="module")
def maps(route):
    x, _ = route
    return {
        "plain": rj.fit(x),
        "codes": rj.fit(x, rj.MapConfig(codes="int8")),
        "mixed": rj.fit(x, rj.MapConfig(layout="mixed")),
    }


def _message(fn, *args) -> str:
    with pytest.raises(InputError) as err:
        fn(*args)
    return str(err.value)


def test_predict_under_jit_and_vmap_names_decode(route, maps):
    _, q = route
    m = maps["plain"]
    for traced in (
        lambda: jax.jit(rj.predict)(m, q[:3]),
        lambda: jax.vmap(rj.predict, in_axes=(None, 0))(m, q[:6].reshape(2, 3, D)),
        lambda: jax.jit(lambda y: rj.predict(m, y))(q[:3]),
    ):
        msg = _message(traced)
        assert "\n" not in msg and "rhythmic_jax.decode" in msg and "trace" in msg


def test_the_estimator_faces_under_jit(route):
    x, q = route
    est = rj.RhythmicMap().fit(x, progress=False)
    msg = _message(jax.jit(est.predict), q[:3])
    assert "rhythmic_jax.decode" in msg
    got = jax.jit(lambda y: est.decode(y).index)(q[:5])
    np.testing.assert_array_equal(np.asarray(got), np.asarray(est.decode(q[:5]).index))


BAD = {
    "wide": np.zeros((3, D + 1), np.float32),
    "narrow": np.zeros((3, D - 1), np.float32),
    "rank 1": np.zeros((D,), np.float32),
    "rank 3": np.zeros((2, 3, D), np.float32),
    "empty": np.zeros((0, D), np.float32),
    "boolean": np.ones((3, D), bool),
    "complex": np.ones((3, D), np.complex64),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_a_bad_query_is_refused_at_trace_time_in_the_eager_words(maps, case):
    q = BAD[case]
    m = maps["plain"]
    eager = _message(rj.decode, m, q)
    traced = _message(jax.jit(rj.decode), m, q)
    assert traced == eager and "\n" not in traced
    # a map traced beside the queries as well as one closed over
    assert _message(jax.jit(lambda y: rj.decode(m, y)), q) == eager


@pytest.mark.parametrize("kind", ["plain", "codes", "mixed"])
@pytest.mark.parametrize("method", ["hard", "soft", "topm"])
def test_non_finite_queries_decode_to_no_match_in_the_program(
    route, maps, kind, method
):
    _, q = route
    m = maps[kind]
    bad = q[:6].copy()
    bad[1, 3], bad[3, 0], bad[4, :] = np.nan, np.inf, -np.inf
    out = jax.jit(lambda mm, y: rj.decode(mm, y, method))(m, bad)
    idx, conf = np.asarray(out.index), np.asarray(out.confidence)
    want = np.asarray(rj.decode(m, q[:6], method).index)  # the finite rows, eagerly
    np.testing.assert_array_equal(idx[[1, 3, 4]], -1)
    np.testing.assert_array_equal(idx[[0, 2, 5]], want[[0, 2, 5]])
    assert np.isfinite(conf).all() and (conf[[1, 3, 4]] == 0).all()
    # eagerly the same queries are refused in one line, never answered
    assert "NaN or inf" in _message(rj.decode, m, bad)


def test_a_sequence_with_a_nan_frame_is_no_match_while_it_is_in_the_window(route, maps):
    _, q = route
    m = maps["plain"]
    frames = q[:20].copy()
    frames[8, 2] = np.nan
    idx, conf = jax.jit(lambda y: rj.decode_sequence(m, y, 3))(frames)
    idx, conf = np.asarray(idx), np.asarray(conf)
    want = np.asarray(rj.decode_sequence(m, q[:20], 3)[0])
    np.testing.assert_array_equal(idx[8:11], -1)  # frames 8, 9, 10 see frame 8
    keep = np.r_[0:8, 11:20]
    np.testing.assert_array_equal(idx[keep], want[keep])
    assert np.isfinite(conf).all() and (conf[8:11] == 0).all()


@pytest.mark.filterwarnings("ignore:invalid value:RuntimeWarning")
def test_the_kernels_answer_non_finite_scores_with_no_match():
    """The decodes of scores, eagerly: a row with a NaN or inf is no match in
    every kernel (hard, its numpy lane, soft, top-m), never place 0."""
    from rhythmic_jax.decoding.dispatch import decode_scores
    from rhythmic_jax.decoding.host import host_decode
    from rhythmic_jax.map.groups import Groups

    periods = (5, 7)
    s = np.random.default_rng(0).normal(size=(4, 12)).astype(np.float32)
    s[1, 2], s[2, 9], s[3, :] = np.nan, np.inf, -np.inf
    for method in ("hard", "soft", "topm"):
        idx = np.asarray(decode_scores(s, periods, 35, method).index)
        assert idx[0] >= 0 and (idx[1:] == -1).all(), method
    host = host_decode(s.copy(), Groups("periods", periods), 35)
    np.testing.assert_array_equal(host.index[1:], -1)


# ----------------------------------------------------- hypothesis: the family
DTYPES = st.sampled_from(["float32", "float64", "float16", "int32", "bool"])


@settings(max_examples=25, deadline=None, database=None)
@given(
    rows=st.integers(0, 5),
    width=st.sampled_from([D - 1, D, D + 3]),
    rank=st.sampled_from([1, 2, 3]),
    dtype=DTYPES,
    poison=st.lists(st.sampled_from([np.nan, np.inf, -np.inf]), max_size=3),
    via_vmap=st.booleans(),
)
def test_traced_decode_fuzz(route, maps, rows, width, rank, dtype, poison, via_vmap):
    """Whatever the shape, dtype or values: under jit (or vmap over a leading
    axis) ``rj.decode`` answers exactly as eagerly on finite queries of a good
    shape, refuses a bad one in the eager line at trace time, and answers a
    non-finite row with no match."""
    _, q = route
    m = maps["plain"]
    shape = {1: (width,), 2: (rows, width), 3: (2, rows, width)}[rank]
    x = np.resize(q.ravel()[: max(np.prod(shape), 1)], shape).astype(np.float32)
    rng = np.random.default_rng(rows * 7 + width)
    bad_rows = set()
    if poison and x.ndim == 2 and rows > 0 and dtype.startswith("float"):
        for v in poison:
            r = int(rng.integers(rows))
            x[r, int(rng.integers(width))] = v
            bad_rows.add(r)
    x = x.astype(dtype) if dtype != "bool" else x > 0
    if via_vmap:  # vmap over a leading axis of two copies
        x = np.stack([x, x])
        fn = jax.vmap(lambda y: rj.decode(m, y).index)
    else:
        fn = jax.jit(lambda y: rj.decode(m, y).index)
    one = x[0] if via_vmap else x
    try:
        eager = np.asarray(
            rj.decode(
                m, np.where(np.isfinite(one), one, 0) if one.dtype.kind == "f" else one
            ).index
        )
    except InputError as err:
        with pytest.raises(InputError) as got:
            fn(jnp.asarray(x))
        assert str(got.value) == str(err)
        return
    got = np.asarray(fn(jnp.asarray(x)))
    got = got[0] if via_vmap else got
    for r in range(len(got)):
        if r in bad_rows:
            assert got[r] == -1
        else:
            assert got[r] == eager[r]
