"""Files from others, mutated: a valid map folder and valid data files changed
one way at a time, each outcome the original answer or one line and exit 2.

A small map is fitted once (40 x 8 reference frames) and queried by 12 frames
near its first 12. Hypothesis then mutates a copy of its folder (a field of
``map.json`` deleted, retyped, made huge, negative, NaN or deeply nested; a
byte of an array file; a file renamed, swapped, linked or replaced by a
folder; an array's values changed with the digests recomputed), or a valid
Patch-NetVLAD ground truth, positions CSV or hloc ``.h5`` file, and runs the
command in this process (:func:`rhythmic_jax.app.cli.main`). Every outcome is
the original answer (exit 0, the unmutated map's predictions), or, where the
mutation changes what the file means (a decode setting, an array's values with
their digests recomputed, a data file), a well-formed answer; else exactly one
``rhythmic-jax CMD: error:`` line and exit 2: never a traceback, within 30 s
and with the process's peak memory grown by less than 1 GiB. A few mutations
also run the installed command in a subprocess under an address-space limit.

Mutations that can block or exhaust memory (a FIFO, a link to ``/dev/zero``,
an ``.h5`` dataset stored outside its file) run only in subprocesses, under
the slow marker; they need every read to pass one reader (regular files only,
names inside their folder, sizes checked first) and are expected to fail until
then.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from rhythmic_jax.app.cli import main
from rhythmic_jax.io.checkpoint import load_map, save_map

N, D, B = 40, 8, 12
TIMEOUT_S = 30
GIB = 2**30
FAST = settings(
    max_examples=25,
    deadline=None,
    database=None,
    derandomize=True,  # the same mutations on every run: a failure replays
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
SLOW = settings(FAST, max_examples=300)
# an expected failure is not shrunk (that would cost a minute per test)
EXPECTED = settings(FAST, max_examples=3, phases=(Phase.explicit, Phase.generate))


# ---------------------------------------------------------------- the route
@pytest.fixture(scope="session")
def route(tmp_path_factory) -> dict:
    """The map folder, its queries, data files about them and the original
    answers (query predictions, evaluate's JSON)."""
    root = tmp_path_factory.mktemp("fuzz_files")
    rng = np.random.default_rng(0)
    x = rng.normal(size=(N, D)).astype(np.float32)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    q = x[:B] + 0.05 * rng.normal(size=(B, D)).astype(np.float32)
    np.save(root / "x.npy", x)
    np.save(root / "q.npy", q)
    code, _, err = _main(["fit", str(root / "x.npy"), "--out", str(root / "m.map"),
                          "--no-progress"])  # fmt: skip
    assert code == 0, err
    # positions 10 m apart along a line; the queries at the first 12 places
    db = np.stack([np.arange(N) * 10.0, np.zeros(N)], 1) + 500_000.0
    np.savez(root / "gt.npz", utmDb=db, utmQ=db[:B] + 1.0, posDistThr=25.0)
    for name, xy in (("ref.csv", db), ("qry.csv", db[:B] + 1.0)):
        rows = "".join(f"{e:.1f},{n:.1f}\n" for e, n in xy)
        (root / name).write_text("easting,northing\n" + rows)
    _write_h5(root / "global-feats.h5", q)
    route = {"root": root, "map": root / "m.map", "q": root / "q.npy"}
    route["predictions"] = _predictions(_query(route["map"], route["q"]))
    assert len(route["predictions"]) == B
    h5 = _query(route["map"], root / "global-feats.h5")
    assert _predictions(h5) == route["predictions"]
    return route


def _write_h5(path: Path, q: np.ndarray) -> None:
    import h5py

    with h5py.File(path, "w") as f:  # hloc: one group per image name
        for i, v in enumerate(q):
            f.create_group(f"q/{i:03d}.jpg").create_dataset("global_descriptor", data=v)


def _main(argv: list[str]) -> tuple[int, str, list[str]]:
    """(status, stdout, stderr lines) of the command line, run in this process."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except SystemExit as done:
            code = done.code if isinstance(done.code, int) else 1
    return code, out.getvalue(), err.getvalue().splitlines()


def _query(folder, source) -> tuple[int, str, list[str]]:
    return _main(["query", str(folder), str(source), "--json", "--no-progress"])


def _predictions(outcome) -> list[int]:
    code, out, err = outcome
    assert code == 0, err
    return json.loads(out)["predictions"]


def _peak_rss() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def _judged(run, original=None, n: int = N) -> tuple[int, str, list[str]]:
    """Run ``run()`` (a command in this process) and check its outcome: one
    error line and exit 2, or exit 0 with the ``original`` predictions (None: a
    well-formed answer), within the time and memory bounds."""
    before, start = _peak_rss(), time.monotonic()
    code, out, err = run()
    took = time.monotonic() - start
    assert took < TIMEOUT_S, f"took {took:.0f} s"
    assert _peak_rss() - before < GIB, "the process grew by 1 GiB or more"
    assert not any("Traceback" in line for line in err), "\n".join(err)
    if code == 2:
        assert len(err) == 1, "\n".join(err)
        assert err[0].startswith("rhythmic-jax ") and ": error: " in err[0], err[0]
        return code, out, err
    assert code == 0, f"exit {code}: " + "\n".join(err[-5:])
    got = json.loads(out)
    if "predictions" in got:
        if original is not None:
            assert got["predictions"] == original
        else:
            assert all(isinstance(p, int) and -1 <= p < n for p in got["predictions"])
    return code, out, err


@contextlib.contextmanager
def _copy(route):
    """A fresh copy of the route's map folder, removed after."""
    tmp = Path(tempfile.mkdtemp(dir=route["root"]))
    try:
        target = tmp / "m.map"
        shutil.copytree(route["map"], target, symlinks=True)
        yield target
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.rglob("*") if p.is_file())


# -------------------------------------------------------------- map.json
JSON_VALUES = st.sampled_from(
    [
        "delete", "x", "", [], {}, None, True, False, 1.5, 0, -1, -(10**9),
        10**30, 2**63, 1e308, float("nan"), float("inf"), -float("inf"), [1, 2],
        {"kind": "periods"}, "deep",
    ]
)  # fmt: skip
DEEP = 100_000  # lists nested this deep, written as text


def _paths(value, prefix=()) -> list[tuple]:
    """Every key path into a JSON value, containers included."""
    out = [prefix] if prefix else []
    if isinstance(value, dict):
        for k, v in value.items():
            out += _paths(v, prefix + (k,))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            out += _paths(v, prefix + (i,))
    return out


def _set_path(meta, path, value) -> None:
    *head, last = path
    for k in head:
        meta = meta[k]
    if value == "delete":
        del meta[last]
    else:
        meta[last] = value


# fields whose value steers the decode or says what the map holds: a change
# may give another well-formed answer (the map means something else)
STEERING = {"n", "config", "periods", "groups", "reference", "descriptor_settings"}


@st.composite
def json_mutations(draw, meta: dict):
    path = draw(st.sampled_from(_paths(meta)))
    return path, draw(JSON_VALUES)


def _write_json(folder: Path, meta: dict, path, value) -> None:
    if value == "deep":
        _set_path(meta, path, "@DEEP@")
        text = json.dumps(meta).replace('"@DEEP@"', "[" * DEEP + "]" * DEEP)
    else:
        _set_path(meta, path, value)
        text = json.dumps(meta)
    (folder / "map.json").write_text(text)


def _json_case(route, data, deep: bool) -> None:
    meta = json.loads((route["map"] / "map.json").read_text())
    path, value = data.draw(json_mutations(meta))
    if deep != (value == "deep"):
        value = "deep" if deep else "delete"
    with _copy(route) as folder:
        _write_json(folder, meta, path, value)
        strict = path[0] not in STEERING
        original = route["predictions"] if strict else None
        if data.draw(st.booleans(), label="info"):
            _judged(lambda: _main(["info", str(folder), "--json"]))
        else:
            _judged(lambda: _query(folder, route["q"]), original, n=10**9)


@FAST
@given(data=st.data())
def test_map_json_fields(route, data):
    _json_case(route, data, deep=False)


@EXPECTED
@given(data=st.data())
def test_map_json_nested_deep(route, data):
    """10**5 nested lists anywhere in map.json: one line, not a recursion
    error."""
    _json_case(route, data, deep=True)


# ----------------------------------------------------------- array files
def _byte_case(route, data) -> None:
    with _copy(route) as folder:
        files = _files(folder / "arrays")
        path = data.draw(st.sampled_from(files), label="file")
        size = path.stat().st_size
        where = data.draw(st.integers(0, max(size - 1, 0)), label="offset")
        flip = data.draw(st.integers(1, 255), label="xor")
        raw = bytearray(path.read_bytes())
        if raw:
            raw[where] ^= flip
        else:
            raw = bytearray([flip])
        path.write_bytes(bytes(raw))
        _judged(lambda: _query(folder, route["q"]), route["predictions"])


@FAST
@given(data=st.data())
def test_array_file_bytes(route, data):
    _byte_case(route, data)


ARRAY_VALUES = st.sampled_from(
    [np.nan, np.inf, -np.inf, 1e38, -1e38, 0.0, 1e-45, 10**6, -1, 2**40]
)


def _array_values_with_digests_recomputed(route, data) -> None:
    """An array's value changed and the digests recomputed: only the checks of
    what a map means stand between it and a decode."""
    arrays, meta = load_map(route["map"])
    meta.pop("format_version", None)
    name = data.draw(st.sampled_from(sorted(arrays)), label="array")
    value = data.draw(ARRAY_VALUES, label="value")
    a = arrays[name].copy()
    flat = a.reshape(-1)
    i = data.draw(st.integers(0, flat.size - 1), label="index")
    with np.errstate(all="ignore"), contextlib.suppress(OverflowError, ValueError):
        flat[i] = np.asarray(value).astype(a.dtype)
    arrays[name] = a
    if data.draw(st.booleans(), label="with labels"):
        labels = np.arange(N, dtype=np.int64)
        labels[i % N] = data.draw(st.sampled_from([0, N - 1, N, -1, 10**6, 2**40]))
        arrays["extra_reference_labels"] = labels
    with _copy(route) as folder:
        shutil.rmtree(folder)
        save_map(folder, arrays, meta)
        _judged(lambda: _query(folder, route["q"]))


# ------------------------------------------------- names, links and types
FILE_OPS = ("rename", "swap", "link_copy", "link_loop", "link_missing", "folder")
# map.json as a folder or a link loop is met by its read (OSError): the reader's
MAP_JSON_OPS = ("swap", "link_loop", "folder")


def _file_case(route, data, ops, meta: bool = False) -> None:
    """A file of the map folder (``meta``: map.json) renamed, swapped with
    another, replaced by a link or a folder."""
    with _copy(route) as folder:
        entries = [folder / "arrays"] + _files(folder / "arrays")
        path = folder / "map.json"
        if not meta:
            path = data.draw(st.sampled_from([path] + entries), label="path")
        if path.name == "map.json" and not meta:  # what is refused today
            ops = tuple(op for op in ops if op not in MAP_JSON_OPS)
        op = data.draw(st.sampled_from(ops), label="op")
        outside = folder.parent / "outside"
        if op == "rename":
            path.rename(path.with_name(path.name + ".moved"))
        elif op == "swap":
            other = data.draw(st.sampled_from(entries), label="other")
            if (
                other != path
                and other not in path.parents
                and path not in other.parents
            ):
                path.rename(outside)
                other.rename(path)
                outside.rename(other)
        elif op == "link_copy":  # the same bytes, in a file outside the folder
            if path.is_dir():
                shutil.copytree(path, outside)
                shutil.rmtree(path)
            else:
                shutil.copy(path, outside)
                path.unlink()
            path.symlink_to(outside)
        elif op in ("link_loop", "link_missing"):
            shutil.rmtree(path) if path.is_dir() else path.unlink()
            path.symlink_to(path if op == "link_loop" else folder / "nowhere")
        elif op == "folder":
            shutil.rmtree(path) if path.is_dir() else path.unlink()
            path.mkdir()
            (path / "inside").write_text("{}")
        _judged(lambda: _query(folder, route["q"]), route["predictions"])


@FAST
@given(data=st.data())
def test_names_links_and_file_types(route, data):
    _file_case(route, data, FILE_OPS)


@pytest.mark.parametrize("name", ["arrays", "arrays/_METADATA"])
def test_a_link_loop_in_the_map_folder(route, name):
    """A link to itself where the arrays (or a file of them) should be: one
    line (a loop found while resolving names must not escape as an error)."""
    with _copy(route) as folder:
        path = folder / name
        shutil.rmtree(path) if path.is_dir() else path.unlink()
        path.symlink_to(path)
        _judged(lambda: _query(folder, route["q"]), route["predictions"])


@settings(EXPECTED, max_examples=6)
@given(data=st.data())
def test_map_json_as_a_folder_or_a_link_loop(route, data):
    _file_case(route, data, MAP_JSON_OPS, meta=True)


# ------------------------------------------------------------ data files
def _text_mutation(draw, text: str) -> str:
    op = draw(
        st.sampled_from(
            ["bom", "crlf", "blank", "char", "drop", "number", "header", "empty"]
        )
    )
    lines = text.splitlines(keepends=True)
    if op == "bom":
        return "\ufeff" + text
    if op == "crlf":
        return text.replace("\n", "\r\n")
    if op == "blank":
        i = draw(st.integers(0, len(lines)))
        return "".join(lines[:i] + ["\n", " , \n"] + lines[i:])
    if op == "char":
        i = draw(st.integers(0, len(text)))
        return text[:i] + draw(st.sampled_from(list(',;\t"x-\x00é'))) + text[i:]
    if op == "drop":
        i = draw(st.integers(0, len(lines) - 1))
        return "".join(lines[:i] + lines[i + 1 :])
    if op == "number":
        i = draw(st.integers(1, len(lines) - 1))
        bad = draw(st.sampled_from(["nan", "inf", "-inf", "1e400", "9" * 400, "", "-"]))
        lines[i] = bad + "," + lines[i].split(",", 1)[1]
        return "".join(lines)
    if op == "header":
        return draw(st.sampled_from(["lat,lon\n", "x\n", "a,b,c\n"])) + text
    return ""


def _positions_csv(route, data) -> None:
    root = route["root"]
    which = data.draw(st.sampled_from(["ref.csv", "qry.csv"]), label="file")
    tmp = Path(tempfile.mkdtemp(dir=root))
    try:
        for name in ("ref.csv", "qry.csv"):
            shutil.copy(root / name, tmp / name)
        text = (tmp / which).read_text()
        (tmp / which).write_text(_text_mutation(data.draw, text), encoding="utf-8")
        _judged(lambda: _evaluate(route, [tmp / "ref.csv", tmp / "qry.csv"]))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _evaluate(route, truth) -> tuple[int, str, list[str]]:
    return _main(
        ["evaluate", str(route["map"]), str(route["q"]), "--json", "--no-progress",
         "--ground-truth", *map(str, truth)]
    )  # fmt: skip


GT_VALUES = st.sampled_from(
    [
        np.inf, -np.inf, np.nan, 0.0, -25.0, 1e308, np.array([25.0, 30.0]),
        np.array(["25"]), np.zeros((N, 3)), np.zeros((0, 2)),
        np.full((B, 2), np.nan), np.array([[1 + 2j, 3j]]), np.int8(25),
        np.zeros((10**6, 2), np.float16),
    ]
)  # fmt: skip


def _patchnetvlad_ground_truth(route, data) -> None:
    root = route["root"]
    tmp = Path(tempfile.mkdtemp(dir=root))
    try:
        with np.load(root / "gt.npz") as f:
            arrays = {k: f[k] for k in f.files}
        if data.draw(st.booleans(), label="bytes"):
            raw = bytearray((root / "gt.npz").read_bytes())
            raw[data.draw(st.integers(0, len(raw) - 1))] ^= data.draw(
                st.integers(1, 255)
            )
            (tmp / "gt.npz").write_bytes(bytes(raw))
        else:
            key = data.draw(st.sampled_from(sorted(arrays) + ["delete"]), label="key")
            if key == "delete":
                arrays.pop(data.draw(st.sampled_from(sorted(arrays))))
            else:
                arrays[key] = data.draw(GT_VALUES, label="value")
            np.savez(tmp / "gt.npz", **arrays)
        _judged(lambda: _evaluate(route, [tmp / "gt.npz"]))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


H5_OPS = ("byte", "nan", "shape", "dtype", "extra", "delete", "attr", "vds")


def _hloc_h5(route, data) -> None:
    import h5py

    root = route["root"]
    tmp = Path(tempfile.mkdtemp(dir=root))
    try:
        path = tmp / "global-feats.h5"
        shutil.copy(root / "global-feats.h5", path)
        op = data.draw(st.sampled_from(H5_OPS), label="op")
        i = data.draw(st.integers(0, B - 1), label="image")
        key = f"q/{i:03d}.jpg/global_descriptor"
        if op == "byte":
            raw = bytearray(path.read_bytes())
            raw[data.draw(st.integers(0, len(raw) - 1))] ^= data.draw(
                st.integers(1, 255)
            )
            path.write_bytes(bytes(raw))
        else:
            with h5py.File(path, "r+") as f:
                v = f[key][()]
                if op == "nan":
                    f[key][0] = np.nan
                elif op in ("shape", "dtype", "delete", "vds"):
                    del f[key]
                    if op == "shape":
                        f[key] = np.zeros((D, 2), np.float32)
                    elif op == "dtype":
                        f[key] = np.array(["x"] * D, dtype="S1")
                    elif op == "vds":  # the same values, from another file
                        h5py.File(tmp / "other.h5", "w").create_dataset("v", data=v)
                        layout = h5py.VirtualLayout(shape=v.shape, dtype=v.dtype)
                        layout[:] = h5py.VirtualSource(tmp / "other.h5", "v", v.shape)
                        f.create_virtual_dataset(key, layout)
                elif op == "extra":
                    f[f"q/zz{i}.jpg/global_descriptor"] = v[: D // 2]
                else:
                    f[key].attrs["x"] = "y" * 1000
        _judged(lambda: _query(route["map"], path))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


# ------------------------------------------------------- installed command
def _command() -> list[str]:
    exe = Path(sys.executable).with_name("rhythmic-jax")
    return (
        [str(exe)] if exe.is_file() else [sys.executable, "-m", "rhythmic_jax.app.cli"]
    )


LIMIT_KIB = 16 * 2**20  # the children's address space: 16 GiB (JAX reserves much)


def _subprocess(args: list[str]) -> subprocess.CompletedProcess:
    """The installed command on ``args`` under ``ulimit -v`` (a shell sets it
    and execs the command, so no fork of this threaded process runs Python): it
    ends within the timeout, and its own peak resident memory (``wait4``) stays
    below 1 GiB."""
    env = dict(
        os.environ, JAX_PLATFORMS="cpu", PYTHONPATH=str(Path(__file__).parents[1])
    )
    limited = ["/bin/sh", "-c", f'ulimit -v {LIMIT_KIB} && exec "$@"', "sh"]
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        proc = subprocess.Popen(
            limited + _command() + args, stdout=out, stderr=err, env=env,
            stdin=subprocess.DEVNULL,
        )  # fmt: skip
        deadline = time.monotonic() + TIMEOUT_S
        while True:
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                break
            if time.monotonic() > deadline:
                proc.kill()
                os.wait4(proc.pid, 0)
                proc.returncode = -9
                pytest.fail(f"{args}: still running after {TIMEOUT_S} s")
            time.sleep(0.05)
        proc.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0), err.seek(0)
        text = out.read().decode(errors="replace"), err.read().decode(errors="replace")
    peak = usage.ru_maxrss * 1024
    assert peak < GIB, f"the command reached {peak / GIB:.1f} GiB"
    return subprocess.CompletedProcess(args, proc.returncode, *text)


def _one_line_exit_2(done: subprocess.CompletedProcess) -> None:
    assert done.returncode == 2, done.stderr[-2000:]
    lines = done.stderr.splitlines()
    assert len(lines) == 1 and ": error: " in lines[0], done.stderr[-2000:]


def test_installed_command_refuses_nan_templates(route, tmp_path):
    arrays, meta = load_map(route["map"])
    meta.pop("format_version", None)
    arrays["w"] = arrays["w"].copy()
    arrays["w"][0, 0] = np.nan
    save_map(tmp_path / "nan.map", arrays, meta)
    done = _subprocess(["query", str(tmp_path / "nan.map"), str(route["q"])])
    _one_line_exit_2(done)
    assert "w holds 1 NaN" in done.stderr


@pytest.mark.slow
@pytest.mark.parametrize("target", ["map.json", "arrays/_METADATA", "data"])
@pytest.mark.parametrize("kind", ["fifo", "zero"])
def test_installed_command_never_blocks_on_a_file(route, tmp_path, target, kind):
    """A FIFO, or a link to /dev/zero, where a map file should be: one line,
    never a hang or a read until memory runs out."""
    folder = tmp_path / "m.map"
    shutil.copytree(route["map"], folder)
    if target == "data":  # the largest array file
        path = max(_files(folder / "arrays"), key=lambda p: p.stat().st_size)
    else:
        path = folder / target
    path.unlink()
    os.mkfifo(path) if kind == "fifo" else path.symlink_to("/dev/zero")
    _one_line_exit_2(_subprocess(["query", str(folder), str(route["q"])]))


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["fifo", "zero"])
def test_installed_command_reads_no_h5_storage_outside(route, tmp_path, kind):
    """An hloc dataset whose values live in an external file (a FIFO, or
    /dev/zero): refused in one line, the outside file never read."""
    import h5py

    outside = tmp_path / "outside"
    os.mkfifo(outside) if kind == "fifo" else outside.symlink_to("/dev/zero")
    path = tmp_path / "global-feats.h5"
    with h5py.File(path, "w") as f:
        for i in range(B):
            f.create_group(f"q/{i:03d}.jpg").create_dataset(
                "global_descriptor", shape=(D,), dtype="f4",
                external=[(str(outside), 4 * D * i, 4 * D)],
            )  # fmt: skip
    _one_line_exit_2(_subprocess(["query", str(route["map"]), str(path)]))


# ------------------------------------------------------------ slow, larger
@pytest.mark.slow
@SLOW
@given(data=st.data())
def test_map_json_fields_many(route, data):
    _json_case(route, data, deep=False)


@pytest.mark.slow
@SLOW
@given(data=st.data())
def test_array_file_bytes_many(route, data):
    _byte_case(route, data)


@pytest.mark.slow
@SLOW
@given(data=st.data())
def test_names_links_and_file_types_many(route, data):
    _file_case(route, data, FILE_OPS)


@FAST
@given(data=st.data())
def test_array_values_with_digests_recomputed(route, data):
    _array_values_with_digests_recomputed(route, data)


@pytest.mark.slow
@SLOW
@given(data=st.data())
def test_array_values_with_digests_recomputed_many(route, data):
    _array_values_with_digests_recomputed(route, data)


@FAST
@given(data=st.data())
def test_positions_csv(route, data):
    _positions_csv(route, data)


@pytest.mark.slow
@SLOW
@given(data=st.data())
def test_positions_csv_many(route, data):
    _positions_csv(route, data)


@FAST
@given(data=st.data())
def test_patchnetvlad_ground_truth(route, data):
    _patchnetvlad_ground_truth(route, data)


@pytest.mark.slow
@SLOW
@given(data=st.data())
def test_patchnetvlad_ground_truth_many(route, data):
    _patchnetvlad_ground_truth(route, data)


@FAST
@given(data=st.data())
def test_hloc_h5(route, data):
    _hloc_h5(route, data)


@pytest.mark.slow
@SLOW
@given(data=st.data())
def test_hloc_h5_many(route, data):
    _hloc_h5(route, data)
