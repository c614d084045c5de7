"""scripts/: every benchmark is ``run`` and ``markdown`` over one harness, and
every command line the reports and docs quote still parses."""

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


@pytest.mark.parametrize("name", ENTRY)
def test_every_script_is_run_and_markdown_over_the_harness(name):
    module = _module(name)
    assert callable(module.run) and callable(module.markdown)
    assert callable(module.options)
    text = (SCRIPTS / f"{name}.py").read_text()
    assert "_harness" in text and "_bench_common" not in text
    assert module.__doc__ and "python scripts/" + name + ".py" in module.__doc__


def test_one_harness_and_no_second_copy_of_its_parts():
    texts = {p.name: p.read_text() for p in SCRIPTS.glob("*.py")}
    for name, text in texts.items():
        if name == "_harness.py":
            continue
        assert "def timed(fn, *args" not in text, name
        assert 'environ.get("RHYTHMIC_DATA"' not in text, name
        assert "def write_report" not in text and "hashlib" not in text, name


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
    ap = _harness.parser(module.__doc__)
    module.options(ap)
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
    report = _harness.main("Tiny.", run, markdown, options, "tiny", argv)
    assert report["command"].endswith("--quick --n 5")
    assert {"environment", "load_average", "wall_seconds"} <= set(report)
    saved = json.loads((tmp_path / "tiny_quick.json").read_text())
    assert saved["value"] == 0.25 and saved["environment"]["cores"] >= 1
    md = (tmp_path / "tiny_quick.md").read_text()
    assert "value 0.25 n 5" in md and "Command: `python scripts/" in md
    (tmp_path / "tiny_quick.md").unlink()
    _harness.main("Tiny.", run, markdown, options, "tiny",
                  ["--render", str(tmp_path / "tiny_quick.json")])  # fmt: skip
    assert "value 0.25 n 5" in (tmp_path / "tiny_quick.md").read_text()


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


@pytest.mark.slow
def test_bench_solver_work_end_to_end_quick(tmp_path, nordland_root):
    module = _module("bench_solver_work")
    import _harness

    argv = ["--quick", "--out", str(tmp_path), "--root", str(nordland_root.parent)]
    report = _harness.main(module.__doc__, module.run, module.markdown,
                           module.options, "solver_work", argv)  # fmt: skip
    md = (tmp_path / "solver_work_quick.md").read_text()
    assert report["n"] == 600 and str(report["runs"]["full"]["chosen"]) in md
