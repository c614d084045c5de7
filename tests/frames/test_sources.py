"""Command-line sources: descriptor files, image folders, tiles, and the reference
a map's brute-force line is drawn over."""

from __future__ import annotations

import numpy as np
import pytest
from skimage.io import imsave

from rhythmic_jax import RhythmicMap
from rhythmic_jax.errors import InputError
from rhythmic_jax.frames.sources import (
    load_query_source,
    load_sources,
    reference_features,
    source_key,
)

RNG = np.random.default_rng(0)


def _folder(path, n=12, shift=0):
    path.mkdir()
    for i in range(n):
        pixels = np.roll(RNG.integers(0, 256, (16, 32, 3), dtype=np.uint8), shift)
        imsave(path / f"f{i}.png", pixels, check_contrast=False)
    return str(path)


def test_a_source_key_changes_with_the_source_and_its_cut(tmp_path):
    import os
    from pathlib import Path

    folder = Path(_folder(tmp_path / "route", n=2))
    key = source_key(folder)
    assert key.startswith("route-") and key == source_key(folder, None, None)
    assert source_key(folder, 16, 8) not in (key, source_key(folder, 16, 4))
    stat = folder.stat()
    os.utime(folder, ns=(stat.st_atime_ns, stat.st_mtime_ns + 1))
    assert source_key(folder) != key


def test_descriptor_files_and_folders_share_place_labels(tmp_path):
    x = RNG.normal(size=(10, 6)).astype(np.float32)
    np.save(tmp_path / "a.npy", x)
    np.save(tmp_path / "b.npy", x + 1)
    feats = load_sources([str(tmp_path / "a.npy"), str(tmp_path / "b.npy")])
    np.testing.assert_array_equal(feats.x, np.concatenate([x, x + 1]))
    np.testing.assert_array_equal(feats.labels, np.r_[np.arange(10), np.arange(10)])
    assert feats.images is None
    folders = [_folder(tmp_path / "s"), _folder(tmp_path / "w")]
    feats = load_sources(folders, progress=False)
    assert feats.descriptor == "patchnorm" and feats.images.shape == (24, 16, 32, 3)
    np.testing.assert_array_equal(feats.labels, np.r_[np.arange(12), np.arange(12)])


def test_reference_is_explicit_recorded_or_explained(tmp_path):
    x = RNG.normal(size=(30, 8)).astype(np.float32)
    np.save(tmp_path / "ref.npy", x)
    model = RhythmicMap().fit(x, progress=False)
    ref, labels, note = reference_features(model, str(tmp_path / "ref.npy"))
    np.testing.assert_array_equal(ref, x)
    np.testing.assert_array_equal(labels, np.arange(30))
    ref, labels, note = reference_features(model)
    assert ref is None and labels is None and "the map names none" in note
    model.reference = {"sources": [str(tmp_path / "ref.npy")] * 2}
    ref, labels, note = reference_features(model)
    assert ref.shape == (60, 8) and labels[30] == 0 and "ref.npy" in note
    model.reference = {"sources": [str(tmp_path / "gone.npy")]}
    ref, _, note = reference_features(model)
    assert ref is None and note.endswith("gone.npy is gone); give --reference SOURCE")


def test_queries_must_fit_the_maps_descriptor(tmp_path):
    feats = load_sources([_folder(tmp_path / "s")], progress=False)
    model = RhythmicMap(descriptor="patchnorm", descriptor_settings=feats.settings)
    model.fit(feats.x, progress=False)
    again = load_query_source(str(tmp_path / "s"), model, progress=False)
    np.testing.assert_allclose(again.x, feats.x, atol=1e-6)
    with pytest.raises(InputError, match="built with descriptor 'patchnorm'"):
        load_query_source(str(tmp_path / "s"), model, "hog", progress=False)


def test_folders_are_described_as_read_and_cached(tmp_path, monkeypatch):
    """A folder is read ahead of the descriptor and cached by its files' bytes: a
    second load reads no frame, and without kept frames none are held."""
    from rhythmic_jax.frames import pipeline
    from rhythmic_jax.frames.features import describe, get_descriptor
    from rhythmic_jax.io import images

    monkeypatch.setenv("RHYTHMIC_JAX_CACHE", str(tmp_path / "cache"))
    folder = _folder(tmp_path / "s", n=7)
    frames = images.load_traversal(folder).images
    first = load_sources([folder], keep_images=False)
    assert first.images is None
    expected = describe(frames, get_descriptor("patchnorm"), progress=False)
    np.testing.assert_allclose(first.x, expected, atol=1e-6)
    assert len(list((tmp_path / "cache").glob("s-*-patchnorm-files-*.npy"))) == 1

    def unread(path):
        raise AssertionError(f"read {path} despite the cache")

    monkeypatch.setattr(images, "read_rgb", unread)
    monkeypatch.setattr(pipeline, "describe_chunks", unread)
    again = load_sources([folder], keep_images=False)
    np.testing.assert_array_equal(again.x, first.x)
