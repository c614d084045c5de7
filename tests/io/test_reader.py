"""The one reader: pipes, devices and sockets refused unopened, names kept inside
their folder, sizes checked before anything is allocated, ``.h5`` data only from
the file itself; through the library, the command line and real processes.

Every case that could hang runs under an alarm (in this process) or a timeout (a
real process), so a regression fails instead of blocking the suite.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import shutil
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import zlib
from pathlib import Path

import numpy as np
import pytest
from skimage.io import imsave

from rhythmic_jax import RhythmicMap
from rhythmic_jax.app.cli import main
from rhythmic_jax.errors import InputError
from rhythmic_jax.eval.ground_truth_files import load_ground_truth
from rhythmic_jax.fitting.places import read_positions
from rhythmic_jax.frames.features import Hog
from rhythmic_jax.io import reader
from rhythmic_jax.io.vpr_files import read_hloc_descriptors

X = np.random.default_rng(0).normal(size=(40, 18)).astype(np.float32)
REPO = Path(__file__).resolve().parents[2]


@contextlib.contextmanager
def within(seconds: int = 20):
    """Fail (instead of hanging) when the block takes longer than ``seconds``."""

    def late(*_):
        raise TimeoutError(f"still running after {seconds} s")

    old = signal.signal(signal.SIGALRM, late)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def refused(call, *match: str) -> str:
    """``call()`` raises one-line InputError containing every ``match``."""
    with within(), pytest.raises(InputError) as err:
        call()
    line = str(err.value)
    assert "\n" not in line
    for m in match:
        assert m in line, line
    return line


# ---------------------------------------------------------------- odd file kinds


@pytest.fixture
def odd(tmp_path):
    """Paths that are not regular files, by kind (a socket in a short folder:
    AF_UNIX paths are limited to about 100 bytes)."""
    os.mkfifo(tmp_path / "fifo")
    (tmp_path / "fifo-link").symlink_to(tmp_path / "fifo")
    (tmp_path / "zero-link").symlink_to("/dev/zero")
    (tmp_path / "folder").mkdir()
    short = Path(tempfile.mkdtemp(prefix="rj"))
    sock = socket.socket(socket.AF_UNIX)
    sock.bind(str(short / "s"))
    yield {
        "fifo": (tmp_path / "fifo", "FIFO"),
        "link to a fifo": (tmp_path / "fifo-link", "FIFO"),
        "/dev/zero": (Path("/dev/zero"), "character device"),
        "/dev/null": (Path("/dev/null"), "character device"),
        "link to /dev/zero": (tmp_path / "zero-link", "character device"),
        "folder": (tmp_path / "folder", "folder"),
        "socket": (short / "s", "socket"),
    }
    sock.close()
    shutil.rmtree(short)


READS = {
    "open_regular": reader.open_regular,
    "read_bytes": reader.read_bytes,
    "read_json": reader.read_json,
    "npy_header": reader.npy_header,
    "load_npy": reader.load_npy,
    "npz_headers": reader.npz_headers,
    "open_h5": lambda p: reader.open_h5(p).__enter__(),
}


@pytest.mark.parametrize("read", sorted(READS))
def test_only_regular_files_are_read(odd, read):
    for path, kind in odd.values():
        refused(lambda p=path: READS[read](p), str(path), kind, "not a regular file")


def test_a_missing_file_is_named(tmp_path):
    refused(lambda: reader.read_bytes(tmp_path / "nope"), "nope: no such file")


# ------------------------------------------------------------ names in a folder


def test_names_stay_inside_their_folder(tmp_path):
    root = tmp_path / "map"
    (root / "sub").mkdir(parents=True)
    (root / "sub" / "a").write_text("a")
    (tmp_path / "secret").write_text("s")
    (root / "inner").symlink_to(root / "sub" / "a")
    (root / "outer").symlink_to(tmp_path / "secret")
    (root / "loop").symlink_to(root / "loop")
    assert reader.inside(root, "sub/a") == (root / "sub" / "a").resolve()
    assert reader.inside(root, "inner") == (root / "sub" / "a").resolve()
    assert reader.inside(root, "sub/../sub/a") == (root / "sub" / "a").resolve()
    refused(lambda: reader.inside(root, "../secret"), "'../secret'", "outside")
    refused(lambda: reader.inside(root, "../../../../etc/passwd"), "outside")
    refused(lambda: reader.inside(root, "/etc/passwd"), "absolute")
    refused(lambda: reader.inside(root, "outer"), "'outer'", "outside")
    refused(lambda: reader.inside(root, "loop"), "'loop'")
    refused(lambda: reader.inside(root, ""), "not a file name")


# ------------------------------------------------------------------ sizes: text


def test_json_is_bounded_in_size_and_depth(tmp_path):
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 10**5 + "]" * 10**5)
    refused(lambda: reader.read_json(deep, "metadata"), "corrupt metadata", "deep")
    just = tmp_path / "just.json"
    just.write_text("[" * reader.JSON_DEPTH + "]" * reader.JSON_DEPTH)
    assert reader.read_json(just) == eval("[" * reader.JSON_DEPTH + "]" * 64)  # noqa: S307
    over = tmp_path / "over.json"
    over.write_text("[" * 65 + "]" * 65)
    refused(lambda: reader.read_json(over), "nested over 64 deep")
    big = tmp_path / "big.json"
    big.write_text(json.dumps({"a": "x" * 5000}))
    assert reader.read_json(big)["a"] == "x" * 5000
    refused(lambda: reader.read_json(big, limit=4096), "more than the 4,096")


# ------------------------------------------------------------------- sizes: npy


def test_npy_sizes_are_checked_before_reading(tmp_path, monkeypatch):
    huge = tmp_path / "huge.npy"
    head = {"descr": "<f4", "fortran_order": False, "shape": (10**12, 4)}
    with open(huge, "wb") as f:
        np.lib.format.write_array_header_1_0(f, head)
        f.write(bytes(64))
    refused(lambda: reader.npy_header(huge), "truncated", "(1000000000000, 4)")
    assert reader.npy_header(huge, sizes=False).shape == (10**12, 4)
    ok = tmp_path / "ok.npy"
    np.save(ok, np.arange(4096, dtype=np.float32))
    np.testing.assert_array_equal(reader.load_npy(ok), np.arange(4096))
    monkeypatch.setenv("RHYTHMIC_JAX_MEMORY", "8K")
    refused(lambda: reader.load_npy(ok), "16,384 bytes", "RHYTHMIC_JAX_MEMORY")
    assert reader.load_npy(ok, mmap=True).shape == (4096,)  # maps, allocates nothing
    npz = tmp_path / "named.npy"
    np.savez(npz.with_suffix(".npz"), a=np.ones(3))
    npz.with_suffix(".npz").rename(npz)  # an .npz named .npy
    refused(lambda: reader.load_npy(npz), "not a valid .npy file")


def test_memory_budget(monkeypatch):
    monkeypatch.delenv("RHYTHMIC_JAX_MEMORY", raising=False)
    assert 0 < reader.memory_budget() <= reader.available_memory()
    for given, want in (("4G", 4 * 2**30), ("1024", 1024), ("1.5MiB", 3 * 2**19)):
        monkeypatch.setenv("RHYTHMIC_JAX_MEMORY", given)
        assert reader.memory_budget() == want
    monkeypatch.setenv("RHYTHMIC_JAX_MEMORY", "lots")
    refused(reader.memory_budget, "RHYTHMIC_JAX_MEMORY='lots'")


# ------------------------------------------------------------------- sizes: npz


def npz_bomb(path: Path, keys=("GThard", "GTsoft"), side=40_000, chunk=16_000_000):
    """A 3 MB ``.npz`` whose members, bool (side, side) each, declare and really
    inflate to 3.2 GB of False together, written at once: one deflated chunk of
    zeros, closed by a full flush so that it stands alone, repeated. Its CRCs are
    left zero: nothing that refuses it in time reads that far."""
    buf = io.BytesIO()
    shape = (side, side)
    np.lib.format.write_array_header_1_0(
        buf, {"descr": "|b1", "fortran_order": False, "shape": shape}
    )
    head, zeros = buf.getvalue(), side * side
    first = zlib.compressobj(9, zlib.DEFLATED, -15)
    data = first.compress(head + bytes(chunk)) + first.flush(zlib.Z_FULL_FLUSH)
    again = zlib.compressobj(9, zlib.DEFLATED, -15)
    body = again.compress(bytes(chunk)) + again.flush(zlib.Z_FULL_FLUSH)
    data += body * (zeros // chunk - 1) + b"\x03\x00"  # an empty final block
    members, central = b"", b""
    for key in keys:
        name = f"{key}.npy".encode()
        fields = (20, 0, 8, 0, 0x21, 0, len(data), len(head) + zeros, len(name))
        at = len(members)
        members += b"PK\x03\x04" + struct.pack("<HHHHHIIIHH", *fields, 0) + name + data
        central += b"PK\x01\x02" + struct.pack("<HHHHHHIIIHHHHHII", 20, *fields,
                                                 0, 0, 0, 0, 0, at) + name  # fmt: skip
    n = len(keys)
    end = struct.pack("<HHHHIIH", 0, 0, n, n, len(central), len(members), 0)
    path.write_bytes(members + central + b"PK\x05\x06" + end)
    return path


def test_an_npz_bomb_is_refused_before_inflating(tmp_path, monkeypatch):
    bomb = npz_bomb(tmp_path / "GT.npz")
    assert bomb.stat().st_size < 4e6
    heads = reader.npz_headers(bomb)
    assert heads["GThard"].shape == heads["GTsoft"].shape == (40_000, 40_000)
    assert heads["GThard"].nbytes + heads["GTsoft"].nbytes == 3_200_000_000
    refused(
        lambda: load_ground_truth(
            [str(bomb)], n_queries=5, n_places=7, query_source="q"
        ),
        "40000 database images and 40000 queries",
        "7 places",
    )
    monkeypatch.setenv("RHYTHMIC_JAX_MEMORY", "1G")
    refused(lambda: reader.load_npz(bomb), "3,200,000,000 bytes")


def test_a_refused_bomb_takes_little_memory(tmp_path):
    """Peak resident memory of a process refusing the 3.2 GB bomb (its shape
    would fit the map) with a budget below it, measured by the process itself
    (``VmHWM``: ``ru_maxrss`` would carry this test process's peak over exec)."""
    bomb = npz_bomb(tmp_path / "GT.npz")
    script = (
        "from rhythmic_jax.eval.ground_truth_files import load_ground_truth\n"
        "from rhythmic_jax.errors import InputError\n"
        "try:\n"
        f"    load_ground_truth([{str(bomb)!r}], n_queries=40000, n_places=40000,"
        " query_source='q')\n"
        "except InputError as err:\n"
        "    print(err)\n"
        "peak = open('/proc/self/status').read().split('VmHWM:')[1].split()[0]\n"
        "print(int(peak) * 1024)\n"
    )
    env = {**os.environ, "RHYTHMIC_JAX_MEMORY": "2G", "PYTHONPATH": str(REPO)}
    out = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, env=env,
        timeout=60,
    )  # fmt: skip
    lines = out.stdout.splitlines()
    assert "3,200,000,000 bytes" in lines[0], out
    assert int(lines[1]) < 2**30, lines  # well under: about 250 MB of imports


# ------------------------------------------------------------------------- HDF5


def test_h5_data_comes_from_the_file_itself(tmp_path):
    h5py = pytest.importorskip("h5py")
    rows = np.arange(16, dtype=np.float32).reshape(2, 8)
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f["data"] = rows[1]
        f.create_group("img1").create_dataset("global_descriptor", data=rows[1])
    raw = tmp_path / "raw.bin"
    raw.write_bytes(rows[1].tobytes())
    os.mkfifo(tmp_path / "pipe.bin")

    def hloc(name, add):
        path = tmp_path / f"{name}.h5"
        with h5py.File(path, "w") as f:
            f.create_group("img0").create_dataset("global_descriptor", data=rows[0])
            add(f)
        return path

    good = hloc(
        "good", lambda f: f.create_group("img1").create_dataset(
            "global_descriptor", data=rows[1]
        )
    )  # fmt: skip
    names, x = read_hloc_descriptors(good)
    assert names == ["img0", "img1"]
    np.testing.assert_array_equal(x, rows)

    def external(target):
        return lambda f: f.create_group("img1").create_dataset(
            "global_descriptor", shape=(8,), dtype="f4",
            external=[(str(target), 0, h5py.h5f.UNLIMITED)],
        )  # fmt: skip

    def link(f):
        f["img1"] = h5py.ExternalLink(str(other), "/img1")

    def virtual(f):
        layout = h5py.VirtualLayout(shape=(8,), dtype="f4")
        layout[:] = h5py.VirtualSource(str(other), "data", shape=(8,))
        f.create_group("img1").create_virtual_dataset("global_descriptor", layout)

    for name, add, why in [
        ("external", external(raw), "stored in another file"),
        ("external-pipe", external(tmp_path / "pipe.bin"), "stored in another file"),
        ("link", link, "external link into another file"),
        ("virtual", virtual, "a virtual dataset"),
    ]:
        path = hloc(name, add)
        refused(lambda p=path: read_hloc_descriptors(p), f"{name}.h5", why)


# ------------------------------------------------------------ positions (a CSV)


def test_a_positions_csv_from_a_spreadsheet_reads_as_the_clean_one(tmp_path):
    xy = np.random.default_rng(3).uniform(0, 500, (6, 2))
    rows = [f"{float(a)!r},{float(b)!r}" for a, b in xy]
    clean = tmp_path / "clean.csv"
    clean.write_text("easting,northing\n" + "\n".join(rows) + "\n")
    sheet = tmp_path / "sheet.csv"
    lines = ["easting,northing", *rows[:3], "", ",", *rows[3:], "", ""]
    sheet.write_bytes(b"\xef\xbb\xbf" + "\r\n".join(lines).encode())
    want, unit = read_positions(clean)
    got, got_unit = read_positions(sheet)
    assert unit == got_unit == "metres"
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(want, xy)
    gt = [
        load_ground_truth([str(ref), str(ref)], n_queries=6, n_places=6,
                          query_source="q").positives
        for ref in (clean, sheet)
    ]  # fmt: skip
    assert all(np.array_equal(a, b) for a, b in zip(*gt, strict=True))


# -------------------------------------------------------------- the command line


@pytest.fixture(scope="module")
def saved_map(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("reader")
    RhythmicMap().fit(X, progress=False).save(root / "npy.map")
    np.save(root / "q.npy", X[:3])
    return root / "npy.map"


@pytest.fixture(scope="module")
def tiled_map(tmp_path_factory) -> Path:
    """A map of 16-pixel 'hog' tiles of one image, ``source.png``, which the map
    names (evaluate reads it again for brute force): here a FIFO."""
    root = tmp_path_factory.mktemp("tiled")
    hog = Hog(width=16, height=8, pixels_per_cell=8, cells_per_block=1)
    model = RhythmicMap(descriptor="hog", descriptor_settings=hog.settings())
    model.fit(X, progress=False)
    model.reference = {"sources": [str(root / "source.png")], "tile": 16, "stride": 8}
    model.save(root / "tiled.map")
    os.mkfifo(root / "source.png")
    pixels = np.random.default_rng(1).integers(0, 256, (32, 40, 3), dtype=np.uint8)
    imsave(root / "q.png", pixels, check_contrast=False)
    return root / "tiled.map"


def _copy(saved: Path, tmp_path: Path) -> Path:
    dst = tmp_path / "copy.map"
    shutil.copytree(saved, dst)
    return dst


def _meta(folder: Path, edit) -> Path:
    meta = json.loads((folder / "map.json").read_text())
    edit(meta)
    (folder / "map.json").write_text(json.dumps(meta))
    return folder


def _climbing(folder: Path) -> Path:
    """Its digests name a file outside the map, with that file's right sha256."""
    secret = folder.parent / "secret.txt"
    secret.write_text("not the map's")
    files = {"../../secret.txt": hashlib.sha256(secret.read_bytes()).hexdigest()}
    return _meta(folder, lambda m: m["digests"]["sha256"]["files"].update(files))


def _absolute(folder: Path) -> Path:
    path = str(folder / "arrays" / "_METADATA")
    digest = hashlib.sha256(Path(path).read_bytes()).hexdigest()
    return _meta(
        folder, lambda m: m["digests"]["sha256"]["files"].update({path: digest})
    )


def _deep(folder: Path) -> Path:
    (folder / "map.json").write_text("[" * 10**5 + "]" * 10**5)
    return folder


def _swap(folder: Path, name: str, make) -> Path:
    path = folder / name
    path.unlink()
    make(path)
    return folder


MAP_CASES = {
    "map.json a fifo": (lambda f: _swap(f, "map.json", os.mkfifo), "FIFO"),
    "map.json to /dev/zero": (
        lambda f: _swap(f, "map.json", lambda p: p.symlink_to("/dev/zero")),
        "'map.json' leads outside",
    ),
    "map.json leaving": (
        lambda f: _swap(f, "map.json", lambda p: p.symlink_to(f.parent / "other.json")),
        "outside",
    ),
    "array file a fifo": (
        lambda f: _swap(f, "arrays/_METADATA", os.mkfifo),
        "arrays are missing or corrupt",
    ),
    "array file to /dev/zero": (
        lambda f: _swap(
            f, "arrays/manifest.ocdbt", lambda p: p.symlink_to("/dev/zero")
        ),
        "'manifest.ocdbt' leads outside",
    ),
    "digest path climbing out": (_climbing, "'../../secret.txt' leads outside"),
    "digest path absolute": (_absolute, "is absolute"),
    "map.json deep": (_deep, "nested too deep"),
}


def _one_line(argv: list[str], capsys, *match: str) -> None:
    capsys.readouterr()
    with within(30):
        code = main(argv)
    err = capsys.readouterr().err.splitlines()
    assert code == 2 and len(err) == 1, err
    for m in match:
        assert m in err[0], err[0]


@pytest.mark.parametrize("case", sorted(MAP_CASES))
def test_a_damaged_map_folder_ends_in_one_line(case, saved_map, tmp_path, capsys):
    damage, match = MAP_CASES[case]
    (tmp_path / "other.json").write_text((saved_map / "map.json").read_text())
    folder = damage(_copy(saved_map, tmp_path))
    _one_line(["info", str(folder)], capsys, match)
    q = str(saved_map.parent / "q.npy")
    out = str(tmp_path / "p.npy")
    _one_line(["query", str(folder), q, "--out", out, "--no-progress"], capsys, match)
    assert not Path(out).exists()


def test_pipes_and_devices_as_sources_end_in_one_line(
    saved_map, tiled_map, tmp_path, capsys
):
    os.mkfifo(tmp_path / "q.npy")
    (tmp_path / "zero.npy").symlink_to("/dev/zero")
    os.mkfifo(tmp_path / "q.h5")
    (tmp_path / "big.png").symlink_to("/dev/zero")
    os.mkfifo(tmp_path / "gt.npz")
    (tmp_path / "pos.csv").symlink_to("/dev/zero")
    query = ["query", str(saved_map)]
    more = ["--out", str(tmp_path / "p.npy"), "--no-progress"]
    for name in ("q.npy", "zero.npy", "q.h5"):
        _one_line([*query, str(tmp_path / name), *more], capsys, name, "not a regular")
    tiled = ["query", str(tiled_map), str(tmp_path / "big.png"), "--tile", "16"]
    _one_line([*tiled, *more], capsys, "big.png", "character device")
    q = str(tiled_map.parent / "q.png")  # brute force reads the map's source, a FIFO
    _one_line(["evaluate", str(tiled_map), q, "--no-progress"], capsys,
              "source.png", "FIFO")  # fmt: skip
    _one_line(["fit", str(tmp_path / "zero.npy"), "--out", str(tmp_path / "m.map"),
               "--no-progress"], capsys, "zero.npy", "character device")  # fmt: skip
    q = str(saved_map.parent / "q.npy")
    for gt in (["gt.npz"], ["pos.csv", "pos.csv"]):
        files = [str(tmp_path / g) for g in gt]
        argv = ["evaluate", str(saved_map), q, "--ground-truth", *files]
        _one_line([*argv, "--no-progress"], capsys, gt[0], "not a regular file")


def test_real_processes_end_at_once_on_pipes_and_devices(saved_map, tmp_path):
    """A FIFO as map.json, /dev/zero as a descriptor file, a FIFO as ground
    truth: each process exits 2 with one line, well within 30 s."""
    folder = _swap(_copy(saved_map, tmp_path), "map.json", os.mkfifo)
    os.mkfifo(tmp_path / "gt.npz")
    q = str(saved_map.parent / "q.npy")
    cli = [sys.executable, "-m", "rhythmic_jax.app.cli"]
    gt, zero = str(tmp_path / "gt.npz"), tmp_path / "zero.npy"
    zero.symlink_to("/dev/zero")
    runs = [
        ["info", str(folder)],
        ["query", str(saved_map), str(zero), "--out", str(tmp_path / "p.npy")],
        ["evaluate", str(saved_map), q, "--ground-truth", gt, "--no-progress"],
    ]
    env = {**os.environ, "PYTHONPATH": str(REPO), "JAX_PLATFORMS": "cpu"}
    procs = [
        subprocess.Popen([*cli, *argv], stderr=subprocess.PIPE, env=env)
        for argv in runs
    ]
    for argv, proc in zip(runs, procs, strict=True):
        try:
            err = proc.communicate(timeout=30)[1]
        except subprocess.TimeoutExpired:
            proc.kill()
            raise
        lines = err.decode().splitlines()
        assert proc.returncode == 2, (argv, lines)
        assert len(lines) == 1 and "not a regular file" in lines[0], lines


def test_a_map_without_digests_is_still_checked_before_orbax_reads_it(
    saved_map, tmp_path, capsys
):
    """A map saved before digests existed has no sha256 to check its files
    against: what orbax would read must still be regular files inside it."""
    folder = _meta(_copy(saved_map, tmp_path), lambda m: m.pop("digests"))
    q, out = str(saved_map.parent / "q.npy"), str(tmp_path / "p.npy")
    argv = ["query", str(folder), q, "--out", out, "--no-progress"]
    assert main(argv) == 0  # the old map loads
    _swap(folder, "arrays/manifest.ocdbt", os.mkfifo)
    _one_line(argv, capsys, "arrays are missing or corrupt", "not a regular file")
    _swap(folder, "arrays/manifest.ocdbt", lambda p: p.symlink_to("/dev/zero"))
    _one_line(argv, capsys, "'manifest.ocdbt' leads outside")


def test_a_tiled_pair_stays_inside_its_folders(tmp_path):
    from rhythmic_jax.io.tiles import load_aerial_route

    pixels = np.random.default_rng(2).integers(0, 256, (32, 32, 3), dtype=np.uint8)
    for side in ("A", "B"):
        (tmp_path / "pair" / side).mkdir(parents=True)
    imsave(tmp_path / "pair" / "A" / "x.png", pixels, check_contrast=False)
    imsave(tmp_path / "elsewhere.png", pixels, check_contrast=False)
    (tmp_path / "pair" / "B" / "x.png").symlink_to(tmp_path / "elsewhere.png")
    refused(lambda: load_aerial_route(tmp_path / "pair", 16, 16), "'x.png' leads out")
    (tmp_path / "pair" / "B" / "x.png").unlink()
    imsave(tmp_path / "pair" / "B" / "x.png", pixels, check_contrast=False)
    route = load_aerial_route(tmp_path / "pair", 16, 16)
    assert len(route) == 4
    np.testing.assert_array_equal(route.map_tiles, route.query_tiles)


def test_a_weights_file_that_is_a_pipe_is_named_so(odd):
    from rhythmic_jax.frames.weights import resolve_weights

    for path, kind in odd.values():
        if kind != "folder":
            refused(lambda p=path: resolve_weights("VGG16", str(p)), str(path), kind)


def test_a_map_is_refused_before_orbax_allocates_more_than_the_budget(
    saved_map, monkeypatch
):
    from rhythmic_jax.io.checkpoint import load_map

    arrays, _ = load_map(saved_map)
    need = sum(a.nbytes for a in arrays.values())
    monkeypatch.setenv("RHYTHMIC_JAX_MEMORY", str(need - 1))
    refused(lambda: load_map(saved_map), f"arrays would take {need:,} bytes")
    monkeypatch.setenv("RHYTHMIC_JAX_MEMORY", str(need))
    assert sorted(load_map(saved_map)[0]) == sorted(arrays)
