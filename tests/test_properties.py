"""Properties over many drawn inputs: number theory, decoding, loaders, round trips.

Each property is checked against a brute-force reference (integer loops) or an
invariant (a map that is saved and loaded predicts as before). Example counts are
small so that the module stays fast.
"""

from __future__ import annotations

import json
import math
import shutil
import tempfile
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rhythmic_jax import RhythmicMap
from rhythmic_jax.decoding.hard import hard_decode
from rhythmic_jax.errors import InputError
from rhythmic_jax.io.checkpoint import load_map
from rhythmic_jax.io.descriptor_files import load_descriptors
from rhythmic_jax.io.images import read_rgb
from rhythmic_jax.map.periods import (
    candidate_periods,
    crt_tables,
    pairwise_coprime,
    period_offsets,
)
from rhythmic_jax.solvers.resumable import memmap_batches

FAST = settings(max_examples=40, deadline=None, database=None)
SLOW = settings(
    max_examples=4,
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.too_slow],
)


@st.composite
def coprime_periods(draw, most: int = 4, largest: int = 60, limit: int = 2**30):
    """Pairwise co-prime periods (>= 1) with a product below ``limit``."""
    raw = draw(st.lists(st.integers(1, largest), min_size=1, max_size=most))
    kept: list[int] = []
    for t in raw:
        if all(math.gcd(t, u) == 1 for u in kept) and math.prod(kept) * t < limit:
            kept.append(t)
    return tuple(kept)


# -------------------------------------------------------------- number theory


@FAST
@given(st.data())
def test_crt_tables_reconstruct_every_index(data):
    periods = data.draw(coprime_periods())
    tables, m = crt_tables(periods)
    assert m == math.prod(periods)
    idx = data.draw(st.lists(st.integers(0, m - 1), min_size=1, max_size=20))
    for i in idx:
        total = 0
        for t, table in zip(periods, tables, strict=True):
            assert table.shape == (t,) and 0 <= table.min() and table.max() < m
            total = (total + int(table[i % t])) % m
        assert total == i


@FAST
@given(st.integers(1, 30), st.integers(1, 30), st.integers(2, 12))
def test_crt_tables_refuse_periods_sharing_a_factor(t, u, k):
    with pytest.raises(InputError, match="not pairwise co-prime"):
        crt_tables((t * k, u * k))


@FAST
@given(
    st.integers(2, 10**7),
    st.integers(2, 4),
    st.integers(1, 3),
    st.integers(0, 6),
)
def test_candidates_start_at_the_integer_root_and_cover_n(n, r, level, extra):
    cands = candidate_periods(n, r, level, r + extra)
    base = cands[0] // level
    assert cands[0] == level * base
    assert base**r >= n and (base - 1) ** r < n  # the exact integer r-th root
    assert cands == tuple(range(cands[0], cands[0] + r + extra))
    assert math.prod(cands[-r:]) >= n  # the top r candidates always cover n


# ---------------------------------------------------------------------- decoding


def _one_hot_scores(index: np.ndarray, periods, shift: np.ndarray) -> np.ndarray:
    """Scores (b, p): 1 at phase ``index mod tau`` of every period, plus a row shift."""
    out = np.zeros((len(index), sum(periods)), np.float32)
    for off, t in zip(period_offsets(periods), periods, strict=True):
        out[np.arange(len(index)), off + index % t] = 1.0
    return out + shift[:, None]


# one program an example, where the eager decode compiled each of its ops for every
# new shape
_hard_decode = jax.jit(hard_decode, static_argnums=(1, 2))


@settings(max_examples=20, deadline=None, database=None)
@given(st.data())
def test_hard_decode_of_one_hot_phases(data):
    periods = data.draw(coprime_periods(most=3, largest=15, limit=5_000))
    m = math.prod(periods)
    n = data.draw(st.integers(1, m))
    b = data.draw(st.integers(1, 6))
    index = np.asarray(
        data.draw(st.lists(st.integers(0, m - 1), min_size=b, max_size=b))
    )
    shift = np.asarray(data.draw(st.lists(st.floats(-5, 5), min_size=b, max_size=b)))
    scores = jnp.asarray(_one_hot_scores(index, periods, shift.astype(np.float32)))
    got = np.asarray(_hard_decode(scores, periods, n).index)
    want = np.where(index < n, index, -1)  # brute force: the index itself or none
    np.testing.assert_array_equal(got, want)
    assert pairwise_coprime(periods)


# ----------------------------------------------------------------------- loaders


def _png_bytes() -> bytes:
    from skimage.io import imsave

    pixels = np.random.default_rng(0).integers(0, 256, (6, 5, 3), dtype=np.uint8)
    with tempfile.TemporaryDirectory() as tmp:
        imsave(Path(tmp) / "f.png", pixels, check_contrast=False)
        return (Path(tmp) / "f.png").read_bytes()


def _npy_bytes() -> bytes:
    from io import BytesIO

    buf = BytesIO()
    np.save(buf, np.arange(12, dtype=np.float32).reshape(3, 4))
    return buf.getvalue()


PNG, NPY = _png_bytes(), _npy_bytes()
ROUTE = (36, 7)  # frames x features of every fitted map: one solver compilation


def damaged(valid: bytes) -> st.SearchStrategy[bytes]:
    """Random bytes, the file cut short, its head kept with a random tail, or one
    byte flipped."""
    return st.one_of(
        st.binary(max_size=300),
        st.integers(0, len(valid) - 1).map(lambda k: valid[:k]),
        st.tuples(st.integers(0, len(valid)), st.binary(max_size=200)).map(
            lambda kt: valid[: kt[0]] + kt[1]
        ),
        st.tuples(st.integers(0, len(valid) - 1), st.integers(1, 255)).map(
            lambda kv: (
                valid[: kv[0]] + bytes([valid[kv[0]] ^ kv[1]]) + valid[kv[0] + 1 :]
            )
        ),
    )


@FAST
@given(damaged(PNG))
def test_png_reader_returns_rgb_or_input_error(content):
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "frame.png"
        path.write_bytes(content)
        try:
            image = read_rgb(path)
        except InputError as err:
            assert "\n" not in str(err) and "frame.png" in str(err)
        else:
            assert image.dtype == np.uint8 and image.ndim == 3 and image.shape[2] == 3


@FAST
@given(damaged(NPY))
def test_npy_readers_return_finite_2d_or_input_error(content):
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "x.npy"
        path.write_bytes(content)
        try:
            x = load_descriptors(path)
        except InputError as err:
            assert "\n" not in str(err) and "x.npy" in str(err)
        else:
            assert x.dtype == np.float32 and x.ndim == 2 and np.isfinite(x).all()
        try:  # the streaming reader opens the same file by memory map
            batches = memmap_batches(path, np.arange(3), (2, 3), 2, 0)
            list(batches(0))
        except InputError as err:
            assert "\n" not in str(err)


@pytest.fixture(scope="module")
def small_map(tmp_path_factory) -> Path:
    x = np.random.default_rng(1).normal(size=ROUTE).astype(np.float32)
    path = tmp_path_factory.mktemp("map") / "small.map"
    RhythmicMap().fit(x, progress=False).save(path)
    return path


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=5),
    lambda inner: (
        st.lists(inner, max_size=3)
        | st.dictionaries(st.text(max_size=5), inner, max_size=3)
    ),
    max_leaves=6,
)


@SLOW
@given(
    st.one_of(
        st.binary(max_size=200),
        json_values.map(lambda v: json.dumps(v).encode()),
        st.tuples(st.integers(0, 30), json_values),  # one field of the real file
    )
)
def test_map_loaders_load_or_raise_input_error(small_map, content):
    q = np.random.default_rng(2).normal(size=(4, ROUTE[1])).astype(np.float32)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "m.map"
        shutil.copytree(small_map, path)
        if isinstance(content, tuple):
            meta = json.loads((path / "map.json").read_text())
            fields = [(meta, k) for k in meta] + [
                (meta["config"], k) for k in meta["config"]
            ]
            where, key = fields[content[0] % len(fields)]
            where[key] = content[1]
            content = json.dumps(meta).encode()
        (path / "map.json").write_bytes(content)
        for load in (load_map, RhythmicMap.load):
            try:
                model = load(path)
                if isinstance(model, RhythmicMap):
                    model.predict(q)
            except InputError as err:
                assert "\n" not in str(err)


# -------------------------------------------------------------------- round trip


@SLOW
@given(st.integers(0, 2**31 - 1))
def test_save_load_preserves_every_prediction(seed):
    n, d = ROUTE
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, d)).astype(np.float32)
    queries = np.concatenate([x, rng.normal(size=(20, d)).astype(np.float32)])
    model = RhythmicMap().fit(x, progress=False)
    with tempfile.TemporaryDirectory() as tmp:
        model.save(Path(tmp) / "m.map")
        back = RhythmicMap.load(Path(tmp) / "m.map")
    assert back.info() == model.info()
    np.testing.assert_array_equal(np.asarray(back.params.w), np.asarray(model.params.w))
    for method in ("hard", "soft", "topm"):
        np.testing.assert_array_equal(
            back.predict(queries, method), model.predict(queries, method)
        )
    np.testing.assert_array_equal(
        back.predict(queries, sequence=3), model.predict(queries, sequence=3)
    )
