"""SIGKILL at random moments: during a training run and during a map save.

A killed training run resumes from its checkpoints and ends on the templates of
an uninterrupted run; a map killed while being replaced still loads (from its
path, or from the backup an interrupted save keeps) and predicts exactly as one
of the two complete maps did.
"""

from __future__ import annotations

import logging
import random
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from rhythmic_jax import RhythmicMap
from rhythmic_jax.decoding.hard import hard_decode
from rhythmic_jax.solvers.objective import scores, targets
from rhythmic_jax.solvers.optax_loops import ridge_start
from rhythmic_jax.solvers.resumable import RunConfig, memmap_batches, train_run

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="needs SIGKILL")

TRAIN_CHILD = """
import sys
import numpy as np
from rhythmic_jax.solvers.objective import Templates
from rhythmic_jax.solvers.resumable import RunConfig, memmap_batches, train_run

root = sys.argv[1]
init = np.load(root + "/init.npz")
config = RunConfig(**{CONFIG})
batches = memmap_batches(root + "/x.npy", np.load(root + "/labels.npy"), {PERIODS},
                         config.batch_size, config.seed)
train_run(batches, Templates(init["w"], init["b"]), {C}, {N}, config,
          root + "/ckpt", progress=False)
print("finished", flush=True)
"""

SAVE_CHILD = """
import sys
from rhythmic_jax import RhythmicMap

model = RhythmicMap.load(sys.argv[1])
print("ready", flush=True)
while True:
    model.save(sys.argv[2])
"""


def _child(tmp_path: Path, name: str, code: str, *args: str) -> subprocess.Popen:
    script = tmp_path / name
    script.write_text(textwrap.dedent(code))
    return subprocess.Popen(
        [sys.executable, str(script), *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _kill(proc: subprocess.Popen) -> None:
    alive = proc.poll() is None
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    assert alive, f"the child ended before it was killed: {proc.stderr.read()}"
    assert proc.returncode == -signal.SIGKILL


def _wait_for_a_checkpoint(proc: subprocess.Popen, ckpt: Path, moment) -> None:
    """Wait for the child's first checkpoint in ``ckpt``, then a random moment
    more (``moment``: a seeded ``random.Random``), so a kill lands mid-run."""
    deadline = time.monotonic() + 120
    while not (ckpt.is_dir() and any(p.name.isdigit() for p in ckpt.iterdir())):
        assert proc.poll() is None, proc.stderr.read()
        assert time.monotonic() < deadline, "no checkpoint within two minutes"
        time.sleep(0.02)
    time.sleep(moment.uniform(0.0, 0.3))


# ------------------------------------------------------------------- training

N, D, PERIODS, C = 48, 6, (7, 8), 2.0
CONFIG = {"epochs": 3, "batch_size": 4, "learning_rate": 0.05, "checkpoint_every": 1}


def test_sigkill_during_training_resumes_to_the_same_map(tmp_path, caplog):
    rng = np.random.default_rng(0)
    x = rng.normal(size=(N, D)).astype(np.float32)
    labels = np.arange(N)
    init = ridge_start(x[:8], targets(labels[:8], PERIODS), C)
    np.save(tmp_path / "x.npy", x)
    np.save(tmp_path / "labels.npy", labels)
    np.savez(tmp_path / "init.npz", w=np.asarray(init.w), b=np.asarray(init.b))
    code = TRAIN_CHILD.format(CONFIG=CONFIG, PERIODS=PERIODS, C=C, N=N)
    proc = _child(tmp_path, "train_child.py", code, str(tmp_path))
    ckpt = tmp_path / "ckpt"
    _wait_for_a_checkpoint(proc, ckpt, random.Random(0))
    _kill(proc)

    config = RunConfig(**CONFIG)
    batches = memmap_batches(tmp_path / "x.npy", labels, PERIODS, 4, config.seed)
    whole = train_run(batches, init, C, N, config, None, progress=False)
    sparse = RunConfig(**{**CONFIG, "checkpoint_every": 1000})  # cadence may differ
    with caplog.at_level(logging.INFO, logger="rhythmic_jax.solvers.resumable"):
        resumed = train_run(batches, init, C, N, sparse, ckpt, progress=False)
    assert "resuming from" in caplog.text  # it did pick up the killed run's steps
    np.testing.assert_allclose(np.asarray(resumed.w), np.asarray(whole.w), atol=1e-6)
    np.testing.assert_allclose(np.asarray(resumed.b), np.asarray(whole.b), atol=1e-6)
    pred = [
        np.asarray(hard_decode(scores(p, jnp.asarray(x)), PERIODS, N).index)
        for p in (resumed, whole)
    ]
    np.testing.assert_array_equal(pred[0], pred[1])


# ------------------------------------------------------------------ map saves


def test_sigkill_during_map_saves_leaves_a_loadable_map(tmp_path):
    rng = np.random.default_rng(1)
    queries = rng.normal(size=(50, 16)).astype(np.float32)
    small = RhythmicMap().fit(queries[:40], progress=False)
    other = rng.normal(size=(40, 16)).astype(np.float32)
    large = RhythmicMap().fit(other, progress=False)
    large.extra["padding"] = rng.normal(size=(1000, 1000)).astype(np.float32)
    path, source = tmp_path / "route.map", tmp_path / "large.map"
    small.save(path)
    large.save(source)
    expected = {
        "small": (small.info(), small.predict(queries)),
        "large": (large.info(), large.predict(queries)),
    }
    assert not np.array_equal(expected["small"][1], expected["large"][1])

    moments = random.Random(2)
    for _ in range(3):
        proc = _child(tmp_path, "save_child.py", SAVE_CHILD, str(source), str(path))
        assert proc.stdout.readline().strip() == "ready", proc.stderr.read()
        time.sleep(moments.uniform(0.0, 1.5))
        _kill(proc)
        back = RhythmicMap.load(path)
        name = "large" if "padding" in back.extra else "small"
        info, pred = expected[name]
        assert back.info() == info
        np.testing.assert_array_equal(back.predict(queries), pred)
    small.save(path)  # a complete save afterwards clears what the kills left
    leftovers = [p.name for p in tmp_path.iterdir() if p.name.startswith(".route")]
    assert leftovers == []
    np.testing.assert_array_equal(
        RhythmicMap.load(path).predict(queries), expected["small"][1]
    )


BETWEEN_RENAMES_CHILD = """
import os
import signal
import sys
from rhythmic_jax import RhythmicMap

model = RhythmicMap.load(sys.argv[1])
rename = os.rename

def rename_then_die(src, dst):
    rename(src, dst)
    if ".old-" in str(dst):  # the old map is aside, the new one not yet in place
        os.kill(os.getpid(), signal.SIGKILL)

os.rename = rename_then_die
model.save(sys.argv[2])
"""


def test_sigkill_between_the_renames_loads_the_backup(tmp_path, caplog):
    """Killed with the old map moved aside and a half-deleted backup from an
    earlier kill beside it: the intact backup is the one loaded."""
    rng = np.random.default_rng(3)
    queries = rng.normal(size=(40, 16)).astype(np.float32)
    first = RhythmicMap().fit(queries, progress=False)
    second = RhythmicMap().fit(queries[::-1].copy(), progress=False)
    path, source = tmp_path / "route.map", tmp_path / "second.map"
    first.save(path)
    second.save(source)
    stale = tmp_path / ".route.map.old-ffffffff"  # sorts after any other backup
    (stale / "arrays").mkdir(parents=True)
    (stale / "map.json").write_text((path / "map.json").read_text())
    proc = _child(
        tmp_path, "rename_child.py", BETWEEN_RENAMES_CHILD, str(source), str(path)
    )
    proc.wait(timeout=120)
    assert proc.returncode == -signal.SIGKILL, proc.stderr.read()
    assert not path.exists()  # killed exactly between the two renames
    with caplog.at_level(logging.WARNING, logger="rhythmic_jax.io.checkpoint"):
        back = RhythmicMap.load(path)
    assert "loading the copy kept by an interrupted save" in caplog.text
    np.testing.assert_array_equal(back.predict(queries), first.predict(queries))
    second.save(path)  # the next save puts a map in place and clears the rest
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []
    np.testing.assert_array_equal(
        RhythmicMap.load(path).predict(queries), second.predict(queries)
    )


# ------------------------------------------------------- augmented fits (CLI)

# 10 epochs of 10 steps: long enough after the first checkpoint that a signal
# sent a moment later always lands mid-run, however fast the steps are
AUGMENTED_ARGS = ["--augment", "all", "--epochs", "10", "--batch-size", "8",
                  "--checkpoint-every", "1", "--no-progress"]  # fmt: skip
AUGMENTED_STEPS = 100
# the uninterrupted run saves its state twice, not at every step (a tenth of a
# second each): the cadence does not change the map, as test_sigkill_during_training
# checks, and the run still makes, then removes, its checkpoint folder
WHOLE_ARGS = ["--augment", "all", "--epochs", "10", "--batch-size", "8",
              "--checkpoint-every", "50", "--no-progress"]  # fmt: skip


@pytest.fixture(scope="module")
def augmented_route(tmp_path_factory):
    """40 frames in a folder and the map of an uninterrupted augmented fit."""
    from skimage.io import imsave

    from rhythmic_jax.app.cli import main

    root = tmp_path_factory.mktemp("augmented")
    rng = np.random.default_rng(4)
    (root / "frames").mkdir()
    for i in range(40):
        pixels = rng.integers(0, 256, (16, 32, 3), dtype=np.uint8)
        imsave(root / "frames" / f"{i:03d}.png", pixels, check_contrast=False)
    assert main(["fit", str(root / "frames"), "--out", str(root / "whole.map"),
                 *WHOLE_ARGS]) == 0  # fmt: skip
    assert not (root / "whole.map.ckpt").exists()  # removed once the map is saved
    assert main(["fit", str(root / "frames"), "--out", str(root / "plain.map"),
                 "--no-progress"]) == 0  # fmt: skip
    whole, plain = (RhythmicMap.load(root / m) for m in ("whole.map", "plain.map"))
    moved = np.abs(np.asarray(whole.params.w) - np.asarray(plain.params.w)).max()
    assert moved > 1e-3  # the augmented steps did change the templates
    return root


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGINT], ids=lambda s: s.name)
def test_a_stopped_augmented_fit_resumes_to_the_same_map(
    augmented_route, sig, tmp_path, caplog, capsys
):
    """``rhythmic-jax fit --augment`` killed (or stopped with Ctrl-C) mid-run and
    run again with the same command ends on the uninterrupted run's map."""
    from rhythmic_jax.app.cli import main

    frames, out = augmented_route / "frames", tmp_path / "route.map"
    argv = ["fit", str(frames), "--out", str(out), *AUGMENTED_ARGS]
    proc = subprocess.Popen(
        [sys.executable, "-m", "rhythmic_jax.app.cli", *argv],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        # Ctrl-C as a user's shell delivers it: a parallel test runner may start
        # its workers with SIGINT ignored, which a child would otherwise inherit
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    ckpt = tmp_path / "route.map.ckpt"
    _wait_for_a_checkpoint(proc, ckpt, random.Random(sig))
    if sig == signal.SIGKILL:
        _kill(proc)
        err = proc.stderr.read()
    else:
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=60)
        assert proc.returncode == 130, err
        assert "run the same command again to resume" in err, err
    assert not out.exists(), err  # no map from a stopped fit
    steps = sorted(int(p.name) for p in ckpt.iterdir() if p.name.isdigit())
    # stopped before the last step
    assert steps and steps[-1] < AUGMENTED_STEPS, (steps, err)

    with caplog.at_level(logging.INFO, logger="rhythmic_jax.solvers.resumable"):
        assert main(argv) == 0
    assert "resuming from" in caplog.text
    assert not ckpt.exists()
    whole, resumed = (RhythmicMap.load(p) for p in (augmented_route / "whole.map", out))
    assert resumed.periods == whole.periods
    for a, b in zip(resumed.params, whole.params, strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), atol=1e-5)
    x = np.random.default_rng(5).normal(size=(64, whole.d)).astype(np.float32)
    np.testing.assert_array_equal(resumed.predict(x), whole.predict(x))
