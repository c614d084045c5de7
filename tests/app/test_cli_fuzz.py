"""Drawn commands over the ``fit`` / ``query`` / ``evaluate`` option space.

Each drawn command line runs in this process through :func:`rhythmic_jax.app.cli.main`
on small synthetic descriptors (60 x 16 reference frames, 20 queries near the
first 20). It either succeeds (exit 0) with finite output, or exits 2 with
exactly one ``rhythmic-jax CMD: error: ...`` line on stderr; never a traceback,
and the inputs are never touched.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rhythmic_jax.app.cli import main

pytestmark = pytest.mark.slow

N, D, B = 60, 16, 20
FUZZ = settings(
    max_examples=20,
    deadline=None,
    database=None,
    derandomize=True,  # the same commands on every run: a failure replays
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)


@pytest.fixture(scope="module")
def route(tmp_path_factory) -> dict[str, Path]:
    """x.npy (60, 16) unit rows, q.npy (20, 16) near the first 20, a map of x."""
    root = tmp_path_factory.mktemp("fuzz")
    rng = np.random.default_rng(0)
    x = rng.normal(size=(N, D)).astype(np.float32)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    q = x[:B] + 0.05 * rng.normal(size=(B, D)).astype(np.float32)
    np.save(root / "x.npy", x)
    np.save(root / "q.npy", q)
    code, _, err = _main(["fit", str(root / "x.npy"), "--out", str(root / "m.map"),
                          "--codes", "8", "--no-progress"])  # fmt: skip
    assert code == 0, err
    return {
        "root": root,
        "x": root / "x.npy",
        "q": root / "q.npy",
        "map": root / "m.map",
    }


def _main(argv: list[str]) -> tuple[int, str, list[str]]:
    """(status, stdout, stderr lines) of the command line, run in this process."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except SystemExit as done:  # main returns; a stray exit is still a status
            code = done.code if isinstance(done.code, int) else 1
    return code, out.getvalue(), err.getvalue().splitlines()


def _snapshot(route) -> dict[str, bytes]:
    root = route["root"]
    return {
        str(p.relative_to(root)): p.read_bytes()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


def _finite(value) -> bool:
    """Whether every number in a JSON value is finite."""
    if isinstance(value, dict):
        return all(_finite(v) for v in value.values())
    if isinstance(value, list):
        return all(_finite(v) for v in value)
    if isinstance(value, float):
        return math.isfinite(value)
    return True


def _judge(command: str, code: int, lines: list[str]) -> bool:
    """True for a success; asserts a refusal is one error line."""
    if code == 0:
        assert not any("Traceback" in line or "error" in line for line in lines), lines
        return True
    assert code == 2, (code, lines)
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"rhythmic-jax {command}: error: "), lines
    return False


def _flag(name: str, values) -> st.SearchStrategy[list[str]]:
    """Nothing, or ``--name=value`` with a drawn value (text as typed)."""
    return st.none() | values.map(lambda v: [f"--{name}={v}"])


NUMBERS = st.sampled_from(["0", "-1", "1", "0.5", "nan", "inf", "1e-3", "x", "1e9"])
INTS = st.sampled_from(["-1", "0", "1", "2", "3", "5", "9", "25", "1000", "2.5"])
LAYOUTS = st.sampled_from(
    ["periods", "periods:7,9", "periods:6,9", "mixed", "mixed:8,8", "mixed:1,9",
     "hierarchical", "hierarchical:10", "hierarchical:10:3,4", "spiral", "periods:"]
)  # fmt: skip
WHERE = st.sampled_from(["new", "map", "x", "q", "inside-map", "missing-folder"])
# a query may write over any file but the ones it reads (the map and queries)
QUERY_OUT = st.sampled_from(["new", "map", "q", "inside-map", "missing-folder"])


def _place(where: str, route, tmp: Path, name: str) -> str:
    return {
        "new": str(tmp / name),
        "map": str(route["map"]),
        "x": str(route["x"]),
        "q": str(route["q"]),
        "inside-map": str(route["map"] / name),
        "missing-folder": str(tmp / "absent" / name),
    }[where]


def _argv(parts) -> list[str]:
    return [a for part in parts if part for a in part]


@FUZZ
@given(
    options=st.tuples(
        _flag("r", INTS),
        _flag("level", INTS),
        _flag("count", INTS),
        _flag("c", NUMBERS),
        _flag("gap", NUMBERS),
        _flag("layout", LAYOUTS),
        _flag("codes", st.sampled_from(["0", "4", "8", "17", "int8", "x"])),
        _flag("fusion", NUMBERS),
        _flag("pca", INTS),
        _flag("dtype", st.sampled_from(["float32", "float16", "int8"])),
        _flag("solver", st.sampled_from(["newton", "lbfgs"])),
        _flag("epochs", INTS),
        _flag("stride", INTS),
        _flag("compile", st.sampled_from(["auto", "never"])),
    ),  # fmt: skip
    out=WHERE,
)
def test_fit_commands(route, options, out):
    before = _snapshot(route)
    with tempfile.TemporaryDirectory() as tmp:
        target = _place(out, route, Path(tmp), "f.map")
        argv = ["fit", str(route["x"]), "--out", target, "--json", "--no-progress"]
        code, stdout, lines = _main(argv + _argv(options))
        if _judge("fit", code, lines):
            info = json.loads(stdout)
            assert info["n"] == N and _finite(info), info
            assert (Path(target) / "map.json").is_file()
            if out in ("map", "inside-map"):  # written where asked: put it back
                shutil.rmtree(route["map"])
                _main(["fit", str(route["x"]), "--out", str(route["map"]),
                       "--codes", "8", "--no-progress"])  # fmt: skip
                return
    assert _snapshot(route) == before


@FUZZ
@given(
    options=st.tuples(
        _flag("decode", st.sampled_from(["hard", "soft", "topm", "bogus"])),
        _flag("sequence", INTS),
        _flag("threshold", NUMBERS),
        _flag("tile", INTS),
        _flag("stride", INTS),
        _flag("compile-min-frames", INTS),
        _flag("descriptor", st.sampled_from(["hog", "patchnorm"])),
    ),  # fmt: skip
    out=st.none() | QUERY_OUT,
    as_json=st.booleans(),
)
def test_query_commands(route, options, out, as_json):
    before = _snapshot(route)
    with tempfile.TemporaryDirectory() as tmp:
        argv = ["query", str(route["map"]), str(route["q"]), "--no-progress"]
        target = None if out is None else _place(out, route, Path(tmp), "p.npy")
        argv += ["--out", target] if target else []
        argv += ["--json"] if as_json else []
        code, stdout, lines = _main(argv + _argv(options))
        if _judge("query", code, lines):
            if as_json:
                pred = np.asarray(json.loads(stdout)["predictions"])
            elif target:
                pred = np.load(target)
            else:
                pred = np.asarray([int(v) for v in stdout.split()])
            assert pred.shape == (B,)
            assert ((pred >= -1) & (pred < N)).all(), pred
    assert _snapshot(route) == before


@FUZZ
@given(
    options=st.tuples(
        _flag("tolerance", INTS),
        _flag("decode", st.sampled_from(["hard", "soft"])),
        _flag("sequence", INTS),
        _flag("tolerance-m", NUMBERS),
        _flag("ground-truth", st.sampled_from(["names", "q"])),
        _flag("reference", st.sampled_from(["x", "q"])),
    ),  # fmt: skip
    plot=st.none() | st.sampled_from(["new", "txt", "inside-map", "q"]),
)
def test_evaluate_commands(route, options, plot):
    before = _snapshot(route)
    options = [
        [o[0].replace("=x", f"={route['x']}").replace("=q", f"={route['q']}")]
        if o and o[0].startswith(("--reference", "--ground-truth"))
        else o
        for o in options
    ]
    with tempfile.TemporaryDirectory() as tmp:
        argv = ["evaluate", str(route["map"]), str(route["q"]), "--json"]
        places = {
            "new": str(Path(tmp) / "pr.png"),
            "txt": str(Path(tmp) / "pr.txt"),
            "inside-map": str(route["map"] / "pr.png"),
            "q": str(route["q"]),
        }
        argv += ["--plot", places[plot]] if plot else []
        code, stdout, lines = _main([*argv, "--no-progress", *_argv(options)])
        if _judge("evaluate", code, lines):
            result = json.loads(stdout)
            assert _finite(result["methods"]), result
    assert _snapshot(route) == before
