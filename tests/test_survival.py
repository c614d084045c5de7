"""Maps that survive their users: one writer at a time, one whole version for every
reader, a killed writer's leftovers cleaned, and a changed byte in any stored file
refused in one line naming it."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from rhythmic_jax.errors import InputError
from rhythmic_jax.io import checkpoint
from rhythmic_jax.io.checkpoint import load_map, locked, save_map
from rhythmic_jax.map import map_file

RNG = np.random.default_rng(0)


def _arrays(seed: int, n: int = 7) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {
        "w": rng.normal(size=(n, 5)).astype(np.float32),
        "b": rng.normal(size=n),
        "codes": rng.integers(0, 255, (n, 3), dtype=np.uint8),
    }


def _same(got: dict, want: dict) -> bool:
    return set(got) == set(want) and all(
        np.array_equal(got[k], want[k]) and got[k].dtype == want[k].dtype for k in want
    )


def _leftovers(path: Path) -> list[str]:
    """Hidden names beside ``path``: temporary folders, backups, lock files."""
    return sorted(p.name for p in path.parent.iterdir() if p.name.startswith("."))


def _in_thread(fn, *args) -> tuple[threading.Thread, dict]:
    box: dict = {}

    def run():
        try:
            box["value"] = fn(*args)
        except BaseException as err:  # noqa: BLE001 - handed to the test
            box["error"] = err

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread, box


# ------------------------------------------------------------- one writer at a time


def test_a_save_waits_for_the_other_writer_and_readers_see_one_version(tmp_path):
    path = tmp_path / "m.map"
    save_map(path, _arrays(0), {"n": 0})
    with locked(path, exclusive=True):  # another writer, mid-save
        writer, wrote = _in_thread(save_map, path, _arrays(1), {"n": 1})
        time.sleep(0.5)
        assert writer.is_alive()  # waits its turn
        assert _same(load_map_unlocked(path), _arrays(0))  # nothing touched yet
    writer.join(60)
    assert "error" not in wrote, wrote
    arrays, meta = load_map(path)
    assert meta["n"] == 1 and _same(arrays, _arrays(1))
    with locked(path, exclusive=False):  # a reader, mid-read
        writer, wrote = _in_thread(save_map, path, _arrays(2), {"n": 2})
        time.sleep(0.5)
        assert writer.is_alive()  # the save waits for the read to end
    writer.join(60)
    assert "error" not in wrote and load_map(path)[1]["n"] == 2
    with locked(path, exclusive=True):  # a reader waits for a save to end
        reader, read = _in_thread(load_map, path)
        time.sleep(0.3)
        assert reader.is_alive()
    reader.join(60)
    assert read["value"][1]["n"] == 2 and _leftovers(path) == []


def load_map_unlocked(path: Path) -> dict[str, np.ndarray]:
    """What the folder holds now, read past the lock (the test holds it)."""
    ckpt = checkpoint._checkpointer()
    try:
        raw = ckpt.restore(path / "arrays")
    finally:
        ckpt.close()
    return {k: np.asarray(v) for k, v in raw.items()}


def test_a_writer_held_too_long_is_reported_in_one_line(tmp_path, monkeypatch):
    path = tmp_path / "m.map"
    save_map(path, _arrays(0), {})
    monkeypatch.setattr(checkpoint, "LOCK_WAIT_S", 0.2)
    with locked(path, exclusive=True):
        with pytest.raises(InputError, match="another process has held it"):
            save_map(path, _arrays(1), {})
        with pytest.raises(InputError, match="another process has held it"):
            load_map(path)
    assert _same(load_map(path)[0], _arrays(0))


def test_a_killed_writers_leftovers_are_cleaned_and_its_backup_restored(tmp_path):
    """A writer killed mid-save leaves its hidden temporary folder; one killed
    between its renames leaves the map under its backup name. Their locks are
    free, so the next save removes the first and readers and writers find the
    second."""
    path = tmp_path / "m.map"
    save_map(path, _arrays(0), {"n": 0})
    stale = tmp_path / ".m.map.tmp-dead0001"
    (stale / "arrays").mkdir(parents=True)
    (stale / "arrays" / "half").write_bytes(b"\0" * 10)
    os.rename(path, tmp_path / ".m.map.old-dead0002")  # killed between renames
    arrays, meta = load_map(path)  # the backup, whole
    assert meta["n"] == 0 and _same(arrays, _arrays(0))
    assert map_file.info(path, lambda p: {"n": "loaded"})["n"] == "loaded"
    save_map(path, _arrays(1), {"n": 1})
    assert _leftovers(path) == []
    assert _same(load_map(path)[0], _arrays(1))


def test_two_processes_saving_one_path_end_with_one_whole_map(tmp_path):
    """Two processes save onto one path at once (each save slowed, so they
    overlap): both succeed, one after the other, and the folder holds one of the
    two maps whole, no temporary folder left."""
    path = tmp_path / "m.map"
    code = (
        "import sys, time, numpy as np\n"
        "from rhythmic_jax.io import checkpoint\n"
        "slow = checkpoint._write_arrays\n"
        "def write(tmp, arrays):\n"
        "    slow(tmp, arrays); time.sleep(1.0)\n"
        "checkpoint._write_arrays = write\n"
        "seed = int(sys.argv[2])\n"
        "rng = np.random.default_rng(seed)\n"
        "arrays = {'w': rng.normal(size=(7, 5)).astype(np.float32),\n"
        "          'b': rng.normal(size=7),\n"
        "          'codes': rng.integers(0, 255, (7, 3), dtype=np.uint8)}\n"
        "checkpoint.save_map(sys.argv[1], arrays, {'n': seed})\n"
    )
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", code, str(path), str(seed)],
            stderr=subprocess.PIPE,
            text=True,
            env=env,
        )
        for seed in (11, 12)
    ]
    errs = [p.communicate(timeout=120)[1] for p in procs]
    assert [p.returncode for p in procs] == [0, 0], errs
    arrays, meta = load_map(path)
    assert meta["n"] in (11, 12) and _same(arrays, _arrays(meta["n"]))
    assert _leftovers(path) == []


# ------------------------------------------------------------------- checksums


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    from rhythmic_jax import RhythmicMap

    x = RNG.normal(size=(60, 24)).astype(np.float32)
    path = tmp_path_factory.mktemp("maps") / "m.map"
    model = RhythmicMap(r=2, level=1, codes=16).fit(x, progress=False)
    model.save(path)
    return path, x


def _files(folder: Path) -> list[Path]:
    return sorted(p for p in (folder / "arrays").rglob("*") if p.is_file())


def test_a_flipped_byte_anywhere_in_the_arrays_is_refused(fitted, tmp_path):
    """Ten positions spread over every file of the arrays: each flipped byte is
    refused by load (so by query) and by info, in one line naming the file."""
    import shutil

    from rhythmic_jax.app import jobs

    saved, _ = fitted
    files = [p.relative_to(saved) for p in _files(saved)]
    positions = [(files[i % len(files)], (i * 37) % 1000) for i in range(10)]
    assert len({f for f, _ in positions}) == min(10, len(files))
    for k, (rel, at) in enumerate(positions):
        path = tmp_path / f"m{k}.map"
        shutil.copytree(saved, path)
        data = bytearray((path / rel).read_bytes())
        data[at % len(data)] ^= 0x01
        (path / rel).write_bytes(bytes(data))
        for read in (load_map, lambda p: jobs.info(str(p))):
            with pytest.raises(InputError) as err:
                read(path)
            line = str(err.value)
            assert "\n" not in line and str(path) in line, line
            assert rel.relative_to("arrays").as_posix() in line, line


def test_a_changed_value_is_refused_by_its_array_digest(fitted, tmp_path, monkeypatch):
    """The values orbax hands back are checked too (here a reader that returns
    a changed value from unchanged files)."""
    import shutil

    saved, _ = fitted
    path = tmp_path / "m.map"
    shutil.copytree(saved, path)
    restore = checkpoint._checkpointer

    class Changed:
        def __init__(self):
            self.inner = restore()

        def restore(self, where):
            raw = dict(self.inner.restore(where))
            raw["b"] = np.asarray(raw["b"]).copy()
            raw["b"][0] += 1
            return raw

        def metadata(self, where):  # the declared shapes, checked before restoring
            return self.inner.metadata(where)

        def close(self):
            self.inner.close()

    monkeypatch.setattr(checkpoint, "_checkpointer", Changed)
    with pytest.raises(InputError, match=r"array 'b' changed since the map was saved"):
        load_map(path)


def test_maps_saved_before_checksums_still_load_and_info_says_so(fitted, tmp_path):
    import shutil

    from rhythmic_jax import RhythmicMap
    from rhythmic_jax.app import jobs, render

    saved, x = fitted
    path = tmp_path / "old.map"
    shutil.copytree(saved, path)
    meta = json.loads((path / "map.json").read_text())
    assert set(meta["digests"]["sha256"]) == {"files", "arrays"}
    del meta["digests"]
    (path / "map.json").write_text(json.dumps(meta))
    old, new = RhythmicMap.load(path), RhythmicMap.load(saved)
    np.testing.assert_array_equal(old.predict(x), new.predict(x))
    assert jobs.info(str(path))["checksums"].startswith("none (saved before")
    assert "checksums: none" in render.info_lines(jobs.info(str(path)))
    assert jobs.info(str(saved))["checksums"].startswith("sha256")


def test_the_digest_is_of_the_values_read_back():
    """Big-endian and Fortran-ordered arrays come back native and C-ordered: the
    same values, the same digest; another dtype or shape, another digest."""
    x = RNG.normal(size=(3, 4))
    digest = checkpoint.array_digest(x)
    assert checkpoint.array_digest(x.astype(">f8")) == digest
    assert checkpoint.array_digest(np.asfortranarray(x)) == digest
    assert checkpoint.array_digest(x.astype(np.float32)) != digest
    assert checkpoint.array_digest(x.reshape(4, 3)) != digest
