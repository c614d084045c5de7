"""Ctrl-C and SIGTERM end ``rhythmic-jax`` at once: exit 130 (143), one line on
stderr, no map; the workers of ``fit --processes`` die with their launcher."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from rhythmic_jax.app import signals
from rhythmic_jax.solvers import distributed

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")


def _taken_over(pid: int, timeout: float = 60.0) -> None:
    """Wait until the command has taken SIGTERM over (``signals.install``, its
    first step): the moments below count from there, so a loaded machine's slow
    interpreter start does not put the signal before the command began."""
    until = time.monotonic() + timeout
    while time.monotonic() < until:
        status = Path(f"/proc/{pid}/status").read_text()
        caught = int(next(ln for ln in status.splitlines() if ln.startswith("SigCgt:"))
                     .split()[1], 16)  # fmt: skip
        if caught >> (signal.SIGTERM - 1) & 1:
            return
        time.sleep(0.01)
    raise AssertionError("the command never took its signals over")


def _start(*argv: str, cwd: Path) -> subprocess.Popen:
    """The command, compiling its programs anew (no compile cache): with the
    frames below its work lasts seconds even on an idle machine."""
    return subprocess.Popen(
        [sys.executable, "-m", "rhythmic_jax.app.cli", *argv, "--no-progress"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=cwd,
        env={**os.environ, "RHYTHMIC_JAX_COMPILE_CACHE": "0"},
        # as a user's shell delivers it: a parallel test runner may start its
        # workers with SIGINT ignored, which a child would otherwise inherit
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )


@pytest.fixture(scope="module")
def frames(tmp_path_factory) -> Path:
    """1,000 small JPEGs: a plain image fit of about 4-5 s on an idle machine
    (120 had ended within 1.4 s once its programs were cached)."""
    folder = tmp_path_factory.mktemp("signals") / "frames"
    folder.mkdir()
    rng = np.random.default_rng(0)
    for i in range(1000):
        pixels = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
        Image.fromarray(pixels).save(folder / f"{i:04d}.jpg")
    return folder


@pytest.mark.parametrize(
    "sig, after",
    [(signal.SIGINT, 0.3), (signal.SIGINT, 1.5), (signal.SIGTERM, 2.5)],
    ids=["int-starting", "int-working", "term-working"],
)
def test_a_stopped_fit_ends_at_once_in_one_line_and_writes_no_map(
    frames, tmp_path, sig, after
):
    out = tmp_path / "route.map"
    proc = _start("fit", str(frames), "--out", str(out), cwd=tmp_path)
    _taken_over(proc.pid)
    time.sleep(after)
    assert proc.poll() is None, "the fit ended before it could be stopped"
    proc.send_signal(sig)
    sent = time.monotonic()
    _, err = proc.communicate(timeout=30)
    assert time.monotonic() - sent < 10, err
    what = "interrupted" if sig == signal.SIGINT else "terminated"
    assert proc.returncode == 128 + sig, err
    assert err.strip().splitlines() == [f"rhythmic-jax fit: {what}"], err
    assert not out.exists()
    assert [p.name for p in tmp_path.iterdir() if not p.name.startswith(".")] == []


def test_a_failed_command_ends_without_the_interpreters_shutdown(tmp_path):
    code = (
        "import atexit, sys\n"
        "from rhythmic_jax.app import signals\n"
        "atexit.register(print, 'shutdown ran')\n"
        "print('said', end='')\n"
        "signals.finish(0)\n"
        "signals.finish(2)\n"
    )
    got = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert (got.returncode, got.stdout) == (2, "said"), got.stderr


def test_the_launcher_and_its_workers_agree_on_where_it_is_named():
    assert distributed.LAUNCHER_ENV == signals.LAUNCHER_ENV


def _children(pid: int) -> list[int]:
    try:
        return [
            int(c) for c in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
        ]
    except OSError:
        return []


def _running(pid: int) -> bool:
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    return "\nState:\tZ" not in status  # a zombie has ended


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="needs /proc")
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGINT], ids=lambda s: s.name)
def test_the_workers_of_a_stopped_launcher_end_within_5_s(tmp_path, sig):
    """``fit --processes 2``: its launcher killed (or stopped with Ctrl-C) while
    the workers run leaves no worker after 5 s, and no map."""
    x = np.random.default_rng(0).normal(size=(6000, 256)).astype(np.float32)
    np.save(tmp_path / "big.npy", x)
    out = tmp_path / "route.map"
    proc = _start("fit", "big.npy", "--out", str(out), "--processes", "2",
                  cwd=tmp_path)  # fmt: skip
    start = time.monotonic()
    while len(_children(proc.pid)) < 2 and time.monotonic() - start < 60:
        time.sleep(0.05)
    workers = _children(proc.pid)
    assert len(workers) == 2
    time.sleep(1.0)  # the workers are importing, joining, or fitting
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=30)
    sent = time.monotonic()
    while any(_running(w) for w in workers) and time.monotonic() - sent < 5:
        time.sleep(0.05)
    left = [w for w in workers if _running(w)]
    for w in left:
        os.kill(w, signal.SIGKILL)
    assert not left, err
    assert not out.exists()
    if sig == signal.SIGINT:
        assert proc.returncode == 130
        assert err.strip().splitlines() == ["rhythmic-jax fit: interrupted"], err
