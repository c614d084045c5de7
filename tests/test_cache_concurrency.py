"""The descriptor cache shared by jobs: entries whole or absent, damage recomputed.

Every job of a user shares ``$RHYTHMIC_JAX_CACHE``. Two ``rhythmic-jax fit`` jobs
at once on one image folder with an empty cache, or a job killed while it writes
an entry, must leave the entry whole or absent; the next job reuses a whole
entry or recomputes, and a truncated one is recomputed with a warning.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import skimage.io

from rhythmic_jax.io import checkpoint

N_IMAGES = 80

# A job whose numpy.save writes half of the array's bytes, flushes them and then
# dies by SIGKILL: the state a killed writer leaves on disk, deterministically.
KILLED_WRITER = """
import os, signal, sys
import numpy as np
from rhythmic_jax.app import cli

def save_then_die(fh, x, allow_pickle=False):
    x = np.asarray(x)
    np.lib.format.write_array_header_1_0(
        fh, np.lib.format.header_data_from_array_1_0(x)
    )
    data = x.tobytes()
    fh.write(data[: len(data) // 2])
    fh.flush()
    os.fsync(fh.fileno())
    os.kill(os.getpid(), signal.SIGKILL)

np.save = save_then_die
sys.exit(cli.main(sys.argv[1:]))
"""


def _images(folder: Path) -> Path:
    rng = np.random.default_rng(0)
    folder.mkdir()
    for i in range(N_IMAGES):
        image = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
        skimage.io.imsave(folder / f"{i:04d}.jpg", image, check_contrast=False)
    return folder


def _fit_args(folder: Path, out: Path) -> list[str]:
    return ["fit", str(folder), "--out", str(out), "--descriptor", "patchnorm",
            "--no-progress"]  # fmt: skip


def _env(cache: Path) -> dict[str, str]:
    return {**os.environ, "RHYTHMIC_JAX_CACHE": str(cache)}


def _start(args: list[str], cache: Path, code: str | None = None):
    head = ["-c", code] if code else ["-m", "rhythmic_jax.app.cli"]
    return subprocess.Popen(
        [sys.executable, *head, *args],
        env=_env(cache),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _finish(job) -> str:
    out, err = job.communicate(timeout=600)
    assert job.returncode == 0, err[-2000:]
    return out + err


def _entries(cache: Path) -> list[Path]:
    """The cache's descriptor entries (hidden temporary files left out)."""
    return sorted(p for p in cache.glob("*.npy") if not p.name.startswith("."))


def _whole(entry: Path) -> np.ndarray:
    x = np.load(entry, allow_pickle=False)
    assert x.shape[0] == N_IMAGES and x.dtype == np.float32
    assert np.isfinite(x).all()
    return x


def _same_map(a: Path, b: Path) -> None:
    (arr_a, meta_a), (arr_b, meta_b) = checkpoint.load_map(a), checkpoint.load_map(b)
    assert meta_a["periods"] == meta_b["periods"]
    assert sorted(arr_a) == sorted(arr_b)
    for key in arr_a:
        np.testing.assert_array_equal(arr_a[key], arr_b[key])


@pytest.mark.slow
def test_two_fits_at_once_share_an_empty_cache(tmp_path):
    folder, cache = _images(tmp_path / "frames"), tmp_path / "cache"
    jobs = [_start(_fit_args(folder, tmp_path / f"m{i}.map"), cache) for i in (1, 2)]
    for job in jobs:
        _finish(job)
    entries = _entries(cache)
    assert len(entries) == 1, entries  # both jobs wrote the one key
    assert [p.name for p in cache.iterdir() if p.name.startswith(".")] == []
    x = _whole(entries[0])
    _same_map(tmp_path / "m1.map", tmp_path / "m2.map")
    before = entries[0].stat()
    _finish(_start(_fit_args(folder, tmp_path / "m3.map"), cache))
    after = entries[0].stat()
    # found whole and reused: a recomputed entry is a new file renamed over it
    assert (after.st_ino, after.st_mtime_ns) == (before.st_ino, before.st_mtime_ns)
    np.testing.assert_array_equal(_whole(entries[0]), x)
    _same_map(tmp_path / "m1.map", tmp_path / "m3.map")


@pytest.mark.slow
def test_a_job_killed_while_writing_leaves_no_partial_entry(tmp_path):
    folder, cache = _images(tmp_path / "frames"), tmp_path / "cache"
    killed = _start(_fit_args(folder, tmp_path / "k.map"), cache, KILLED_WRITER)
    _, err = killed.communicate(timeout=600)
    assert killed.returncode == -signal.SIGKILL, err[-2000:]
    assert _entries(cache) == []  # the half-written bytes never took the name
    assert not (tmp_path / "k.map").exists()

    text = _finish(_start(_fit_args(folder, tmp_path / "a.map"), cache))
    assert "recomputing" not in text  # nothing damaged under the entry's name
    (entry,) = _entries(cache)
    x = _whole(entry)

    # a truncated entry (a copy cut short, a full disk) is recomputed, and said
    entry.write_bytes(entry.read_bytes()[: entry.stat().st_size // 2])
    text = _finish(_start(_fit_args(folder, tmp_path / "b.map"), cache))
    assert "recomputing unreadable cache file" in text
    assert _entries(cache) == [entry]
    np.testing.assert_array_equal(_whole(entry), x)
    _same_map(tmp_path / "a.map", tmp_path / "b.map")
