"""The map's file format: what a saved map folder holds, and ``info`` from its
metadata alone."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rhythmic_jax import InputError, MapConfig, RhythmicMap
from rhythmic_jax.io.checkpoint import arrays_listed, read_metadata
from rhythmic_jax.map import map_file


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    x = np.random.default_rng(0).normal(size=(60, 24)).astype(np.float32)
    path = tmp_path_factory.mktemp("maps") / "m.map"
    RhythmicMap(r=2, level=1, codes=16).fit(x, progress=False).save(path)
    return path


def _refused(path):
    raise AssertionError(f"{path}: loaded, though its metadata answers")


def test_the_metadata_holds_every_info_key_and_the_arrays_it_needs(saved):
    folder, meta = read_metadata(saved)
    model = RhythmicMap.load(saved)
    assert set(model.info()) == set(map_file.INFO_KEYS) | {"codes_kind"}
    listed = arrays_listed(folder)
    assert {"w", "b"} | map_file.CODE_ARRAYS["itq"] <= listed
    assert map_file.consistent(meta, listed)
    checked = {"checksums": "sha256 of every stored array, checked"}
    assert map_file.info(saved, _refused) == model.info() | checked


@pytest.mark.parametrize(
    "change",
    [
        lambda meta: meta.pop("storage"),
        lambda meta: meta.update(database_bytes=1),
        lambda meta: meta.update(periods=[5, 6]),
    ],
)
def test_inconsistent_metadata_is_handed_to_the_load(saved, tmp_path, change):
    folder, meta = read_metadata(saved)
    change(meta)
    meta.pop("digests")  # no arrays to check: the metadata alone is at fault
    assert not map_file.consistent(meta, arrays_listed(folder))
    assert not map_file.consistent(read_metadata(saved)[1], {"w", "b"})  # no codes
    (tmp_path / "m.map").mkdir()
    (tmp_path / "m.map" / "map.json").write_text(json.dumps(meta))
    assert map_file.info(tmp_path / "m.map", lambda p: {"loaded": str(p)}) == {
        "loaded": str(tmp_path / "m.map"),
        "checksums": "none (saved before maps carried checksums; not checked)",
    }


def test_load_checks_what_queries_need(saved):
    got = map_file.load(saved, MapConfig)
    assert isinstance(got.config, MapConfig) and got.codebook is not None
    assert got.stored["w"].shape == (24, sum(got.periods)) and got.n == 60
    with pytest.raises(InputError, match="queries are 9-d"):
        map_file.load(saved, MapConfig, d=9)
    with pytest.raises(InputError, match="queries use 'hog'"):
        map_file.load(saved, MapConfig, descriptor="hog")


def test_settings_under_an_earlier_name_are_renamed():
    """``m`` was the name of the phases top-m keeps; a name of now wins."""
    assert map_file.settings_now({"m": 4, "r": 2}) == {"top": 4, "r": 2}
    assert map_file.settings_now({"m": 4, "top": 2}) == {"top": 2}
    assert map_file.settings_now({"top": 2}) == {"top": 2}
