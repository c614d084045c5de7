"""The cache folder's .npy files: written atomically, refused when they do not fit."""

from __future__ import annotations

import os

import numpy as np
import pytest

from rhythmic_jax.errors import InputError
from rhythmic_jax.frames.cache_files import (
    cache_key_check,
    default_cache_dir,
    load_cached,
    save_cached,
)


def test_save_then_load(tmp_path):
    x = np.arange(6, dtype=np.float32).reshape(2, 3)
    path = tmp_path / "sub" / "a.npy"
    save_cached(path, x)
    np.testing.assert_array_equal(load_cached(path, (2, 3)), x)
    assert [p.name for p in path.parent.iterdir()] == ["a.npy"]  # no temporary left
    assert load_cached(path, (3, 2)) is None  # mis-shaped: recomputed by the caller
    assert load_cached(tmp_path / "missing.npy", (2, 3)) is None
    path.write_bytes(b"garbage")
    assert load_cached(path, (2, 3)) is None


def test_keys_and_folder(monkeypatch, tmp_path):
    for bad in ("", "a/b", ".hidden"):
        with pytest.raises(InputError, match="cache key"):
            cache_key_check(bad)
    cache_key_check("route-1")
    monkeypatch.setenv("RHYTHMIC_JAX_CACHE", str(tmp_path))
    assert default_cache_dir() == tmp_path


def test_a_write_stopped_midway_keeps_the_previous_entry(monkeypatch, tmp_path):
    path = tmp_path / "a.npy"
    old = np.arange(6, dtype=np.float32).reshape(2, 3)
    save_cached(path, old)

    def half_then_fail(fh, x, allow_pickle=False):
        fh.write(np.asarray(x).tobytes()[:5])
        raise KeyboardInterrupt

    monkeypatch.setattr(np, "save", half_then_fail)
    with pytest.raises(KeyboardInterrupt):
        save_cached(path, old + 1)
    monkeypatch.undo()
    np.testing.assert_array_equal(load_cached(path, (2, 3)), old)
    assert [p.name for p in tmp_path.iterdir()] == ["a.npy"]  # no temporary left


def test_a_truncated_entry_is_recomputed_with_a_warning(tmp_path, caplog):
    path = tmp_path / "a.npy"
    save_cached(path, np.ones((40, 8), np.float32))
    path.write_bytes(path.read_bytes()[:200])  # what a non-atomic writer leaves
    with caplog.at_level("WARNING", logger="rhythmic_jax.frames.cache_files"):
        assert load_cached(path, (40, 8)) is None
    assert "recomputing unreadable cache file" in caplog.text


@pytest.mark.parametrize("fault", ["a file", "full", "read-only"])
def test_a_cache_that_cannot_be_written_warns_once_and_the_job_goes_on(
    monkeypatch, tmp_path, caplog, fault
):
    """``RHYTHMIC_JAX_CACHE`` naming a file, a full disk, a read-only one: the
    descriptors are still computed (equal to an uncached run's), one warning."""
    import errno

    from rhythmic_jax.frames import cache_files
    from rhythmic_jax.frames.features import cached_describe, describe, get_descriptor
    from rhythmic_jax.io import atomic

    monkeypatch.setattr(cache_files, "_WARNED", set())
    folder = tmp_path / "cache"
    if fault == "a file":
        folder.write_text("not a folder")
    else:
        code = errno.ENOSPC if fault == "full" else errno.EROFS

        def refuse(*args, **kwargs):
            raise OSError(code, os.strerror(code))

        monkeypatch.setattr(atomic.tempfile, "mkstemp", refuse)
    images = np.random.default_rng(0).integers(0, 256, (3, 32, 64, 3), np.uint8)
    d = get_descriptor("patchnorm", width=64, height=32, patch=8)
    with caplog.at_level("WARNING", logger="rhythmic_jax.frames.cache_files"):
        for key in ("a", "b"):
            got = cached_describe(images, d, key, cache_dir=folder, progress=False)
            np.testing.assert_array_equal(got, describe(images, d, progress=False))
        save_cached(folder / "c.npy", np.ones((2, 2), np.float32))
    warnings = [r for r in caplog.records if r.levelname == "WARNING"]
    assert len(warnings) == 1 and "going on without the cache" in warnings[0].message
    assert not list(tmp_path.glob("**/*.tmp"))
