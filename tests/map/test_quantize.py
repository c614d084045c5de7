"""Templates stored as float16 and int8: round trips, bytes, saved maps."""

import numpy as np
import pytest

from rhythmic_jax import RhythmicMap
from rhythmic_jax.errors import InputError
from rhythmic_jax.map.quantize import dequantize, quantize, template_bytes


@pytest.fixture(scope="module")
def route():
    """A smooth random walk of 300 unit frames, 32-d."""
    rng = np.random.default_rng(1)
    x = np.cumsum(rng.normal(size=(300, 32)), axis=0).astype(np.float32)
    return x / np.linalg.norm(x, axis=1, keepdims=True)


def test_round_trips_stay_within_each_dtypes_step():
    rng = np.random.default_rng(0)
    w, b = rng.normal(size=(50, 7)).astype(np.float32), rng.normal(size=7)
    w[:, 3] *= 1e-3  # a small template keeps its own scale
    b[3] *= 1e-3
    w16, b16 = dequantize(quantize(w, b, "float16"))
    assert np.allclose(w16, w, rtol=1e-3, atol=6e-8)  # float16 subnormals
    stored = quantize(w, b, "int8")
    assert stored["w"].dtype == np.int8 and stored["scale"].shape == (7,)
    w8, b8 = dequantize(stored)
    top = np.maximum(np.abs(w).max(0), np.abs(b))
    assert np.all(np.abs(w8 - w) <= top / 254 + 1e-9)
    assert np.all(np.abs(b8 - b) <= top / 254 + 1e-9)
    assert np.abs(w8[:, 3] - w[:, 3]).max() < 1e-5


def test_bytes_count_the_chosen_dtype():
    assert template_bytes(10, 99, "float32") == 10 * 100 * 4
    assert template_bytes(10, 99, "float16") == 10 * 100 * 2
    assert template_bytes(10, 99, "int8") == 10 * 100 + 40
    with pytest.raises(InputError, match="dtype"):
        template_bytes(1, 1, "float64")


@pytest.mark.slow
def test_maps_keep_their_dtype_on_disk_and_most_of_their_accuracy(route, tmp_path):
    full = RhythmicMap(r=2, gap=1e-3).fit(route, progress=False)
    base = np.mean(full.predict(route) == np.arange(len(route)))
    for dtype, size in (("float16", 2), ("int8", 1)):
        m = full.with_dtype(dtype)
        assert m.periods == full.periods
        assert m.storage_bytes == template_bytes(sum(m.periods), 32, dtype)
        assert m.storage_bytes < full.storage_bytes * size / 4 + 4 * sum(m.periods) + 1
        acc = np.mean(m.predict(route) == np.arange(len(route)))
        assert acc >= base - (0.005 if dtype == "float16" else 0.05)
        m.save(tmp_path / dtype)
        back = RhythmicMap.load(tmp_path / dtype)
        assert back.config.dtype == dtype and back.storage_bytes == m.storage_bytes
        assert back.info()["storage_bytes"] == m.storage_bytes
        np.testing.assert_array_equal(back.predict(route), m.predict(route))
    with pytest.raises(InputError, match="dtype"):
        RhythmicMap(dtype="float64").fit(route[:100], progress=False)
    direct = RhythmicMap(r=2, gap=1e-3, dtype="int8").fit(route[:100], progress=False)
    assert direct.info()["config"]["dtype"] == "int8"
    assert direct.storage_bytes == template_bytes(sum(direct.periods), 32, "int8")
