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
import os
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
    assert len(lines) == 1, lines  # warnings and notes are said only on success
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


# ------------------------------------------------- names that are data, not code
# frames named as spreadsheet formulas, TeX and format markup
FORMULAS = ["=HYPERLINK(\"x\",\"y\")", "+1+cmd|' calc'!A0", "-2+3", "@SUM(1)",
            "\t=1", "'=1", "@0543256.96@4178906.70@37.7@-122.4@"]  # fmt: skip
MARKUP = ["$x^2$", "$\\frac{a}{b}$", "a_b^c", "100%", "{braces}", "\\", "$", "$$"]
REF_STEM = "=HYPERLINK($y^2$_{a}%\\"
NAME = st.text(st.sampled_from(list("=+-@'$\\_^%{}|!(), aZ0\t")), min_size=1,
               max_size=10)  # fmt: skip


def _frames(k: int) -> list[np.ndarray]:
    """k distinct 32 x 48 RGB frames (a photograph's strips)."""
    from skimage import data as skdata
    from skimage.transform import resize

    photo = resize(skdata.astronaut(), (32, 48 + 4 * k), anti_aliasing=True)
    return [(photo[:, 4 * i : 4 * i + 48] * 255).astype(np.uint8) for i in range(k)]


def _write_folder(folder: Path, names: list[str], frames) -> None:
    from skimage.io import imsave

    folder.mkdir()
    for name, frame in zip(names, frames, strict=True):
        imsave(folder / f"{name}.png", frame, check_contrast=False)


@pytest.fixture(scope="module")
def named(tmp_path_factory) -> dict[str, Path]:
    """A map fitted on an image folder of 12 frames named as a formula holding
    TeX and format markup (``=HYPERLINK($y^2$_{a}%\\00).png``, ...)."""
    root = tmp_path_factory.mktemp("named")
    names = [f"{REF_STEM}{i:02d})" for i in range(12)]  # one pattern: a route
    _write_folder(root / "ref", names, _frames(len(names)))
    code, _, err = _main(["fit", str(root / "ref"), "--out", str(root / "m.map"),
                          "--no-progress"])  # fmt: skip
    assert code == 0, err
    return {"root": root, "ref": root / "ref", "map": root / "m.map"}


def _number(cell: str) -> bool:
    """Whether a CSV cell is a number (a negative score starts with ``-``)."""
    try:
        float(cell)
    except ValueError:
        return False
    return True


def _exact_names(folder: Path) -> list[str]:
    from rhythmic_jax.io.images import list_images

    return [p.name for p in list_images(folder, "query")]


@settings(FUZZ, max_examples=6)
@given(stem=NAME | st.sampled_from(FORMULAS + MARKUP), k=st.integers(2, 4))
def test_names_as_formulas_and_markup(named, stem, k):
    """query --csv writes every name inert (read back with the csv module, no
    cell starts with = + - @ tab CR) and exact once its one leading quote is
    removed, the same names as --json; evaluate --matches draws the same
    names as they are (no mathtext traceback). The queries of a folder share
    one naming pattern (their order along the route): ``STEM0 .. STEMk``."""
    import csv

    from rhythmic_jax.io.csv_cells import TRIGGERS, name_of

    frames, names = _frames(12), [f"{stem}{i}" for i in range(k)]
    with tempfile.TemporaryDirectory() as tmp:
        qry, table = Path(tmp) / "qry", Path(tmp) / "r.csv"
        _write_folder(qry, names, frames[: len(names)])
        code, out, lines = _main(["query", str(named["map"]), str(qry), "--json",
                                  "--csv", str(table), "--top", "2",
                                  "--no-progress"])  # fmt: skip
        assert _judge("query", code, lines), lines
        records = json.loads(out)["queries"]
        with table.open(newline="") as f:
            rows = list(csv.reader(f))
        head, rows = rows[0], rows[1:]
        assert len(rows) == len(records) == len(names)
        assert {r["query"] for r in records} == {f"{n}.png" for n in names}
        for row, record in zip(rows, records, strict=True):
            cells = dict(zip(head, row, strict=True))
            assert all(_number(c) or not c.startswith(TRIGGERS) for c in row), row
            assert name_of(cells["query"]) == record["query"]
            assert name_of(cells["place_name"]) == (record["place_name"] or "")
            assert name_of(cells["top1_name"]) == record["top"][0]["name"]
            assert int(cells["place"]) == record["place"]  # a number, unquoted
            assert record["place_name"] in _exact_names(named["ref"]) + [None]
        png = Path(tmp) / "m.png"
        code, _, lines = _main(["evaluate", str(named["map"]), str(qry), "--matches",
                                str(png), "--no-progress"])  # fmt: skip
        assert _judge("evaluate", code, lines), lines
        assert png.stat().st_size > 1000


# ----------------------------------------------- every numeric option at its limits
def _numeric_options() -> list[tuple[str, str, object]]:
    """(command, flag, domain) of every option parsed with a domain, read from
    the parsers the command line renders from the jobs: an option declared
    later is covered without naming it here."""
    from rhythmic_jax.app.cli import _parser
    from rhythmic_jax.validate import Domain

    found = []
    for name, command in _parser().commands.items():
        for action in command._actions:
            if isinstance(action.type, Domain) and action.option_strings:
                found.append((name, action.option_strings[-1], action.type))
    return found


def _outside(domain) -> list[str]:
    """Values outside ``domain``: past each bound, huge, NaN and infinities."""
    lo, hi = domain.limits()
    past = [hi + 1 if domain.integer else hi * 10]
    past += [lo - 1 if domain.integer else (lo - 1 if lo > 0 else lo * 10 - 1)]
    if domain.low is not None and domain.open_low and not domain.integer:
        past.append(domain.low)
    if domain.high is not None and domain.open_high and not domain.integer:
        past.append(domain.high)
    texts = [str(int(v)) if domain.integer else repr(float(v)) for v in past]
    texts += ["1e308", "-1e308", "nan", "inf", "-inf"]
    huge = ["9223372036854775808", "-9223372036854775809", "18446744073709551616"]
    return texts + [h for h in huge if domain.integer or not lo <= float(h) <= hi]


REQUIRED = {"fit": ["x", "--out", "NEW"], "learn": ["x", "q", "--out", "NEW"],
            "query": ["map", "q"], "evaluate": ["map", "q"], "describe": ["x", "--out",
            "NEW"], "frontier": ["x", "q"], "info": ["map"], "demo": []}  # fmt: skip


def _positionals(command: str, route, tmp: Path) -> list[str]:
    where = {"x": str(route["x"]), "q": str(route["q"]), "map": str(route["map"]),
             "NEW": str(tmp / "new.out")}  # fmt: skip
    return [where.get(a, a) for a in REQUIRED[command]]


def test_numeric_options_are_enumerated():
    seen = {(c, f) for c, f, _ in _numeric_options()}
    assert {("evaluate", "--tolerance"), ("fit", "--count"), ("query", "--top"),
            ("frontier", "--budget"), ("fit", "--memory")} <= seen  # fmt: skip
    for _, _, domain in _numeric_options():  # every domain bounded both sides
        lo, hi = domain.limits()
        assert math.isfinite(lo) and math.isfinite(hi) and lo < hi


@settings(FUZZ, max_examples=60)
@given(st.data())
def test_values_outside_every_numeric_domain_end_in_one_line(route, data):
    """Past a bound, huge, NaN or infinite: one line naming the flag, exit 2,
    before any work (nothing read, nothing written)."""
    command, flag, domain = data.draw(st.sampled_from(_numeric_options()))
    value = data.draw(st.sampled_from(_outside(domain)))
    before = _snapshot(route)
    with tempfile.TemporaryDirectory() as tmp:
        argv = [command, *_positionals(command, route, Path(tmp)), f"{flag}={value}",
                "--no-progress"]  # fmt: skip
        code, _, lines = _main(argv)
        assert code == 2, (argv, lines)
        assert not _judge(command, code, lines)
        assert f"argument {flag}: " in lines[0], (argv, lines)
        assert os.listdir(tmp) == []
    assert _snapshot(route) == before


# options run at the edges of their ranges (the others need images, a cluster
# or an augmented fit, and their rules refuse them here; --processes would start
# that many processes)
RUN_AT_EDGES = {("query", "--sequence"), ("query", "--threshold"), ("query", "--top"),
                ("evaluate", "--tolerance"), ("evaluate", "--sequence"),
                ("fit", "--r"), ("fit", "--level"), ("fit", "--count"),
                ("fit", "--c"), ("fit", "--gap"), ("fit", "--codes"), ("fit", "--pca"),
                ("fit", "--fusion"), ("fit", "--memory")}  # fmt: skip


def _edges(domain) -> list[str]:
    lo, hi = domain.limits()
    if domain.integer:
        return [str(int(lo)), str(int(lo) + 1), str(int(hi)), str(int(hi) - 1)]
    tiny = 1e-30 if lo == 0 else lo
    return [repr(float(v)) for v in (tiny, hi if not domain.open_high else hi * 0.99,
                                     -hi if domain.low is None else tiny)]


@settings(FUZZ, max_examples=16)
@given(st.data())
def test_values_at_the_edges_of_numeric_domains_work_or_end_in_one_line(route, data):
    """The smallest and largest values a domain takes: a right answer (a map of
    the route's places, predictions of its places) or one line, exit 2."""
    options = [o for o in _numeric_options() if o[:2] in RUN_AT_EDGES]
    command, flag, domain = data.draw(st.sampled_from(options))
    value = data.draw(st.sampled_from(_edges(domain)))
    before = _snapshot(route)
    with tempfile.TemporaryDirectory() as tmp:
        argv = [command, *_positionals(command, route, Path(tmp)), f"{flag}={value}",
                "--json", "--no-progress"]  # fmt: skip
        if (command, flag) == ("fit", "--fusion"):
            argv.append("--codes=8")
        code, out, lines = _main(argv)
        if _judge(command, code, lines):
            result = json.loads(out)
            if command == "fit":
                assert result["n"] == N and _finite(result), result
            elif command == "query":
                pred = np.asarray(result["predictions"])
                assert pred.shape == (B,) and ((pred >= -1) & (pred < N)).all()
            else:
                assert _finite(result["methods"]), result
    assert _snapshot(route) == before


def test_refused_extremes_take_little_memory(route, tmp_path):
    """Refused where parsed, a huge value allocates nothing: each command run
    as the installed one, its peak resident memory well under 1 GiB (measured
    by a fresh parent that starts only these children)."""
    import subprocess
    import sys

    huge = [("evaluate", "--tolerance", "9223372036854775808"),
            ("query", "--top", "18446744073709551616"),
            ("fit", "--count", "2147483647"), ("fit", "--memory", "1e308"),
            ("frontier", "--budget", "1e308"), ("learn", "--k", "-1")]  # fmt: skip
    argvs = [[c, *_positionals(c, route, tmp_path), f"{flag}={value}", "--no-progress"]
             for c, flag, value in huge]  # fmt: skip
    parent = (
        "import json, resource, subprocess, sys\n"
        "codes = [subprocess.run([sys.executable, '-m', 'rhythmic_jax.app.cli', *a],"
        " capture_output=True).returncode for a in json.loads(sys.argv[1])]\n"
        "peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss\n"
        "print(json.dumps([codes, peak]))\n"
    )
    done = subprocess.run([sys.executable, "-c", parent, json.dumps(argvs)],
                          capture_output=True, text=True, timeout=600)  # fmt: skip
    codes, peak_kib = json.loads(done.stdout)
    assert codes == [2] * len(argvs), done
    assert peak_kib * 1024 < 2**30, peak_kib
