"""``frontier``'s cache is read through the map's reader and meaning checks: a
damaged entry is fitted again, never used."""

import dataclasses
import logging

import numpy as np
import pytest

from rhythmic_jax.eval.frontier import fitted_codes, fitted_map, fitted_model
from rhythmic_jax.map import map_file


@pytest.fixture(scope="module")
def ref():
    rng = np.random.default_rng(4)
    walk = np.cumsum(rng.standard_normal((80, 24)), axis=0).astype(np.float32)
    return walk - walk.mean(0)


def _entry(cache):
    (folder,) = cache.glob("map-*")
    return folder


def test_nan_templates_in_the_cache_are_refitted(ref, tmp_path, caplog):
    w, b, per = fitted_map(ref, 2, 1, 5e-4, tmp_path)
    m = fitted_model(ref, 2, 1, 5e-4, tmp_path)
    stored = {**m.stored, "w": np.full_like(np.asarray(m.stored["w"]), np.nan)}
    map_file.save(_entry(tmp_path), dataclasses.replace(m, stored=stored))
    with caplog.at_level(logging.WARNING, "rhythmic_jax.eval.frontier"):
        w2, b2, per2 = fitted_map(ref, 2, 1, 5e-4, tmp_path)
    assert "NaN" in caplog.text and "fitted again" in caplog.text
    assert np.isfinite(w2).all() and per2 == per
    np.testing.assert_allclose(w2, w, rtol=1e-5, atol=1e-6)
    caplog.clear()
    with caplog.at_level(logging.WARNING, "rhythmic_jax.eval.frontier"):
        fitted_map(ref, 2, 1, 5e-4, tmp_path)  # the entry was replaced: read back
    assert "fitted again" not in caplog.text


def test_arrays_cut_short_in_the_cache_are_refitted(ref, tmp_path, caplog):
    w, _, _ = fitted_map(ref, 2, 1, 5e-4, tmp_path)
    files = [f for f in _entry(tmp_path).rglob("*") if f.is_file()]
    big = max(files, key=lambda f: f.stat().st_size)
    big.write_bytes(big.read_bytes()[: big.stat().st_size // 2])
    with caplog.at_level(logging.WARNING, "rhythmic_jax.eval.frontier"):
        w2, _, _ = fitted_map(ref, 2, 1, 5e-4, tmp_path)
    assert "fitted again" in caplog.text
    np.testing.assert_allclose(w2, w, rtol=1e-5, atol=1e-6)
    # templates of the wrong shape, saved with fresh digests: refused by shape
    m = fitted_model(ref, 2, 1, 5e-4, tmp_path)
    stored = {**m.stored, "w": np.asarray(m.stored["w"])[:-3]}
    map_file.save(_entry(tmp_path), dataclasses.replace(m, stored=stored))
    caplog.clear()
    with caplog.at_level(logging.WARNING, "rhythmic_jax.eval.frontier"):
        w3, _, _ = fitted_map(ref, 2, 1, 5e-4, tmp_path)
    assert "fitted again" in caplog.text and w3.shape == w.shape


def test_damaged_codes_in_the_cache_are_refitted(ref, tmp_path, caplog):
    book = fitted_codes(ref, 8, tmp_path)
    (entry,) = tmp_path.glob("itq-*.npz")
    arrays = dict(np.load(entry))
    arrays["codes_projection"][:] = np.nan
    np.savez(entry, **arrays)
    with caplog.at_level(logging.WARNING, "rhythmic_jax.eval.frontier"):
        again = fitted_codes(ref, 8, tmp_path)
    assert "fitted again" in caplog.text
    np.testing.assert_array_equal(again.codes, book.codes)
    entry.write_bytes(entry.read_bytes()[:100])  # cut short
    caplog.clear()
    with caplog.at_level(logging.WARNING, "rhythmic_jax.eval.frontier"):
        again = fitted_codes(ref, 8, tmp_path)
    assert "fitted again" in caplog.text
    np.testing.assert_array_equal(again.codes, book.codes)
