"""A compiled package's path names its settings; one builder holds its lock, and a
stale lock (its builder gone) is taken over."""

from __future__ import annotations

import subprocess

from rhythmic_jax.frames.features import get_descriptor
from rhythmic_jax.frames.package_builds import lock_held, package_path, take_lock


def _dead_pid() -> int:
    proc = subprocess.Popen(["true"])
    proc.wait()
    return proc.pid


def test_package_path_names_the_settings(tmp_path):
    a = get_descriptor("efficientnet_lite0")
    b = get_descriptor("efficientnet_lite0", block=9)
    shape = (8, 3, 112, 224)
    assert package_path(a, shape, tmp_path).parent == tmp_path / "compiled"
    assert package_path(a, shape, tmp_path) == package_path(a, shape, tmp_path)
    assert package_path(a, shape, tmp_path) != package_path(b, shape, tmp_path)
    assert package_path(a, shape, tmp_path) != package_path(a, (64, *shape[1:]))


def test_builder_lock_is_exclusive_and_taken_over_when_stale(tmp_path):
    lock = tmp_path / "net.lock"
    assert take_lock(lock) and lock_held(lock)
    assert not take_lock(lock)
    lock.write_text(f"{_dead_pid()}\n")
    assert not lock_held(lock)
    assert take_lock(lock) and lock_held(lock)
    lock.write_text("")
    assert not lock_held(lock)


def test_queued_builds_start_once_when_the_jobs_are_over_and_never_after_a_failure(
    tmp_path, monkeypatch
):
    import atexit
    import json

    from rhythmic_jax.frames import package_builds

    started = []

    def spawn(argv):  # recorded, not started
        started.append(argv)
        return argv

    monkeypatch.setattr(package_builds, "_spawn", spawn)
    monkeypatch.setattr(package_builds, "_PENDING", {})
    monkeypatch.setattr(atexit, "register", lambda fn: fn)  # no build at exit
    desc, shape = get_descriptor("patchnorm"), (8, 3, 32, 64)
    package_builds.build_after_jobs(desc, shape, tmp_path)
    package_builds.build_after_jobs(desc, shape, tmp_path)  # the same: queued once
    assert started == []
    assert len(package_builds.start_pending_builds()) == len(started) == 1
    argv = started[0]
    assert argv[1:3] == ["-m", "rhythmic_jax.frames.network_build"]
    spec = json.loads(argv[3])
    package = package_path(desc, shape, tmp_path)
    assert spec["package"] == str(package) and spec["cache_dir"] == str(tmp_path)
    assert spec["fields"] == {"width": 64, "height": 32, "patch": 8}
    assert package_builds.start_pending_builds() == []  # the queue is empty
    package.parent.mkdir(parents=True)
    package_builds.failed_path(package).write_text("RuntimeError: no compiler\n")
    package_builds.build_after_jobs(desc, shape, tmp_path)
    assert package_builds.start_pending_builds() == [] and len(started) == 1
