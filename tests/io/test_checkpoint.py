"""Maps on disk: round trips, atomic replacement, and every way a folder can be bad."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from rhythmic_jax.errors import InputError
from rhythmic_jax.io import checkpoint
from rhythmic_jax.io.checkpoint import FORMAT_VERSION, load_map, save_map


def _arrays(seed=0, d=9, p=12):
    rng = np.random.default_rng(seed)
    return {
        "w": rng.normal(size=(d, p)).astype(np.float32),
        "b": rng.normal(size=(p,)).astype(np.float32),
        "special": np.array([np.nan, np.inf, -np.inf, -0.0, 1e-45], np.float32),
        "big": (np.arange(5, dtype=np.int64) + 1) * 2**40,  # survives without x64
        "f64": rng.normal(size=(3, 2)),
        "i32": np.arange(-3, 3, dtype=np.int32),
        "flags": np.array([True, False, True]),
        "scalar": np.float32(2.5),
    }


META = {
    "periods": [3, 4, 5],
    "n": 60,
    "d": 9,
    "c": 4.0943445622221,
    "descriptor": "patchnorm",
    "settings": {"size": [64, 32], "eps": 1e-12},
    "candidate_errors": [0.0, 0.5, 0.25],
}


def _hidden(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.parent.iterdir() if p.name.startswith("."))


def _assert_same(got: dict, want: dict) -> None:
    assert sorted(got) == sorted(want)
    for k, v in want.items():
        v = np.asarray(v)
        assert got[k].dtype == v.dtype, k
        assert got[k].shape == v.shape, k
        assert got[k].tobytes() == v.tobytes(), k  # bit-equal, NaNs included


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    """One saved map, copied by the tests that damage it."""
    root = tmp_path_factory.mktemp("saved")
    path = save_map(root / "map", _arrays(), META)
    return path


def _copy(saved: Path, tmp_path: Path) -> Path:
    dst = tmp_path / "map"
    shutil.copytree(saved, dst)
    return dst


def test_round_trip_is_bit_equal(saved):
    assert saved.is_dir() and saved.is_absolute()
    arrays, meta = load_map(saved)
    _assert_same(arrays, _arrays())
    assert meta == {"format_version": FORMAT_VERSION, **META}
    assert json.loads((saved / "map.json").read_text())["format_version"] == 1
    assert _hidden(saved) == []  # no temporary folder left beside it


def test_save_creates_parents_and_accepts_str_paths(tmp_path):
    path = save_map(str(tmp_path / "a" / "b" / "map"), {"w": np.ones(3)}, {})
    assert path == (tmp_path / "a" / "b" / "map").absolute()
    arrays, meta = load_map(str(path))
    _assert_same(arrays, {"w": np.ones(3)})
    assert meta == {"format_version": FORMAT_VERSION}


def test_save_over_existing_map_replaces_it(saved, tmp_path):
    path = _copy(saved, tmp_path)
    new = {"w": np.full((2, 2), 7.0, np.float32)}
    assert save_map(path, new, {"n": 2}) == path
    arrays, meta = load_map(path)
    _assert_same(arrays, new)  # the old "b", "big", ... are gone
    assert meta == {"format_version": FORMAT_VERSION, "n": 2}
    assert _hidden(path) == []  # the previous map is removed, no temp left


@pytest.mark.parametrize("kind", ["folder", "file"])
def test_refuses_to_replace_a_non_map(tmp_path, kind):
    path = tmp_path / "precious"
    if kind == "folder":
        path.mkdir()
        (path / "notes.txt").write_text("keep me")
        keep = path / "notes.txt"
    else:
        path.write_text("keep me")
        keep = path
    with pytest.raises(InputError, match="not a map folder"):
        save_map(path, {"w": np.ones(2)}, {})
    assert keep.read_text() == "keep me"
    assert _hidden(path) == []


def test_missing_folder(tmp_path):
    with pytest.raises(InputError, match="no such map folder"):
        load_map(tmp_path / "nothing")


@pytest.mark.parametrize(
    "content",
    [
        b'{"format_version": 1, "periods": [3,',  # truncated
        b"",
        b"\xff\xfe\x00garbage",  # not UTF-8
        b"[1, 2, 3]",  # not an object
        b'{"periods": [3, 4]}',  # no version
        b'{"format_version": "1"}',
    ],
)
def test_corrupt_metadata(saved, tmp_path, content):
    path = _copy(saved, tmp_path)
    (path / "map.json").write_bytes(content)
    with pytest.raises(InputError, match="corrupt metadata") as err:
        load_map(path)
    assert "\n" not in str(err.value)


def test_missing_metadata(saved, tmp_path):
    path = _copy(saved, tmp_path)
    (path / "map.json").unlink()
    with pytest.raises(InputError, match="not a map folder"):
        load_map(path)


def test_newer_format_is_refused(saved, tmp_path):
    path = _copy(saved, tmp_path)
    meta = json.loads((path / "map.json").read_text())
    meta["format_version"] = FORMAT_VERSION + 1
    (path / "map.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match="newer"):
        load_map(path)


def _data_files(path: Path) -> list[Path]:
    return sorted(p for p in (path / "arrays").rglob("*") if p.parent.name == "d")


@pytest.mark.parametrize("damage", ["truncate", "empty", "delete_data", "delete_all"])
def test_damaged_arrays(saved, tmp_path, damage):
    path = _copy(saved, tmp_path)
    files = _data_files(path)
    assert files  # the layout this test damages is there
    if damage == "truncate":
        for f in files:
            f.write_bytes(f.read_bytes()[: f.stat().st_size // 2])
    elif damage == "empty":
        for f in (path / "arrays").rglob("*"):
            if f.is_file():
                f.write_bytes(b"")
    elif damage == "delete_data":
        for f in files:
            f.unlink()
    else:
        shutil.rmtree(path / "arrays")
    with pytest.raises(InputError, match="arrays are missing or corrupt") as err:
        load_map(path)
    assert "\n" not in str(err.value)


def test_backup_of_an_interrupted_save_is_loaded(saved, tmp_path, caplog):
    # a crash between "map -> .map.old-*" and ".map.tmp-* -> map": only the
    # backup and a finished temp folder exist
    path = _copy(saved, tmp_path)
    os.rename(path, tmp_path / ".map.old-0123abcd")
    shutil.copytree(tmp_path / ".map.old-0123abcd", tmp_path / ".map.tmp-89abcdef")
    arrays, meta = load_map(path)
    _assert_same(arrays, _arrays())
    assert meta["periods"] == META["periods"]
    assert "interrupted save" in caplog.text
    # the next save puts a map in place and clears the stale backup
    save_map(path, {"w": np.zeros(3, np.float32)}, {})
    _assert_same(load_map(path)[0], {"w": np.zeros(3, np.float32)})
    assert not (tmp_path / ".map.old-0123abcd").exists()


def _failing_rename(monkeypatch, target: Path, which: str):
    """Make os.rename fail for one of save_map's two renames (orbax's pass)."""
    real = os.rename

    def rename(src, dst, *args, **kwargs):
        src, dst_p = Path(src), Path(dst)
        first = src == target and dst_p.name.startswith(f".{target.name}.old-")
        second = src.name.startswith(f".{target.name}.tmp-") and dst_p == target
        if (which == "first" and first) or (which == "second" and second):
            raise OSError(28, "No space left on device (injected)")
        return real(src, dst, *args, **kwargs)

    monkeypatch.setattr(checkpoint.os, "rename", rename)


@pytest.mark.parametrize("which", ["first", "second"])
def test_failed_rename_keeps_old_map(saved, tmp_path, monkeypatch, which):
    path = _copy(saved, tmp_path)
    _failing_rename(monkeypatch, path, which)
    with pytest.raises(OSError, match="injected"):
        save_map(path, {"w": np.zeros(4, np.float32)}, {"n": 4})
    monkeypatch.undo()
    assert _hidden(path) == []  # no temp folder, no backup
    arrays, meta = load_map(path)
    _assert_same(arrays, _arrays())
    assert meta == {"format_version": FORMAT_VERSION, **META}


def test_failed_first_save_leaves_nothing(tmp_path, monkeypatch):
    path = tmp_path / "map"
    _failing_rename(monkeypatch, path, "second")
    with pytest.raises(OSError, match="injected"):
        save_map(path, {"w": np.zeros(4, np.float32)}, {})
    assert list(tmp_path.iterdir()) == []


def test_unserialisable_metadata_keeps_old_map(saved, tmp_path):
    path = _copy(saved, tmp_path)
    with pytest.raises(TypeError):  # json cannot write a set; arrays were written
        save_map(path, {"w": np.zeros(4, np.float32)}, {"periods": {3, 4}})
    assert _hidden(path) == []
    _assert_same(load_map(path)[0], _arrays())


@pytest.mark.parametrize(
    "bad",
    [
        np.array([{"a": 1}], dtype=object),
        np.array(["ab", "c"]),
        np.zeros((0, 3), np.float32),
    ],
    ids=["object", "str", "empty"],
)
def test_unsaveable_array_keeps_old_map(saved, tmp_path, bad):
    path = _copy(saved, tmp_path)
    with pytest.raises(InputError, match="arrays\\['bad'\\]"):
        save_map(path, {"w": np.ones(3), "bad": bad}, {})
    assert _hidden(path) == []
    _assert_same(load_map(path)[0], _arrays())
