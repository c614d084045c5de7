"""scripts/: the benchmarks are a few scripts by theme, each a set of parts
(``run`` and ``markdown`` over one harness and its one renderer); every report in
reports/ has the part that writes it and renders again from its JSON, and every
command line the reports and docs quote still parses."""

from __future__ import annotations

import importlib
import json
import re
import shlex
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SCRIPTS = REPO / "scripts"
ENTRY = sorted(p.stem for p in SCRIPTS.glob("*.py") if not p.stem.startswith("_"))
QUOTED = re.compile(r"`python\s+(scripts/[a-z_]+\.py[^`]*)`")


@pytest.fixture(scope="module", autouse=True)
def on_path():
    sys.path.insert(0, str(SCRIPTS))
    yield
    sys.path.remove(str(SCRIPTS))


def _module(name: str):
    return importlib.import_module(name)


# every report in reports/ and the script and part that write it
REPORTS = {
    "decode": ("bench_decode", "batch"),
    "decoding": ("bench_decode", "decoders"),
    "single_query": ("bench_decode", "single-query"),
    "solver": ("bench_solver", "joint"),
    "solver_work": ("bench_solver", "work"),
    "span": ("bench_solver", "span"),
    "frames": ("bench_frames", "end-to-end"),
    "first_run": ("bench_frames", "first-run"),
    "pipeline": ("bench_frames", "pipeline"),
    "pipeline_efficientnet_lite0": ("bench_frames", "pipeline"),
    "network": ("bench_frames", "network"),
    "descriptors": ("bench_frames", "descriptors"),
    "augment": ("bench_frames", "augment"),
    "scale": ("bench_scale", "grid"),
    "streamed": ("bench_scale", "streamed"),
    "memory": ("bench_scale", "memory"),
    "compile": ("bench_compile", "jobs"),
    "startup": ("bench_compile", "startup"),
    "recall_per_byte": ("bench_recall", "per-byte"),
    "cross_condition": ("bench_recall", "cross-condition"),
    "digits": ("bench_recall", "digits"),
    "gpu_quick": ("bench_gpu", ""),
    "reproduction": ("reproduce", ""),
}
THEMES = sorted({script for script, part in REPORTS.values() if part})


def _parts(module) -> dict:
    """A script's parts by subcommand ("" for a script of one part)."""
    import _harness

    return getattr(module, "PARTS", None) or {
        "": _harness.Part(module.run, module.markdown, module.options)
    }


@pytest.mark.parametrize("name", ENTRY)
def test_every_script_is_parts_over_the_harness(name):
    module = _module(name)
    for part in _parts(module).values():
        assert callable(part.run) and callable(part.markdown)
    text = (SCRIPTS / f"{name}.py").read_text()
    assert "_harness" in text and "_bench_common" not in text
    assert module.__doc__ and "python scripts/" + name + ".py" in module.__doc__


def test_every_report_has_its_script_and_part():
    """Each reports/*.json names a script and a part that writes its stem; the
    theme scripts are about six, with no script left over."""
    stems = {p.stem for p in (REPO / "reports").glob("*.json")}
    assert stems <= set(REPORTS), stems - set(REPORTS)
    for stem, (script, part) in REPORTS.items():
        parts = _parts(_module(script))
        assert part in parts, (stem, script, part)
        assert not part or stem.startswith(parts[part].stem), (stem, part)
    assert set(ENTRY) == {*THEMES, "bench_gpu", "reproduce"}
    assert 5 <= len(THEMES) <= 7


@pytest.mark.parametrize("stem", sorted(REPORTS))
def test_each_report_renders_again_from_its_json(stem, tmp_path):
    """``--render``: each committed report's JSON through its part's renderer
    (the one of the harness), measuring nothing."""
    import shutil

    import _harness

    script, part = REPORTS[stem]
    source = REPO / "reports" / f"{stem}.json"
    if stem == "reproduction" or not source.is_file():
        pytest.skip("reproduce.py renders its own report (tests/test_reproduce.py)")
    shutil.copy(source, tmp_path / source.name)
    module = _module(script)
    argv = [part] if part else []
    argv += ["--render", str(tmp_path / source.name)]
    _harness.main(module.__doc__, _parts(module), argv=argv)
    md = (tmp_path / f"{stem}.md").read_text()
    assert md.startswith("# ") and "|---" in md


def _quoted() -> list[tuple[str, str]]:
    out = []
    for path in [
        REPO / "README.md",
        *REPO.glob("docs/*.md"),
        *REPO.glob("reports/*.md"),
    ]:
        for m in QUOTED.finditer(path.read_text()):
            for part in " ".join(m.group(1).split()).split(" ; python "):
                out.append((path.name, part.strip()))
    return sorted(set(out))


@pytest.mark.parametrize(("where", "command"), _quoted())
def test_quoted_command_lines_parse(where, command):
    """Every ``python scripts/X.py ...`` the reports, docs and README quote names a
    script that exists and whose options take those arguments."""
    import _harness

    script, *argv = shlex.split(command.replace("CHECKOUT", "/tmp/x"))
    path = REPO / script
    assert path.is_file(), (where, command)
    module = _module(path.stem)
    ap = _harness.parser(module.__doc__, _parts(module))
    argv = ["/tmp/x" if a.isupper() else a for a in argv]
    ap.parse_args(argv)


def test_report_writer_writes_json_and_markdown(tmp_path, capsys):
    import _harness

    report = dict(command="python scripts/x.py", rows=[dict(a=1.5, b="x")])
    md = _harness.table(["a", "b"], [[r["a"], r["b"]] for r in report["rows"]])
    _harness.write_report(tmp_path, "x", report, md, md_stem="X")
    assert json.loads((tmp_path / "x.json").read_text()) == report
    text = (tmp_path / "X.md").read_text()
    assert "| 1.5 | x |" in text and "|---:|---|" in text
    assert "| 1.5 | x |" in capsys.readouterr().out


def test_main_runs_run_then_writes_and_renders(tmp_path, capsys):
    """``main``: the machine record around ``run``'s numbers, both files, and
    ``--render`` from the JSON alone."""
    import _harness

    def run(args):
        args.stem = "tiny_quick" if args.quick else "tiny"
        return dict(value=0.25, n=args.n)

    def markdown(r):
        return "\n".join(
            _harness.header("Tiny", r) + [f"value {r['value']} n {r['n']}"]
        )

    def options(ap):
        ap.add_argument("--n", type=int, default=3)

    argv = ["--out", str(tmp_path), "--quick", "--n", "5"]
    parts = {"": _harness.Part(run, markdown, options, "tiny")}
    report = _harness.main("Tiny.", parts, argv)
    assert report["command"].endswith("--quick --n 5")
    assert {"environment", "load_average", "wall_seconds"} <= set(report)
    saved = json.loads((tmp_path / "tiny_quick.json").read_text())
    assert saved["value"] == 0.25 and saved["environment"]["cores"] >= 1
    md = (tmp_path / "tiny_quick.md").read_text()
    assert "value 0.25 n 5" in md and "Command: `python scripts/" in md
    (tmp_path / "tiny_quick.md").unlink()
    _harness.main("Tiny.", parts, ["--render", str(tmp_path / "tiny_quick.json")])
    assert "value 0.25 n 5" in (tmp_path / "tiny_quick.md").read_text()


def test_parts_are_subcommands_with_their_own_options(tmp_path):
    """Two parts: each a subcommand with its own options, defaults and ``--quick``
    settings, its report under its stem, rendered by the one renderer."""
    import _harness

    def markdown(r):
        return _harness.render("Two", r, f"n {r['n']}", (["a", "b"], [[1.5, "x"]]))

    def options(ap):
        ap.add_argument("--n", type=int, default=3)

    parts = {
        "one": _harness.Part(lambda a: dict(n=a.n), markdown, options, "one"),
        "two": _harness.Part(lambda a: dict(n=a.n), markdown, options, "two",
                             quick=dict(n=7)),  # fmt: skip
    }
    out = ["--out", str(tmp_path)]
    assert _harness.main("Two.", parts, argv=["one", *out])["n"] == 3
    report = _harness.main("Two.", parts, argv=["two", "--quick", *out])
    assert report["n"] == 7 and report["command"].endswith("two --quick --out "
                                                           + str(tmp_path))
    md = (tmp_path / "two_quick.md").read_text()
    assert md.startswith("# Two\n") and "n 7\n\n| a | b |\n|---:|---|" in md
    assert _harness.main("Two.", parts, argv=["two", "--n", "2", *out])["n"] == 2
    with pytest.raises(SystemExit):
        _harness.main("Two.", parts, argv=["three", *out])


def test_options_declared_as_data():
    """Each option is a name and its default, type or help: the harness builds the
    flag, its type and its form (False: a switch; a list: one or more values)."""
    import argparse

    import _harness

    ap = argparse.ArgumentParser()
    _harness.add_options(ap, dict(
        n=3, rate=(0.5, "a rate"), base=(Path, "a folder"), skip=False,
        sizes=[1, 2], mode=dict(default="a", choices=("a", "b")),
    ))  # fmt: skip
    args = ap.parse_args([])
    assert (args.n, args.rate, args.base, args.skip, args.sizes) == (3, 0.5, None,
                                                                     False, [1, 2])
    args = ap.parse_args(["--n", "4", "--base", "/x", "--skip", "--sizes", "5", "6",
                          "--mode", "b", "--rate", "2"])  # fmt: skip
    assert (args.n, args.base, args.skip, args.sizes, args.mode) == (
        4, Path("/x"), True, [5, 6], "b")  # fmt: skip
    assert args.rate == 2.0 and "a rate" in ap.format_help()
    with pytest.raises(SystemExit):
        ap.parse_args(["--mode", "c"])


def test_cached_fit_fits_once(tmp_path):
    import _harness
    import numpy as np

    from rhythmic_jax import RhythmicMap

    rng = np.random.default_rng(0)
    x = _harness.unit_rows(rng.standard_normal((120, 16)))
    a, rec = _harness.cached_fit(RhythmicMap(r=2, count=3), x, tmp_path)
    b, again = _harness.cached_fit(RhythmicMap(r=2, count=3), x, tmp_path)
    assert (
        not rec["cached"] and again["cached"] and rec["map_path"] == again["map_path"]
    )
    assert list(a.periods) == list(b.periods) and "fit_wall_s" in again
    _, other = _harness.cached_fit(RhythmicMap(r=2, count=3), x[::-1], tmp_path)
    assert other["map_path"] != rec["map_path"]


# keys of committed reports from options a quick run leaves off, or from before the
# harness recorded the machine under "environment"
OPTIONAL = {"probe", "full", "wall_seconds_by_process", "cpu_count", "python", "torch"}
# one quick run of every part: (script, part, extra arguments)
QUICK = [
    ("bench_decode", "batch", []),
    ("bench_decode", "decoders", []),
    ("bench_decode", "single-query", []),
    ("bench_solver", "joint", []),
    ("bench_solver", "work", []),
    ("bench_solver", "span", []),
    ("bench_frames", "end-to-end", ["--base", str(REPO), "--skip-augmented"]),
    ("bench_frames", "pipeline", []),
    ("bench_frames", "network", []),
    ("bench_frames", "descriptors", []),
    ("bench_frames", "augment", []),
    ("bench_scale", "grid", ["--budget", "0"]),
    ("bench_scale", "streamed", []),
    ("bench_scale", "memory", []),
    ("bench_compile", "jobs", ["--base", str(REPO), "--jobs", "imports,fit"]),
    ("bench_compile", "startup", []),
    ("bench_recall", "per-byte", ["--no-timing", "--cache", ""]),
    ("bench_recall", "cross-condition", []),
    ("bench_recall", "digits", []),
]


@pytest.mark.slow
@pytest.mark.parametrize(("script", "part", "extra"), QUICK)
def test_every_part_runs_quick_and_keeps_the_report_keys(
    script, part, extra, tmp_path, nordland_root
):
    """Each part's ``--quick`` run writes a report with the top-level keys of the
    committed one (but those of options a quick run leaves off)."""
    import _harness

    if part == "digits" and not Path("/work/cache/nordland_summer_"
                                     "efficientnet_lite0.npy").is_file():  # fmt: skip
        pytest.skip("the digits part reads cached Lite0 features (--cache)")
    module = _module(script)
    argv = [part, "--quick", "--no-progress", "--out", str(tmp_path)]
    argv += ["--root", str(nordland_root.parent), *extra]
    report = _harness.main(module.__doc__, _parts(module), argv=argv)
    stem = _parts(module)[part].stem
    committed = REPO / "reports" / f"{stem}.json"
    assert report is not None and list(tmp_path.glob("*.md"))
    if committed.is_file():
        keys = set(json.loads(committed.read_text())) - OPTIONAL
        assert keys <= set(report), sorted(keys - set(report))


@pytest.mark.slow
def test_solver_work_end_to_end_quick(tmp_path, nordland_root):
    module = _module("bench_solver")
    import _harness

    argv = ["work", "--quick", "--out", str(tmp_path), "--root",
            str(nordland_root.parent)]  # fmt: skip
    report = _harness.main(module.__doc__, module.PARTS, argv=argv)
    md = (tmp_path / "solver_work_quick.md").read_text()
    assert report["n"] == 600 and str(report["runs"]["full"]["chosen"]) in md
