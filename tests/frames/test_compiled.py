"""The compiled descriptor network: when a job compiles, padding to the fixed
batch, the eager fallback, and (slow) compiled against eager descriptors and maps."""

from __future__ import annotations

import logging
import re

import numpy as np
import pytest
import torch

from rhythmic_jax.errors import InputError
from rhythmic_jax.frames import compiled, package_builds
from rhythmic_jax.frames.compiled import (
    BUILD_MIN_FRAMES,
    LOAD_MIN_FRAMES,
    CompilePolicy,
    FastDescriptor,
    network_runner,
    package_path,
    plan,
    stages,
)
from rhythmic_jax.frames.features import describe, get_descriptor


@pytest.fixture(autouse=True)
def fresh(monkeypatch, tmp_path):
    """A private cache folder, no compiled network kept from another test, and
    no background build started."""
    monkeypatch.setenv("RHYTHMIC_JAX_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv(compiled.BUILD_ENV, "0")
    compiled._compiled.cache_clear()
    yield
    compiled._compiled.cache_clear()


def wants_compiled(descriptor, frames, policy, ready) -> bool:
    """Whether a job of ``frames`` frames runs ``descriptor`` compiled."""
    return compiled.plan(descriptor, frames, policy, ready) in ("load", "build")


def test_policy_decides_by_frames():
    lite0, patch = get_descriptor("efficientnet_lite0"), get_descriptor("patchnorm")
    auto = CompilePolicy()
    assert not wants_compiled(lite0, LOAD_MIN_FRAMES - 1, auto, ready=True)
    assert wants_compiled(lite0, LOAD_MIN_FRAMES, auto, ready=True)
    assert not wants_compiled(lite0, BUILD_MIN_FRAMES - 1, auto, ready=False)
    assert wants_compiled(lite0, BUILD_MIN_FRAMES, auto, ready=False)
    assert wants_compiled(lite0, 1, CompilePolicy("always"), ready=False)
    assert not wants_compiled(lite0, 10**9, CompilePolicy("never"), ready=True)
    assert wants_compiled(lite0, 50, CompilePolicy(min_frames=50), ready=False)
    assert not wants_compiled(lite0, 49, CompilePolicy(min_frames=50), ready=True)
    assert not wants_compiled(patch, 10**9, CompilePolicy("always"), ready=True)
    assert wants_compiled(lite0, 100, auto, ready=True)  # loading is cheap now
    assert not wants_compiled(lite0, 100, auto, ready=False)  # building is not


def test_policy_refuses_bad_settings():
    with pytest.raises(InputError) as err:
        CompilePolicy("fast")
    assert re.search("--compile 'fast'", err.value.as_flag())
    with pytest.raises(InputError) as err:
        CompilePolicy(min_frames=-1)
    assert re.search("--compile-min-frames", err.value.as_flag())



def test_chunks_pad_the_last_batch_to_the_fixed_shape():
    w = torch.randn(5, 3)
    seen = []

    def fixed(x):  # stands for a package compiled for 4 rows
        seen.append(tuple(x.shape))
        return x.flatten(1) @ w

    run = compiled._chunked(fixed, 4)
    x = torch.randn(10, 5, 1, 1).contiguous(memory_format=torch.channels_last)
    torch.testing.assert_close(run(x), x.flatten(1) @ w)
    assert seen == [(4, 5, 1, 1)] * 3  # 4 + 4 + 2 padded: never another shape
    assert run(x[:0]).shape == (0, 3)


def test_eager_runs_in_slices_of_the_batch_with_the_same_rows():
    seen = []
    module = torch.nn.Sequential(torch.nn.Conv2d(3, 4, 3), torch.nn.Flatten())

    def spy(mod, args):
        seen.append(len(args[0]))

    module.register_forward_pre_hook(spy)
    run = compiled.Sliced(module, 4)
    x = torch.randn(10, 3, 6, 6)
    with torch.inference_mode():
        torch.testing.assert_close(run(x), module(x), rtol=1e-6, atol=1e-6)
    assert seen == [4, 4, 2, 10]  # sliced, then the one whole call of the reference
    desc = get_descriptor("efficientnet_lite0")
    runner = network_runner(desc, 10, CompilePolicy("never"))
    assert isinstance(runner, compiled.Sliced)
    assert runner.batch == compiled.EAGER_BATCH


def test_failed_compile_runs_eagerly_with_one_warning(monkeypatch, caplog):
    def no_compiler(*args, **kwargs):
        raise RuntimeError("C++ compile error\nNo such file or directory: 'g++'")

    monkeypatch.setattr(compiled, "_build", no_compiler)
    desc = get_descriptor("efficientnet_lite0")
    frames = np.random.default_rng(0).integers(0, 256, (3, 40, 80, 3), np.uint8)
    with caplog.at_level(logging.WARNING, logger="rhythmic_jax.frames.compiled"):
        fast = describe(frames, desc, progress=False, compile=CompilePolicy("always"))
    eager = describe(frames, desc, progress=False, compile=CompilePolicy("never"))
    np.testing.assert_array_equal(fast, eager)
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 1 and "\n" not in lines[0]
    assert "compiling the network failed (RuntimeError: C++ compile error)" in lines[0]
    assert lines[0].endswith("running it eagerly")
    run = network_runner(desc, 10**6, CompilePolicy("always"))  # not tried again
    assert isinstance(run, compiled.Sliced) and len(caplog.records) == 1


def test_fast_descriptor_keeps_the_face_of_the_descriptor():
    desc = get_descriptor("efficientnet_lite0")
    fast = FastDescriptor(desc, 10, CompilePolicy("never"))
    assert (fast.name, fast.dim, fast.settings()) == (
        desc.name,
        desc.dim,
        desc.settings(),
    )
    batch = torch.rand(2, 3, 30, 50)
    torch.testing.assert_close(fast(batch), desc(batch))
    prepare, run = stages(desc)
    torch.testing.assert_close(run(prepare(batch)), desc(batch))
    patch = get_descriptor("patchnorm")
    prepare, run = stages(FastDescriptor(patch, 10))
    torch.testing.assert_close(run(prepare(batch)), patch(batch))


@pytest.mark.slow
def test_compiled_equals_eager_descriptors_and_predictions(
    nordland_root, nordland_lite0
):
    """Compiled (AOTInductor, built here, minutes) against the eager reference on
    real frames: the same descriptors (relative 1e-4) and the same map answers.

    The eager rows are those of all of Nordland that other tests share (a frame's
    eager row does not depend on the frames described with it: the same bits)."""
    from rhythmic_jax import RhythmicMap
    from rhythmic_jax.io.images import nordland

    (winter,) = nordland(nordland_root, seasons=("winter",))
    idx = np.arange(0, 3576, 12)  # 298 places along the route
    desc = get_descriptor("efficientnet_lite0")
    summer_rows, winter_rows = nordland_lite0
    eager = {"summer": summer_rows[idx], "winter": winter_rows[idx]}
    fast = describe(
        winter.images[idx], desc, progress=False, compile=CompilePolicy("always")
    )
    assert package_path(desc, (compiled.COMPILE_BATCH, 3, 112, 224)).is_file()
    rel = np.linalg.norm(fast - eager["winter"], axis=1)  # rows are unit
    assert rel.max() < 1e-4
    model = RhythmicMap(r=2).fit(eager["summer"], progress=False)
    np.testing.assert_array_equal(model.predict(fast), model.predict(eager["winter"]))
    assert (model.predict(fast) == np.arange(len(idx))).mean() > 0.05  # it localises


def _installed(*argv, cwd, env):
    import shutil
    import subprocess
    import sys

    script = shutil.which("rhythmic-jax")
    cmd = [script] if script else [sys.executable, "-m", "rhythmic_jax.app.cli"]
    return subprocess.run(
        [*cmd, *argv], cwd=cwd, env=env, capture_output=True, text=True, timeout=600
    )


def test_help_says_what_compiling_costs():
    from rhythmic_jax.app.cli import _parser

    parser = _parser()
    sub = parser._subparsers._group_actions[0].choices
    for command in ("fit", "query", "evaluate", "learn"):
        text = " ".join(sub[command].format_help().split())
        assert "--compile {auto,always,never}" in text
        assert "--compile-min-frames" in text
    text = " ".join(parser.format_help().split())  # the cost, once, in the epilog
    assert "up to a minute once per machine" in text


@pytest.mark.slow
def test_installed_command_without_a_compiler_runs_eagerly(tmp_path, rgb, write_image):
    """No C++ compiler (CXX and PATH lead nowhere): ``fit --compile always`` says so
    in one line and fits the map with the eager network, no traceback."""
    import os
    import sys

    frames = tmp_path / "frames"
    for i in range(3):
        write_image(frames, f"f{i}.png", rgb(40, 80))
    work = tmp_path / "elsewhere"
    work.mkdir()
    env = {
        **os.environ,
        "RHYTHMIC_JAX_CACHE": str(tmp_path / "cache"),
        "CXX": str(tmp_path / "no-compiler" / "c++"),
        "PATH": os.path.dirname(sys.executable),
    }
    proc = _installed(
        "fit", str(frames), "--out", "m.map", "--descriptor", "efficientnet_lite0",
        "--compile", "always", "--no-progress", cwd=work, env=env,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    lines = [line for line in proc.stderr.splitlines()  # fit's notes on its map aside
             if line.strip() and ": note: " not in line]  # fmt: skip
    assert len(lines) == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    assert "No working C++ compiler" in lines[0]
    assert lines[0].endswith("running it eagerly")
    assert (work / "m.map").is_dir() and "map m.map: n=3" in proc.stdout
    assert not list((tmp_path / "cache" / "compiled").glob("*.pt2"))


def test_plan_builds_in_the_background_for_the_next_job(monkeypatch):
    lite0, patch = get_descriptor("efficientnet_lite0"), get_descriptor("patchnorm")
    auto = CompilePolicy()
    monkeypatch.delenv(compiled.BUILD_ENV, raising=False)
    assert plan(lite0, LOAD_MIN_FRAMES - 1, auto, ready=False) == "eager"
    assert plan(lite0, LOAD_MIN_FRAMES, auto, ready=False) == "background"
    assert plan(lite0, BUILD_MIN_FRAMES - 1, auto, ready=False) == "background"
    assert plan(lite0, BUILD_MIN_FRAMES, auto, ready=False) == "build"
    assert plan(lite0, LOAD_MIN_FRAMES, auto, ready=True) == "load"
    assert plan(lite0, 1, CompilePolicy("always"), ready=False) == "build"
    assert plan(lite0, 10**6, CompilePolicy("never"), ready=True) == "eager"
    assert plan(lite0, 50, CompilePolicy(min_frames=50), ready=False) == "build"
    assert plan(patch, 10**6, auto, ready=False) == "eager"
    monkeypatch.setenv(compiled.BUILD_ENV, "0")
    assert plan(lite0, 100, auto, ready=False) == "eager"
    assert plan(lite0, BUILD_MIN_FRAMES, auto, ready=False) == "build"


@pytest.fixture
def spawned(monkeypatch):
    """Background builds allowed; each one recorded instead of started."""
    monkeypatch.delenv(compiled.BUILD_ENV, raising=False)
    calls = []
    monkeypatch.setattr(package_builds, "_spawn", calls.append)
    return calls


def _dead_pid() -> int:
    import subprocess

    proc = subprocess.Popen(["true"])
    proc.wait()
    return proc.pid


def _job(desc, frames: int):
    """A job's network, then the job over: the builds it queued start."""
    run = network_runner(desc, frames, CompilePolicy())
    compiled.start_pending_builds()
    return run


def test_first_job_runs_eagerly_and_starts_one_detached_build(spawned):
    """The first job runs eagerly beside no builder: the build it asks for
    starts once the job is over (one, detached), not while it runs."""
    import json
    import os

    desc = get_descriptor("efficientnet_lite0")
    run = network_runner(desc, 100, CompilePolicy())
    network_runner(desc, 100, CompilePolicy())  # the same package: queued once
    assert isinstance(run, compiled.Sliced)
    assert spawned == []  # nothing beside the job
    compiled.start_pending_builds()
    assert len(spawned) == 1
    argv = spawned[0]
    assert argv[1:3] == ["-m", "rhythmic_jax.frames.network_build"]
    spec = json.loads(argv[3])
    shape = (compiled.COMPILE_BATCH, 3, 112, 224)
    package = package_path(desc, shape)
    assert spec["package"] == str(package) and spec["shape"] == list(shape)
    assert spec["threads"] == torch.get_num_threads()
    assert get_descriptor(spec["name"], **spec["fields"]) == desc

    lock = package.with_suffix(".lock")
    package.parent.mkdir(parents=True)
    lock.write_text(f"{os.getpid()}\n")  # a builder at work: no second one
    _job(desc, 100)
    assert len(spawned) == 1
    lock.write_text(f"{_dead_pid()}\n")  # its builder was killed: start again
    _job(desc, 100)
    assert len(spawned) == 2
    lock.unlink()
    package.with_suffix(".failed").write_text("RuntimeError: no compiler\n")
    _job(desc, 100)  # failed before: not again
    assert len(spawned) == 2
    _job(desc, LOAD_MIN_FRAMES - 1)
    assert len(spawned) == 2


def test_damaged_package_is_deleted_never_loaded_and_rows_match(spawned, caplog):
    import zipfile

    desc = get_descriptor("efficientnet_lite0")
    package = package_path(desc, (compiled.COMPILE_BATCH, 3, 112, 224))
    package.parent.mkdir(parents=True)
    with zipfile.ZipFile(package, "w") as z:  # a package cut short mid-write
        z.writestr("model/data/weights", bytes(range(256)) * 400)
    whole = package.read_bytes()
    package.write_bytes(whole[: len(whole) // 2])
    frames = np.random.default_rng(0).integers(0, 256, (LOAD_MIN_FRAMES, 40, 80, 3))
    frames = frames.astype(np.uint8)
    with caplog.at_level(logging.WARNING, logger="rhythmic_jax.frames.compiled"):
        auto = describe(frames, desc, progress=False, compile=CompilePolicy())
    eager = describe(frames, desc, progress=False, compile=CompilePolicy("never"))
    np.testing.assert_array_equal(auto, eager)
    assert not package.exists()
    assert [r.getMessage() for r in caplog.records if "damaged" in r.getMessage()]
    compiled.start_pending_builds()
    assert len(spawned) == 1  # built again, in the background, after the job

    package.write_bytes(b"not a zip at all")  # a foreign file: the same
    assert not compiled.package_ready(package) and not package.exists()


@pytest.mark.slow
def test_builder_killed_mid_build_then_the_next_jobs_build_and_load(
    monkeypatch, tmp_path
):
    """A real background build killed mid-way leaves no package; the next job
    runs eagerly (same rows) and, once over, starts a builder that finishes; the
    job after runs compiled (rows within 1e-4). Minutes: two real builds may run."""
    import os
    import signal
    import time

    monkeypatch.delenv(compiled.BUILD_ENV, raising=False)
    desc = get_descriptor("efficientnet_lite0")
    shape = (compiled.COMPILE_BATCH, 3, 112, 224)
    package = package_path(desc, shape)
    frames = np.random.default_rng(1).integers(0, 256, (LOAD_MIN_FRAMES, 60, 120, 3))
    frames = frames.astype(np.uint8)
    eager = describe(frames, desc, progress=False, compile=CompilePolicy("never"))

    from rhythmic_jax.frames.compiled import start_build

    proc = start_build(desc, shape)
    lock = package.with_suffix(".lock")
    deadline = time.time() + 120
    while not lock.exists() and time.time() < deadline:
        time.sleep(0.2)
    time.sleep(5)  # into the export / code generation
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert not package.exists() and lock.exists()  # killed: a stale lock

    first = describe(frames, desc, progress=False, compile=CompilePolicy())
    np.testing.assert_array_equal(first, eager)  # eager; its build queued
    compiled.start_pending_builds()  # the job is over: the queued build starts
    deadline = time.time() + 900
    while not package.exists() and time.time() < deadline:
        time.sleep(2)
    while lock.exists() and time.time() < deadline:
        time.sleep(0.5)
    assert compiled.package_ready(package)
    compiled._compiled.cache_clear()
    second = describe(frames, desc, progress=False, compile=CompilePolicy())
    assert np.linalg.norm(second - eager, axis=1).max() < 1e-4
