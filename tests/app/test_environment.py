"""The process's environment, through the installed command: outputs that are
devices, pipes or streams, closed standard streams, the C locale and ASCII stdio,
file names that are not UTF-8, a memory limit, and a fit --shards killed midway.

Every run ends in a result or one line with exit status 2, never a traceback or
a hang; /dev/null is still a character device after each.
"""

from __future__ import annotations

import io
import json
import os
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from rhythmic_jax.app import cli
from rhythmic_jax.app.cli import main

ROOT = Path(__file__).resolve().parents[2]
NULL = os.stat(os.devnull)


def _env(**extra) -> dict:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "JAX_PLATFORMS": "cpu"}
    return {**env, **extra}


def _command(*args, env=None, timeout=120, shell=None, **kw):
    """Run the command (``shell``: a ``sh`` line run first, as ``>&-`` or
    ``ulimit -v``, without forking this threaded process in Python)."""
    cmd = [sys.executable, "-m", "rhythmic_jax.app.cli", *map(os.fsdecode, args)]
    if shell is not None:
        cmd = ["sh", "-c", f'{shell}; exec "$@"', "sh", *cmd]
    kw.setdefault("capture_output", True)
    done = subprocess.run(cmd, env=env or _env(), timeout=timeout, **kw)
    now = os.stat(os.devnull)
    assert stat.S_ISCHR(now.st_mode) and now.st_rdev == NULL.st_rdev
    return done


def _one_line(err: bytes, *words: str) -> str:
    lines = [x for x in err.decode("utf-8", "replace").splitlines() if x.strip()]
    assert len(lines) == 1, lines
    assert "Traceback" not in lines[0]
    for word in words:
        assert word in lines[0], lines
    return lines[0]


def _hidden(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.rglob(".*"))


@pytest.fixture(scope="module")
def route(tmp_path_factory):
    """Descriptors of a route and a map fitted on them."""
    root = tmp_path_factory.mktemp("env")
    rng = np.random.default_rng(0)
    x = np.cumsum(rng.normal(size=(60, 16)), axis=0).astype(np.float32)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    np.save(root / "ref.npy", x)
    np.save(root / "q.npy", x + 0.01 * rng.normal(size=x.shape).astype(np.float32))
    assert main(["fit", str(root / "ref.npy"), "--out", str(root / "m.map"),
                 "--no-progress"]) == 0  # fmt: skip
    return root


def _frames(folder: Path, n: int, name=b"%03d.png") -> Path:
    """``n`` small frames of a smooth route (names as bytes: any the OS takes)."""
    folder.mkdir(parents=True)
    rng = np.random.default_rng(1)
    walk = np.cumsum(rng.normal(size=(n, 16, 24, 3)), axis=0)
    walk = (255 * (walk - walk.min()) / np.ptp(walk)).astype(np.uint8)
    for i in range(n):
        Image.fromarray(walk[i]).save(os.path.join(os.fsencode(folder), name % i),
                                      format="PNG")  # fmt: skip
    return folder


# ------------------------------------------------------------------ devices
def test_out_dev_stdout_writes_the_predictions_to_standard_output(route, tmp_path):
    link = tmp_path / "pred.npy"
    link.symlink_to("/dev/stdout")
    for out in ("/dev/stdout", link):
        done = _command("query", route / "m.map", route / "q.npy", "--out", out,
                        "--no-progress")  # fmt: skip
        assert done.returncode == 0, done.stderr
        pred = np.load(io.BytesIO(done.stdout), allow_pickle=False)
        assert pred.shape == (60,) and pred.dtype == np.int64
        assert b"60 predictions" in done.stdout[-200:]
    assert link.is_symlink() and sorted(os.listdir(tmp_path)) == ["pred.npy"]


def test_out_a_pipe_nobody_reads_is_one_line_not_a_hang(route, tmp_path):
    fifo = tmp_path / "pipe.npy"
    os.mkfifo(fifo)
    start = time.monotonic()
    done = _command("query", route / "m.map", route / "q.npy", "--out", fifo,
                    "--no-progress", timeout=30)  # fmt: skip
    assert time.monotonic() - start < 30
    assert done.returncode == 2
    _one_line(done.stderr, "--out", "no process reads the pipe")
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)


# --------------------------------------------------------- standard streams
def test_a_closed_standard_output_drops_only_what_is_printed(route, tmp_path):
    """With ``--out`` the work is done and the file written (the same
    predictions as with standard output open); only the summary line is
    dropped, said in one note. A query that writes nothing, or writes to
    standard output itself, is refused before any work."""
    out, ref = tmp_path / "p.npy", tmp_path / "ref.npy"
    done = _command("query", route / "m.map", route / "q.npy", "--out", out,
                    shell="exec >&-")  # fmt: skip
    assert done.returncode == 0, done.stderr
    _one_line(done.stderr, "standard output is closed", str(out))
    assert b"error" not in done.stderr
    again = _command("query", route / "m.map", route / "q.npy", "--out", ref)
    assert again.returncode == 0, again.stderr
    np.testing.assert_array_equal(np.load(out), np.load(ref))
    for extra in ([], ["--out", "/dev/stdout"]):
        bad = _command("query", route / "m.map", route / "q.npy", *extra,
                       shell="exec >&-")  # fmt: skip
        assert bad.returncode == 2
        _one_line(bad.stderr, "standard output is closed")


def test_a_closed_standard_error_is_silent(route, tmp_path):
    ok = _command("info", route / "m.map", shell="exec 2>&-")
    assert ok.returncode == 0 and b"periods" in ok.stdout and ok.stderr == b""
    bad = _command("info", tmp_path / "none.map", shell="exec 2>&-")
    assert bad.returncode == 2 and bad.stdout == b"" and bad.stderr == b""


@pytest.mark.parametrize(
    "env",
    [{"LC_ALL": "C", "PYTHONUTF8": "0"}, {"PYTHONIOENCODING": "ascii"}],
    ids=["C-locale", "ascii-stdio"],
)
def test_non_ascii_paths_in_the_c_locale_and_ascii_stdio(route, tmp_path, env):
    """The map is saved (orbax writes under a name it could not take) and the
    line says where in escapes: never "saved, then exit 1"."""
    folder = tmp_path / "été"
    folder.mkdir()
    (folder / "ref.npy").write_bytes((route / "ref.npy").read_bytes())
    env = _env(**env)
    fit = _command("fit", folder / "ref.npy", "--out", folder / "m.map",
                   "--no-progress", env=env)  # fmt: skip
    assert fit.returncode == 0, fit.stderr
    assert b"\\xe9t\\xe9/m.map" in fit.stdout
    assert main(["query", str(folder / "m.map"), str(folder / "ref.npy"), "--out",
                 str(folder / "p.npy"), "--no-progress"]) == 0  # fmt: skip
    assert np.load(folder / "p.npy").shape == (60,)
    if "LC_ALL" in env:
        bad = _command("info", folder / "none.map", env=env)
        assert bad.returncode == 2
        _one_line(bad.stderr, "\\xe9t\\xe9/none.map: no such map folder")


# ------------------------------------------------------- names not UTF-8
def test_frames_named_in_bytes_that_are_not_utf8(tmp_path, monkeypatch, capsys):
    """Carried as the OS gives them (the map is fitted and queried), shown as
    escapes (a refused frame is named readably); imageio, which looks at a file
    PIL cannot read, leaves nothing in the home folder."""
    frames = _frames(tmp_path / "route", 24, name=b"frame\xff%03d.png")
    out = tmp_path / "m.map"
    assert main(["fit", str(frames), "--out", str(out), "--no-progress"]) == 0
    assert main(["query", str(out), str(frames), "--json", "--no-progress"]) == 0
    capsys.readouterr()
    bad = os.path.join(os.fsencode(frames), b"frame\xff005.png")
    with open(bad, "wb") as fh:
        fh.write(b"not an image")
    home = tmp_path / "home"
    home.mkdir()
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.setenv("RHYTHMIC_JAX_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv("IMAGEIO_USERDIR", raising=False)
    argv = ["fit", str(frames), "--out", str(tmp_path / "n.map"), "--no-progress"]
    assert main(argv) == 2
    _one_line(capsys.readouterr().err.encode(), "frame\\xff005.png")
    assert os.listdir(home) == []  # nothing of imageio's in the home folder


# ------------------------------------------------------------------ memory
def test_a_memory_limit_too_small_to_start_is_one_line(route):
    done = _command("query", route / "m.map", route / "q.npy", "--no-progress",
                    shell=f"ulimit -v {1 << 20}")  # KiB: 1 GiB  # fmt: skip
    assert done.returncode == 2
    _one_line(done.stderr, "memory ran out", "ulimit -v", "1.00 GiB")


@pytest.mark.slow
def test_a_memory_limit_the_command_fits_in_gives_the_answer(route, tmp_path):
    """2 GB of address space (``ulimit -v 2000000``) holds a query once malloc
    keeps one arena: the threads' arenas took it whole before (an abort)."""
    out = tmp_path / "p.npy"
    done = _command("query", route / "m.map", route / "q.npy", "--out", out,
                    "--no-progress", shell="ulimit -v 2000000")  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    free = _command("query", route / "m.map", route / "q.npy", "--json")
    np.testing.assert_array_equal(
        np.load(out), json.loads(free.stdout)["predictions"]
    )


@pytest.mark.parametrize(
    "err",
    [
        MemoryError(),
        RuntimeError("RESOURCE_EXHAUSTED: Out of memory while trying to allocate "
                     "80000000000 bytes."),  # fmt: skip
        RuntimeError("can't start new thread"),
    ],
    ids=["MemoryError", "XLA", "thread"],
)
def test_memory_running_out_anywhere_is_one_line(route, monkeypatch, capsys, err):
    def runs_out(*args, **kwargs):
        raise err

    monkeypatch.setitem(cli.COMMANDS, "query", runs_out)
    assert main(["query", str(route / "m.map"), str(route / "q.npy")]) == 2
    err_lines = capsys.readouterr().err.strip().splitlines()
    assert len(err_lines) == 1 and "memory ran out" in err_lines[0], err_lines


def test_other_errors_still_raise(route, monkeypatch):
    def fails(*args, **kwargs):
        raise RuntimeError("RESOURCE_EXHAUSTED: Failed writing: No space left")

    monkeypatch.setitem(cli.COMMANDS, "query", fails)
    with pytest.raises(RuntimeError, match="No space left"):
        main(["query", str(route / "m.map"), str(route / "q.npy")])


# ------------------------------------------------------ a killed --shards run
def _start_until(argv, cwd: Path, ready) -> None:
    """Start the command, SIGKILL it once ``ready()`` holds (or it ended)."""
    cmd = [sys.executable, "-m", "rhythmic_jax.app.cli", *argv]
    proc = subprocess.Popen(cmd, cwd=cwd, env=_env(), stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)  # fmt: skip
    deadline = time.monotonic() + 120
    while proc.poll() is None and not ready() and time.monotonic() < deadline:
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)
    proc.wait(30)


@pytest.mark.parametrize(
    "when", [pytest.param("describing", marks=pytest.mark.slow), "fitting"]
)
def test_a_killed_fit_shards_is_rerun_by_the_same_command(tmp_path, when):
    """Killed while describing (its staged folder hidden) or while fitting (the
    shards finished): the same command then runs, and no hidden file is left."""
    _frames(tmp_path / "route", 80)
    argv = ["fit", "route", "--out", "r.map", "--shards", "r.shards", "--no-progress"]

    def ready():
        if when == "describing":
            return any(p.name.startswith(".r.shards.tmp-") for p in tmp_path.iterdir())
        return (tmp_path / "r.shards" / "shards.json").is_file()

    _start_until(argv, tmp_path, ready)
    again = _command(*argv, cwd=tmp_path)
    assert again.returncode == 0, again.stderr[-2000:]
    assert (tmp_path / "r.map" / "map.json").is_file()
    assert sorted(os.listdir(tmp_path / "r.shards")) == ["00-route", "shards.json"]
    assert _hidden(tmp_path) == []


def test_a_map_in_a_folder_named_in_bytes_that_are_not_utf8(tmp_path):
    """orbax's tensorstore takes no such name: the map is saved and read
    through an open descriptor of its folder, and nothing is left open."""
    from rhythmic_jax.io import checkpoint

    folder = Path(os.fsdecode(os.path.join(os.fsencode(tmp_path), b"r\xffoute")))
    target = folder / "m\xe9.map"
    w = np.arange(6, dtype=np.float32).reshape(3, 2)
    # a first save and load opens what the storage library keeps for the process
    checkpoint.save_map(tmp_path / "warm.map", {"w": w}, {"kind": "test"})
    checkpoint.load_map(tmp_path / "warm.map")
    fds = len(os.listdir("/proc/self/fd"))
    checkpoint.save_map(target, {"w": w}, {"kind": "test"})
    arrays, meta = checkpoint.load_map(target)
    np.testing.assert_array_equal(arrays["w"], w)
    assert meta["kind"] == "test"
    assert os.listdir(os.fsencode(folder)) == [os.fsencode("m\xe9.map")]
    assert len(os.listdir("/proc/self/fd")) <= fds


def test_out_dev_stdout_into_a_reader_that_leaves_is_quiet(route, tmp_path):
    """As any print into ``| head``: status 141, nothing on stderr."""
    rows = np.random.default_rng(0).normal(size=(20_000, 16)).astype(np.float32)
    np.save(tmp_path / "many.npy", rows / np.linalg.norm(rows, axis=1, keepdims=True))
    cmd = [sys.executable, "-m", "rhythmic_jax.app.cli", "query",
           str(route / "m.map"), str(tmp_path / "many.npy"), "--out", "/dev/stdout",
           "--no-progress"]  # fmt: skip
    proc = subprocess.Popen(cmd, env=_env(), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)  # fmt: skip
    assert proc.stdout.read(100)[:6] == b"\x93NUMPY"
    proc.stdout.close()  # the reader leaves
    err = proc.stderr.read()
    assert proc.wait(60) == 141 and err == b"", err
