"""The one writer: whole files or nothing, plain-open permissions; devices,
pipes and the process's streams written through, never replaced."""

from __future__ import annotations

import io
import os
import socket
import stat
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from rhythmic_jax.io import outputs
from rhythmic_jax.io.atomic import atomic_path, save_npy, write_file
from rhythmic_jax.io.outputs import OutputError


def test_write_file_replaces_whole_and_leaves_no_temporary(tmp_path):
    path = tmp_path / "sub" / "report.md"
    write_file(path, "first\n")
    write_file(path, "second\n")
    assert path.read_text() == "second\n"
    write_file(path, b"\x00\x01")
    assert path.read_bytes() == b"\x00\x01"
    assert sorted(p.name for p in path.parent.iterdir()) == ["report.md"]


def test_permissions_follow_the_umask(tmp_path):
    old = os.umask(0o022)
    try:
        write_file(tmp_path / "a.txt", "x")
    finally:
        os.umask(old)
    assert (tmp_path / "a.txt").stat().st_mode & 0o777 == 0o644


def test_a_failed_write_keeps_the_previous_content(tmp_path):
    path = tmp_path / "x.npy"
    save_npy(path, np.arange(3))
    with pytest.raises(RuntimeError, match="on purpose"):
        with atomic_path(path) as tmp:
            tmp.write_bytes(b"half")
            raise RuntimeError("on purpose")
    np.testing.assert_array_equal(np.load(path), np.arange(3))
    assert [p.name for p in tmp_path.iterdir()] == ["x.npy"]


def test_save_npy_refuses_objects(tmp_path):
    with pytest.raises(ValueError):
        save_npy(tmp_path / "o.npy", np.array([{}], dtype=object))
    assert not any(tmp_path.iterdir())


# ------------------------------------------- devices, pipes and streams: through
NULL_MODE = os.stat(os.devnull).st_mode


def _null_still_a_device():
    assert stat.S_ISCHR(os.stat(os.devnull).st_mode)
    assert os.stat(os.devnull).st_mode == NULL_MODE


def test_dev_null_is_written_through_and_stays_a_device():
    write_file(os.devnull, "x" * 10_000)
    save_npy(os.devnull, np.arange(5))
    _null_still_a_device()


def test_a_full_device_ends_in_one_line(tmp_path):
    if not Path("/dev/full").exists():
        pytest.skip("needs /dev/full")
    with pytest.raises(OutputError) as err:
        write_file("/dev/full", b"x")
    assert str(err.value) == "/dev/full: could not write it (No space left on device)"
    assert stat.S_ISCHR(os.stat("/dev/full").st_mode)


def test_a_link_to_a_device_is_followed_and_kept(tmp_path):
    link = tmp_path / "null.npy"
    link.symlink_to(os.devnull)
    save_npy(link, np.arange(3))
    assert link.is_symlink() and os.readlink(link) == os.devnull
    assert sorted(p.name for p in tmp_path.iterdir()) == ["null.npy"]
    _null_still_a_device()


def test_a_link_to_a_file_replaces_the_file_and_keeps_the_link(tmp_path):
    (tmp_path / "real.txt").write_text("old")
    (tmp_path / "link.txt").symlink_to("real.txt")
    write_file(tmp_path / "link.txt", "new")
    assert (tmp_path / "link.txt").is_symlink()
    assert (tmp_path / "real.txt").read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link.txt", "real.txt"]


WRITE_STDOUT = """
import sys
from rhythmic_jax.io.atomic import write_file
print("before", flush=True)
write_file(sys.argv[1], b"\\x00through\\xff")
print("after")
"""


@pytest.mark.parametrize("name", ["/dev/stdout", "/proc/self/fd/1", "link"])
def test_standard_output_is_written_at_its_place(tmp_path, name):
    """A stream of the process: written to its open descriptor, in order with
    what was printed (a file it goes to is appended to, not replaced)."""
    if not Path("/proc/self/fd").is_dir():
        pytest.skip("needs /proc")
    if name == "link":
        name = str(tmp_path / "out.link")
        Path(name).symlink_to("/dev/stdout")
    script = tmp_path / "w.py"
    script.write_text(WRITE_STDOUT)
    got = subprocess.run([sys.executable, str(script), name], capture_output=True,
                         timeout=60, env=_env())  # fmt: skip
    assert got.returncode == 0, got.stderr
    assert got.stdout == b"before\n\x00through\xffafter\n"
    out = tmp_path / "stdout.txt"
    with open(out, "wb") as fh:
        fh.write(b"kept\n")
        fh.flush()
        with open(out, "ab") as append:
            done = subprocess.run([sys.executable, str(script), name], stdout=append,
                                  timeout=60, env=_env())  # fmt: skip
    assert done.returncode == 0
    assert out.read_bytes() == b"kept\nbefore\n\x00through\xffafter\n"


def _env() -> dict:
    root = str(Path(__file__).resolve().parents[2])
    return {**os.environ, "PYTHONPATH": root, "JAX_PLATFORMS": "cpu"}


def test_a_pipe_nobody_reads_ends_in_one_line_at_once(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    start = time.monotonic()
    with pytest.raises(OutputError, match=r"pipe: could not write it \(no process"):
        write_file(fifo, "x")
    assert time.monotonic() - start < 5
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pipe"]


def test_a_pipe_with_a_reader_gets_the_bytes(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    got: list[bytes] = []

    def read():
        with open(fifo, "rb") as fh:  # blocks until a writer opens it
            got.append(fh.read())

    reader = threading.Thread(target=read)
    reader.start()
    deadline = time.monotonic() + 10
    while True:  # the reader's open must come first (no reader: refused)
        try:
            save_npy(fifo, np.arange(4))
            break
        except OutputError:
            assert time.monotonic() < deadline
            time.sleep(0.05)
    reader.join(10)
    assert np.load(io.BytesIO(got[0])).tolist() == [0, 1, 2, 3]
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)


def test_a_folder_where_a_file_is_wanted_is_refused(tmp_path):
    (tmp_path / "pr.png").mkdir()
    with pytest.raises(OutputError, match="is a folder; give a file name"):
        write_file(tmp_path / "pr.png", "x")
    assert list((tmp_path / "pr.png").iterdir()) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pr.png"]


def test_a_socket_is_refused(tmp_path):
    sock = socket.socket(socket.AF_UNIX)
    try:
        sock.bind(str(tmp_path / "s"))
        with pytest.raises(OutputError, match="is a socket"):
            write_file(tmp_path / "s", "x")
    finally:
        sock.close()


def test_a_cancelled_job_writes_nothing_through(tmp_path, monkeypatch):
    """A device is written under the same commit lock as a rename: once the
    job is cancelled, nothing is written and no temporary is left."""
    before = set(Path(tempfile.gettempdir()).glob(".rhythmic-jax-out.*"))
    cancelled = threading.Event()
    cancelled.set()
    monkeypatch.setattr(outputs, "_CANCELLED", cancelled)
    with pytest.raises(outputs.Cancelled):
        write_file(os.devnull, "x")
    assert set(Path(tempfile.gettempdir()).glob(".rhythmic-jax-out.*")) == before
    _null_still_a_device()


def test_a_killed_writers_temporary_is_removed_by_the_next_write(tmp_path):
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)  # fmt: skip
    dead = tmp_path / f".p.npy.{gone.stdout.strip()}-a1b2c3.tmp"
    live = tmp_path / f".p.npy.{os.getppid()}-a1b2c3.tmp"  # a writer still going
    other = tmp_path / f".q.npy.{gone.stdout.strip()}-a1b2c3.tmp"
    for path in (dead, live, other):
        path.write_bytes(b"half")
    save_npy(tmp_path / "p.npy", np.arange(2))
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["p.npy", live.name, other.name]
    )
