"""Every output's place is checked before any work, a failed write ends in one
line, and a cancelled job puts nothing in place.

Faults are injected in-process: a probe file that cannot be written (a read-only
or full place), and each output's writer raising the ``OSError`` a full or
read-only disk raises. The command line must end with status 2 and one line
naming the output, leave nothing at the output's path, and a rerun must work.
"""

from __future__ import annotations

import errno
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from rhythmic_jax.app.cli import main
from rhythmic_jax.errors import InputError
from rhythmic_jax.io import outputs

ENOSPC = OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def _one_line(capsys, *words: str) -> str:
    """The one line a refusal says on stderr: its error (a job's notes and
    warnings are said only once it has succeeded)."""
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1, err
    assert ": error: " in err[0], err
    for word in words:
        assert word in err[0], err
    return err[0]


def _hidden(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


# ----------------------------------------------------------------- the pieces
def test_a_writable_place_passes_and_keeps_no_probe(tmp_path):
    assert outputs.check_place("out", tmp_path / "new" / "x.map") == (
        tmp_path / "new" / "x.map"
    )
    assert list(tmp_path.iterdir()) == []  # nothing made, nothing left


@pytest.mark.parametrize("code", [errno.EROFS, errno.ENOSPC, errno.EACCES])
def test_a_place_that_takes_no_file_is_refused_in_one_line(tmp_path, monkeypatch, code):
    def refused(dir=None, prefix=None):
        raise OSError(code, os.strerror(code), str(dir))

    monkeypatch.setattr(outputs.tempfile, "mkstemp", refused)
    with pytest.raises(InputError) as err:
        outputs.check_place("plot", tmp_path / "pr.png")
    assert str(err.value) == (
        f"plot {tmp_path / 'pr.png'}: cannot write in {tmp_path} ({os.strerror(code)})"
    )
    assert err.value.as_flag().startswith("--plot ")


def test_a_probe_write_that_fails_is_refused_and_removed(tmp_path, monkeypatch):
    """A full disk takes a new, empty file but not its first byte."""
    real = os.write

    def full(fd, data):
        if os.readlink(f"/proc/self/fd/{fd}").startswith(str(tmp_path)):
            raise ENOSPC
        return real(fd, data)

    if not Path("/proc/self/fd").is_dir():
        pytest.skip("needs /proc")
    monkeypatch.setattr(outputs.os, "write", full)
    with pytest.raises(InputError, match="No space left on device"):
        outputs.check_place("out", tmp_path / "x.map")
    monkeypatch.undo()
    assert list(tmp_path.iterdir()) == []


def test_an_existing_checkpoint_folder_is_probed_inside(tmp_path, monkeypatch):
    ckpt = tmp_path / "route.ckpt"
    ckpt.mkdir()
    real = outputs.tempfile.mkstemp

    def inside_refused(dir=None, prefix=None):
        if Path(dir) == ckpt:
            raise OSError(errno.EACCES, os.strerror(errno.EACCES), str(dir))
        return real(dir=dir, prefix=prefix)

    monkeypatch.setattr(outputs.tempfile, "mkstemp", inside_refused)
    outputs.check_place("checkpoint", ckpt)  # only its folder
    with pytest.raises(InputError, match=f"cannot write in {ckpt} "):
        outputs.check_place("checkpoint", ckpt, inside=True)


def test_a_place_under_a_file_is_refused(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(InputError, match="is a file, not a folder"):
        outputs.check_place("shards", tmp_path / "f" / "sub" / "shards")
    # a folder written into: a file at its own place is refused, nothing probed
    with pytest.raises(InputError, match=r"^out .*/f: a file, not a folder$"):
        outputs.check_place("out", tmp_path / "f", inside=True)
    assert (tmp_path / "f").read_text() == "x"


@pytest.mark.parametrize(
    "err",
    [
        OSError(errno.ENOSPC, "No space left on device"),  # a write to an open file
        OSError(errno.EROFS, "Read-only file system", "OUT/arrays/x"),
        OSError(errno.EACCES, "Permission denied", "DIR/.x.map.tmp-1234/map.json"),
        ValueError(
            'RESOURCE_EXHAUSTED: Failed writing "OUT/d/1": No space left on '
            "device [os_error_code='28']"
        ),  # fmt: skip
        OSError("245760 requested and 9184 written"),  # numpy's short write
    ],
    ids=["open-file", "inside", "temporary", "tensorstore", "short-write"],
)
def test_write_errors_of_the_output_are_one_line(tmp_path, err):
    out = tmp_path / "x.map"
    if isinstance(err, OSError) and err.filename:
        name = err.filename.replace("OUT", str(out)).replace("DIR", str(tmp_path))
        err = OSError(err.errno, err.strerror, name)
    with pytest.raises(InputError) as got:
        with outputs.write_errors("out", out):
            raise err
    assert str(got.value).startswith(f"out {out}: could not write it (")
    assert "\n" not in str(got.value)


@pytest.mark.parametrize(
    "err",
    [
        OSError(errno.ENOENT, "No such file or directory", "/data/frames/1.png"),
        OSError(errno.EACCES, "Permission denied", "/data/frames/1.png"),
        ValueError("weights of shape (3, 4) do not fit"),
    ],
    ids=["missing-input", "unreadable-input", "other"],
)
def test_other_errors_pass_through(tmp_path, err):
    with pytest.raises(type(err)) as got:
        with outputs.write_errors("out", tmp_path / "x.map"):
            raise err
    assert got.value is err


def test_a_staged_folder_appears_whole_or_not_at_all(tmp_path):
    root = tmp_path / "route.shards"
    with outputs.staged_folder(root) as staged:
        (staged / "00-a").mkdir()
        assert not root.exists()
    assert (root / "00-a").is_dir()
    assert _hidden(tmp_path) == []

    with pytest.raises(OSError), outputs.staged_folder(tmp_path / "b") as staged:
        (staged / "half").write_text("x")
        raise ENOSPC
    assert list(tmp_path.iterdir()) == [root]


def test_a_staged_folder_of_a_gone_process_is_removed_and_a_live_ones_kept(tmp_path):
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)  # fmt: skip
    dead = tmp_path / f".r.tmp-{gone.stdout.strip()}-0a1b2c3d"
    live = tmp_path / f".r.tmp-{os.getppid()}-0a1b2c3d"
    for folder in (dead, live):
        (folder / "00-a").mkdir(parents=True)
    with outputs.staged_folder(tmp_path / "r"):
        pass
    assert _hidden(tmp_path) == [live.name]
    assert (tmp_path / "r").is_dir()


CANCEL = """
import sys, threading, time
from pathlib import Path
from rhythmic_jax.io import atomic, outputs

folder = Path(sys.argv[1])
atomic.write_file(folder / "before.txt", "kept")
held, done = threading.Event(), []

def rename_under_way():
    with outputs.committing():
        held.set()
        time.sleep(0.3)
        done.append(time.monotonic())

threading.Thread(target=rename_under_way).start()
held.wait()
outputs.cancel()
print("waited", time.monotonic() >= done[0])
try:
    atomic.write_file(folder / "after.txt", "x")
except outputs.Cancelled:
    print("refused")
"""


def test_once_cancelled_nothing_is_put_in_place(tmp_path):
    """A rename under way finishes first; every later one is refused, and its
    temporary file removed (a process of its own: the flag is for good)."""
    script = tmp_path / "cancel.py"
    script.write_text(textwrap.dedent(CANCEL))
    folder = tmp_path / "out"
    folder.mkdir()
    got = subprocess.run([sys.executable, str(script), str(folder)],
                         capture_output=True, text=True, timeout=60)  # fmt: skip
    assert got.stdout.split() == ["waited", "True", "refused"], got.stderr
    assert sorted(p.name for p in folder.iterdir()) == ["before.txt"]


# ------------------------------------------------------- each output, end to end
@pytest.fixture(scope="module")
def route(tmp_path_factory):
    """Descriptor files, an image folder and a map fitted on the descriptors."""
    root = tmp_path_factory.mktemp("route")
    rng = np.random.default_rng(0)
    x = rng.normal(size=(40, 16)).astype(np.float32)
    np.save(root / "ref.npy", x)
    np.save(root / "other.npy", x + 0.1 * rng.normal(size=x.shape).astype(np.float32))
    (root / "frames").mkdir()
    for i in range(12):
        pixels = rng.integers(0, 256, (16, 24, 3), dtype=np.uint8)
        Image.fromarray(pixels).save(root / "frames" / f"{i:02d}.png")
    assert main(["fit", str(root / "ref.npy"), "--out", str(root / "m.map"),
                 "--no-progress"]) == 0  # fmt: skip
    return root


def _fail(monkeypatch, target: str, err: BaseException):
    def raise_it(*args, **kwargs):
        raise err

    monkeypatch.setattr(target, raise_it)


def _enospc(path: Path) -> OSError:
    return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))


def test_every_output_on_a_read_only_place_is_refused_before_any_work(
    route, tmp_path, monkeypatch, capsys
):
    real = outputs.tempfile.mkstemp
    ro, ref, m = tmp_path / "ro", str(route / "ref.npy"), str(route / "m.map")

    def read_only(dir=None, prefix=None):
        if Path(dir) == ro:
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(dir))
        return real(dir=dir, prefix=prefix)

    _fail(monkeypatch, "rhythmic_jax.frames.sources.load_sources", AssertionError())
    _fail(monkeypatch, "rhythmic_jax.map.map_file.load", AssertionError())
    monkeypatch.setattr(outputs.tempfile, "mkstemp", read_only)
    runs = {
        "--out": ["fit", ref, "--out", f"{ro}/x.map"],
        "--checkpoint": ["fit", str(route / "frames"), "--out", str(tmp_path / "y"),
                         "--augment", "hflip", "--checkpoint", f"{ro}/ck"],
        "--shards": ["fit", str(route / "frames"), "--out", str(tmp_path / "y"),
                     "--shards", f"{ro}/sh"],
        "--plot": ["evaluate", m, ref, "--plot", f"{ro}/pr.png"],
    }  # fmt: skip
    runs["learn --out"] = ["learn", ref, ref, "--out", f"{ro}/e.emb"]
    runs["query --out"] = ["query", m, ref, "--out", f"{ro}/p.npy"]
    ro.mkdir()
    for flag, argv in runs.items():
        assert main([*argv, "--no-progress"]) == 2, flag
        _one_line(capsys, flag.split()[-1], "Read-only file system")
    assert list(ro.iterdir()) == []


def test_fit_out_that_fails_to_write_is_one_line(route, tmp_path, monkeypatch, capsys):
    out = tmp_path / "x.map"
    err = OSError(errno.EROFS, os.strerror(errno.EROFS), str(tmp_path / ".x.map.t"))
    _fail(monkeypatch, "rhythmic_jax.map.map_file.save", err)
    argv = ["fit", str(route / "ref.npy"), "--out", str(out), "--no-progress"]
    assert main(argv) == 2
    _one_line(capsys, f"--out {out}: could not write it (Read-only file system)")
    assert not out.exists()


def test_learn_out_that_fails_to_write_is_one_line(
    route, tmp_path, monkeypatch, capsys
):
    out = tmp_path / "e.emb"
    _fail(monkeypatch, "rhythmic_jax.map.embedding.save_embedding",
          _enospc(out / "arrays"))  # fmt: skip
    argv = ["learn", str(route / "ref.npy"), str(route / "other.npy"), "--out",
            str(out), "--k", "8", "--no-progress"]  # fmt: skip
    assert main(argv) == 2
    _one_line(capsys, f"--out {out}: could not write it (No space left on device)")
    assert not out.exists()


@pytest.mark.parametrize("flag", ["--out", "--plot"])
def test_query_out_and_evaluate_plot_that_fail_to_write_are_one_line(
    route, tmp_path, monkeypatch, capsys, flag
):
    """fsync fails (a full disk): no file, no temporary left."""
    _fail(monkeypatch, "rhythmic_jax.io.atomic.os.fsync", ENOSPC)
    out = tmp_path / ("p.npy" if flag == "--out" else "pr.png")
    command = "query" if flag == "--out" else "evaluate"
    argv = [command, str(route / "m.map"), str(route / "ref.npy"), flag, str(out),
            "--no-progress"]  # fmt: skip
    assert main(argv) == 2
    _one_line(capsys, f"{flag} {out}: could not write it (No space left on device)")
    assert list(tmp_path.iterdir()) == []


def test_checkpoint_that_fails_to_write_is_one_line(
    route, tmp_path, monkeypatch, capsys
):
    ckpt = tmp_path / "ck"
    _fail(monkeypatch, "rhythmic_jax.fitting.scale_fit.fit_map_files",
          _enospc(ckpt / "stream-0-of-1.npz"))  # fmt: skip
    argv = ["fit", str(route / "ref.npy"), "--out", str(tmp_path / "x.map"),
            "--memory", "1GiB", "--checkpoint", str(ckpt), "--no-progress"]  # fmt: skip
    assert main(argv) == 2
    _one_line(capsys, f"--checkpoint {ckpt}: could not write it (No space left")

    _fail(monkeypatch, "rhythmic_jax.augment.stream.fit_augmented",
          _enospc(ckpt / "3" / "state"))  # fmt: skip
    argv = ["fit", str(route / "frames"), "--out", str(tmp_path / "x.map"),
            "--augment", "hflip", "--checkpoint", str(ckpt),
            "--no-progress"]  # fmt: skip
    assert main(argv) == 2
    _one_line(capsys, f"--checkpoint {ckpt}: could not write it (No space left")
    assert not (tmp_path / "x.map").exists()


def test_shards_that_fail_to_write_leave_nothing_that_blocks_a_rerun(
    route, tmp_path, monkeypatch, capsys
):
    from rhythmic_jax.frames import describe_shards

    real = describe_shards.describe_to_shards

    def fills_the_disk(folder, out, *args, **kwargs):
        Path(out).mkdir(parents=True)
        (Path(out) / "shard-000000.npy").write_bytes(b"half")
        raise _enospc(Path(out) / "shard-000001.npy")

    shards, out = tmp_path / "route.shards", tmp_path / "x.map"
    argv = ["fit", str(route / "frames"), "--out", str(out), "--shards", str(shards),
            "--no-progress"]  # fmt: skip
    monkeypatch.setattr(describe_shards, "describe_to_shards", fills_the_disk)
    assert main(argv) == 2
    _one_line(capsys, f"--shards {shards}: could not write it (No space left")
    assert list(tmp_path.iterdir()) == []

    monkeypatch.setattr(describe_shards, "describe_to_shards", real)
    assert main(argv) == 0  # the rerun is not refused
    assert sorted(p.name for p in shards.iterdir()) == ["00-frames", "shards.json"]
    assert out.is_dir()
    capsys.readouterr()

    # a fit that failed after describing: the same command takes the shards
    _fail(monkeypatch, "rhythmic_jax.frames.describe_shards.describe_to_shards",
          AssertionError("described again"))  # fmt: skip
    assert main(argv) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["route.shards", "x.map"]
    capsys.readouterr()  # the fit's notes on its map

    # other images, or a folder this command did not finish: refused
    other = tmp_path / "other" / "frames"
    shutil.copytree(route / "frames", other)
    (other / "11.png").unlink()
    assert main([argv[0], str(other), *argv[2:]]) == 2
    _one_line(capsys, f"--shards {shards}: holds the shards of other images")
    (shards / "shards.json").unlink()
    assert main(argv) == 2
    _one_line(capsys, f"--shards {shards}: exists and holds no shards that a finished")


CANCEL_MAP = """
import sys
import numpy as np
from pathlib import Path
from rhythmic_jax.io import checkpoint, outputs

target = Path(sys.argv[1]) / "m.map"
checkpoint.save_map(target, {"w": np.ones((3, 2), np.float32)}, {"kind": "first"})
outputs.cancel()
try:
    checkpoint.save_map(target, {"w": np.zeros((3, 2), np.float32)}, {"kind": "new"})
except outputs.Cancelled:
    print("refused")
arrays, meta = checkpoint.load_map(target)
print(meta["kind"], float(arrays["w"].sum()))
"""


def test_a_cancelled_job_puts_no_map_in_place(tmp_path):
    """A map's folder is renamed into place under the same commit lock as every
    other output: once cancelled, the save is refused, the previous map stays
    whole and no temporary folder is left."""
    script = tmp_path / "cancel_map.py"
    script.write_text(textwrap.dedent(CANCEL_MAP))
    got = subprocess.run([sys.executable, str(script), str(tmp_path)],
                         capture_output=True, text=True, timeout=120)  # fmt: skip
    assert got.stdout.split() == ["refused", "first", "6.0"], got.stderr
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".m.map")] == []


# ------------------------------------------------ what a file output's path names
def test_output_target_names_files_devices_streams_and_links(tmp_path):
    (tmp_path / "f.txt").write_text("x")
    (tmp_path / "to-f").symlink_to("f.txt")
    (tmp_path / "to-null").symlink_to(os.devnull)
    (tmp_path / "loop").symlink_to("loop")
    target = outputs.output_target
    assert target(tmp_path / "new.npy").kind == "file"
    assert target(tmp_path / "to-f").path == tmp_path / "f.txt"
    assert target(tmp_path / "to-null").kind == "device"
    assert target("/dev/stdout") == outputs.Target(
        Path("/dev/stdout"), Path("/proc/self/fd/1"), "stream", 1
    )
    assert target("/dev/fd/2").fd == 2
    with pytest.raises(outputs.OutputError, match="too many levels of links"):
        target(tmp_path / "loop")
    with pytest.raises(outputs.OutputError, match="is a folder"):
        target(tmp_path)


def test_check_place_of_a_file_refuses_a_folder_and_checks_a_device(tmp_path):
    (tmp_path / "pr.png").mkdir()
    with pytest.raises(InputError) as err:
        outputs.check_place("plot", tmp_path / "pr.png", file=True)
    assert err.value.as_flag() == (
        f"--plot {tmp_path / 'pr.png'}: is a folder; give a file name"
    )
    outputs.check_place("plot", tmp_path / "pr.png")  # a folder output: taken
    assert outputs.check_place("out", os.devnull, file=True) == Path(os.devnull)
    assert list((tmp_path / "pr.png").iterdir()) == []


def test_a_closed_stream_is_refused_before_work():
    read, write = os.pipe()
    os.close(write)
    try:
        with pytest.raises(InputError, match=f"descriptor {write} is closed"):
            outputs.check_place("out", f"/dev/fd/{write}", file=True)
    finally:
        os.close(read)


def test_a_failed_write_through_names_the_option(tmp_path):
    with pytest.raises(InputError) as err:
        with outputs.write_errors("out", "/dev/full"):
            raise outputs.OutputError(
                Path("/dev/full"), "could not write it (No space left on device)"
            )
    assert err.value.as_flag() == (
        "--out /dev/full: could not write it (No space left on device)"
    )


def test_file_outputs_go_through_devices_and_folders_are_refused_before_work(
    route, tmp_path, monkeypatch, capsys
):
    """query --out /dev/null writes through (the device stays one); evaluate
    --plot and frontier --csv naming a folder are refused before any map or
    frame is read."""
    null = os.stat(os.devnull)
    m, ref = str(route / "m.map"), str(route / "ref.npy")
    assert main(["query", m, ref, "--out", os.devnull, "--no-progress"]) == 0
    assert os.stat(os.devnull).st_mode == null.st_mode
    assert os.stat(os.devnull).st_rdev == null.st_rdev
    capsys.readouterr()
    folder = tmp_path / "pr.png"
    folder.mkdir()
    _fail(monkeypatch, "rhythmic_jax.map.map_file.load", AssertionError())
    _fail(monkeypatch, "rhythmic_jax.app.frontier.frontier", AssertionError())
    assert main(["evaluate", m, ref, "--plot", str(folder), "--no-progress"]) == 2
    _one_line(capsys, f"--plot {folder}: is a folder; give a file name")
    assert main(["query", m, ref, "--out", str(folder), "--no-progress"]) == 2
    _one_line(capsys, f"--out {folder}: is a folder")
    argv = ["frontier", ref, ref, "--csv", str(folder), "--no-progress"]
    assert main(argv) == 2
    _one_line(capsys, f"--csv {folder}: is a folder; give a file name")
    assert list(folder.iterdir()) == []


def test_a_full_device_is_one_line_after_the_work(route, capsys):
    if not Path("/dev/full").exists():
        pytest.skip("needs /dev/full")
    argv = ["query", str(route / "m.map"), str(route / "ref.npy"), "--out",
            "/dev/full", "--no-progress"]  # fmt: skip
    assert main(argv) == 2
    _one_line(capsys, "--out /dev/full: could not write it (No space left on device)")


def test_fit_out_a_link_to_a_map_replaces_that_map_and_leaves_nothing(
    route, tmp_path, capsys
):
    """The map the link names is replaced (the link kept, as a write through a
    link to a file), with no hidden backup left beside either."""
    from rhythmic_jax.io.checkpoint import read_metadata

    shutil.copytree(route / "m.map", tmp_path / "other.map")
    (tmp_path / "link.map").symlink_to("other.map")
    before = read_metadata(tmp_path / "other.map")[1]
    argv = ["fit", str(route / "other.npy"), "--out", str(tmp_path / "link.map"),
            "--no-progress"]  # fmt: skip
    assert main(argv) == 0
    assert (tmp_path / "link.map").is_symlink()
    after = read_metadata(tmp_path / "other.map")[1]
    assert after["digests"] != before["digests"]  # the new map, in the old place
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link.map", "other.map"]
