"""Every ```bash command of README.md and docs/usage.md, run as written.

The commands are read from the documents (so a command added there is run here
too), in order, from a folder of their own holding every file they name, made
from real frames: Nordland summer and winter (``ref.npy``, ``queries.npy``,
``summer/``, ``winter/``, ``spring/``, a training route of other places, VPR-Bench,
Pittsburgh-style, RobotCar-style and OpenVPRLab / VPR_Tutorial / Patch-NetVLAD /
hloc files) and aerial pairs (``city_2019.png``, ``city_2021.png``). Set-up lines
(:data:`SETUP`) are left out. Each command must exit 0; where the README shows
what a command prints, its lines must have the same shape (numbers aside).

The default run takes the commands on descriptor files (``.npy``, ``.h5``) in
this process; the ``slow`` run takes every command, each through ``bash`` as a
reader would type it. Skipped, with the reason, without ``../shared/data``.
"""

from __future__ import annotations

import csv
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCUMENTS = (ROOT / "README.md", ROOT / "docs" / "usage.md")
# what sets a machine up rather than uses the package: never run here
SETUP = (
    "pip install",
    "python -m venv",
    ". .venv/bin/activate",
    "bash scripts/test.sh",
    "bash scripts/refresh_constraints.sh",
    "bash scripts/test_gpu.sh",  # a GPU machine's checks, from the checkout
)
PLACES = range(1000, 1060)  # the scored route: 60 Nordland places
# the training route, apart from the scored places (learn holds out a fifth)
TRAIN = range(0, 200)
RUNS = range(0, 300)  # the RobotCar-style runs (500 places from 600 frames)
EAST, NORTH = 500_000, 7_000_000  # metres: place i lies at EAST + 10 i
# the README's printed outputs: the README command they belong to (its start)
# -> a line of the output block
SHOWN = {
    "rhythmic-jax demo": r"^map: periods",
    "rhythmic-jax frontier summer.npy winter.npy": r"places of .*queries; ground",
}
# of those, the outputs whose figures (timings aside) a run must print as shown
# (the frontier block is of other data: its figures come from a report)
FIGURES = ("rhythmic-jax demo",)


# --------------------------------------------------------------- the commands


def fenced_blocks(path: Path) -> list[tuple[str, str]]:
    """``(language, text)`` of every fenced block of a Markdown file, in order."""
    blocks, lang, lines = [], None, []
    for line in path.read_text().splitlines():
        if line.startswith("```") and lang is None:
            lang, lines = line[3:].strip(), []
        elif line.startswith("```"):
            blocks.append((lang, "\n".join(lines) + "\n"))
            lang = None
        elif lang is not None:
            lines.append(line)
    return blocks


def bash_blocks(path: Path) -> list[str]:
    """The text of every ```bash block of a Markdown file."""
    return [text for lang, text in fenced_blocks(path) if lang == "bash"]


def block_commands(block: str) -> list[str]:
    """The commands of a block: continued lines joined, comment lines dropped,
    ``a && b`` split, set-up commands (:data:`SETUP`) left out."""
    joined = re.sub(r"\\\n\s*", " ", block)
    out = []
    for line in joined.splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        for part in line.split("&&"):
            part = part.strip()
            if part and not part.startswith(SETUP):
                out.append(part)
    return out


def documented_commands() -> list[tuple[str, str]]:
    """``(document name, command)`` of every bash block, in document order."""
    return [
        (path.name, cmd)
        for path in DOCUMENTS
        for block in bash_blocks(path)
        for cmd in block_commands(block)
    ]


def shown_outputs() -> dict[str, list[str]]:
    """The README's plain ``` blocks that show a command's output (:data:`SHOWN`)."""
    blocks = [text for lang, text in fenced_blocks(DOCUMENTS[0]) if not lang]
    out = {}
    for command, line in SHOWN.items():
        for block in blocks:
            if re.search(line, block, re.M):
                out[command] = block.splitlines()
    return out


def shape(line: str) -> str:
    """A printed line with its numbers (1,234 / 0.16 / 1e-3 / 2356) as ``N``."""
    line = re.sub(r"[-+]?\d[\d,]*(\.\d+)?([eE][-+]?\d+)?", "N", line)
    return " ".join(line.split())


def unmatched_lines(shown: list[str], printed: str) -> list[str]:
    """Lines of a shown output whose shape no printed line has: every line not
    indented (table rows and notes are) and not a Pareto mark; of a ``within``
    line only what comes before its choice."""
    got = {shape(x) for x in printed.splitlines()}
    got_heads = {g.split(":")[0] for g in got}
    missing = []
    for line in shown:
        if not line.strip() or line[0].isspace() or line.startswith("*"):
            continue
        if line.startswith("within "):
            if shape(line).split(":")[0] not in got_heads:
                missing.append(line)
        elif shape(line) not in got:
            missing.append(line)
    return missing


def is_fast(cmd: str) -> bool:
    """A command on descriptor files alone (no image, folder or network)."""
    words = shlex.split(cmd, comments=True)
    if words[:1] != ["rhythmic-jax"] or words[1] not in ("fit", "query", "info",
                                                         "evaluate"):  # fmt: skip
        return False
    images = ("--descriptor", "--tile", "--augment", "--embedding", "names")
    return not any(
        "/" in w or w.lower().endswith(".png") or w in images for w in words[2:]
    )


FILES = (".map", ".emb", ".npy", ".h5", ".npz", ".csv")


def inputs_present(cmd: str, cwd: Path) -> bool:
    """Whether the files a command reads are there (written by the set-up or a
    command before it: a file only an image command writes is not, by default)."""
    words = shlex.split(cmd, comments=True)
    reads = [w for i, w in enumerate(words) if i == 0 or words[i - 1] != "--out"]
    return all((cwd / w).exists() for w in reads if w.endswith(FILES))


# ------------------------------------------------------------- the files named


def _link(frames: list[Path], folder: Path, names=None) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for i, f in enumerate(frames):
        (folder / (names[i] if names else f.name)).symlink_to(f)


def _positions(path: Path, xy: np.ndarray) -> None:
    with open(path, "w", newline="") as f:
        out = csv.writer(f)
        out.writerow(["easting", "northing"])
        out.writerows(xy.tolist())


def _mosaic(files: list[Path], path: Path) -> None:
    """A 3x3 mosaic of 256-pixel RGB crops: one large image to tile."""
    import skimage.io

    tiles = [skimage.io.imread(f)[:256, :256, :3] for f in files[:9]]
    rows = [np.concatenate(tiles[i : i + 3], axis=1) for i in (0, 3, 6)]
    skimage.io.imsave(path, np.concatenate(rows, axis=0), check_contrast=False)


def _hloc(path: Path, x: np.ndarray, prefix: str = "") -> None:
    import h5py

    with h5py.File(path, "a") as f:
        for i, row in enumerate(x):
            f.create_group(f"{prefix}img{i:03d}.jpg")["global_descriptor"] = row


def make_files(cwd: Path, nordland: Path, aerial: Path) -> None:
    """Every file and folder the documented commands name, under ``cwd``."""
    import rhythmic_jax as rj
    from rhythmic_jax.app.cli import main

    summer = sorted((nordland / "summer").iterdir())
    winter = sorted((nordland / "winter").iterdir())
    s, w = [summer[i] for i in PLACES], [winter[i] for i in PLACES]
    n = len(s)
    for name, frames in (("summer", s), ("winter", w), ("spring", w),
                         ("nordland/summer", s), ("nordland/winter", w),
                         ("DATASET/ref", s), ("DATASET/query", w)):  # fmt: skip
        _link(frames, cwd / name)
    _link([summer[i] for i in TRAIN], cwd / "summer_train")
    _link([winter[i] for i in TRAIN], cwd / "winter_train")
    ref_xy = np.stack([EAST + 10.0 * np.arange(n), np.full(n, NORTH)], 1)
    qry_xy = ref_xy + [3.0, 0.0]
    _link(s, cwd / "database", [f"@{e:.0f}@{u:.0f}@d{i:03d}.png"
                                for i, (e, u) in enumerate(ref_xy)])  # fmt: skip
    _link(w, cwd / "queries", [f"@{e:.0f}@{u:.0f}@q{i:03d}.png"
                               for i, (e, u) in enumerate(qry_xy)])  # fmt: skip
    for name, xy in (
        ("ref_positions.csv", ref_xy),
        ("query_positions.csv", qry_xy),
        ("db_positions.csv", ref_xy),
        ("q_positions.csv", qry_xy),
    ):
        _positions(cwd / name, xy)  # fmt: skip
    # RobotCar-style runs of other lengths, positions apart by a few metres
    _link([summer[i] for i in RUNS], cwd / "run1")
    _link([winter[i] for i in RUNS], cwd / "run2")
    _link([winter[i] for i in range(100, 160)], cwd / "run3")
    east = EAST + 10.0 * np.arange(len(RUNS))
    run_xy = np.stack([east, np.full(len(RUNS), NORTH)], 1)
    _positions(cwd / "run1.csv", run_xy)
    _positions(cwd / "run2.csv", run_xy + [4.0, 3.0])
    _positions(cwd / "run3.csv", run_xy[100:160] + [2.0, 0.0])
    # descriptors: patch-normalised pixels of the scored places
    x = rj.describe_frames(cwd / "summer", "patchnorm")
    q = rj.describe_frames(cwd / "winter", "patchnorm")
    for name, rows in (("ref.npy", x), ("queries.npy", q), ("summer.npy", x),
                       ("winter.npy", q), ("database_descriptors.npy", x),
                       ("queries_descriptors.npy", q)):  # fmt: skip
        np.save(cwd / name, rows)
    _hloc(cwd / "global-feats-netvlad-db.h5", x)
    _hloc(cwd / "global-feats-netvlad-q.h5", q)
    _hloc(cwd / "global-feats-netvlad.h5", x, "db/")  # one file holding both
    _hloc(cwd / "global-feats-netvlad.h5", q, "query/")
    near = [np.arange(max(0, i - 1), min(n, i + 2)) for i in range(n)]
    gt = np.empty(n, dtype=object)
    for i in range(n):
        gt[i] = [i, near[i].tolist()]
    np.save(cwd / "DATASET" / "ground_truth_new.npy", gt, allow_pickle=True)
    pos = np.empty(n, dtype=object)
    pos[:] = [a.astype(np.int64) for a in near]
    np.save(cwd / "nordland_gt_25m.npy", pos, allow_pickle=True)
    band = np.abs(np.subtract.outer(np.arange(n), np.arange(n)))
    np.savez(cwd / "GT.npz", GThard=band == 0, GTsoft=band <= 1)
    np.savez(cwd / "pitts30k_test.npz", utmDb=ref_xy, utmQ=qry_xy, posDistThr=25.0)
    pairs = sorted((aerial / "samples_DSIFN").iterdir())
    _mosaic(sorted((pairs[0]).iterdir()), cwd / "city_2019.png")
    _mosaic(sorted((pairs[1]).iterdir()), cwd / "city_2021.png")
    # the map the documents query before they fit it (fit db.h5 comes later)
    assert main(["fit", "ref.npy", "--out", "db.map", "--no-progress"]) == 0


@pytest.fixture()
def doc_folder(nordland_root, aerial_root, tmp_path, monkeypatch):
    """A folder holding the documents' files; the current folder while a test
    runs, with its own descriptor cache."""
    cwd = tmp_path / "work"
    cwd.mkdir()
    monkeypatch.chdir(cwd)
    monkeypatch.setenv("RHYTHMIC_JAX_CACHE", str(tmp_path / "cache"))
    assert (aerial_root / "samples_DSIFN" / "A").is_dir()
    make_files(cwd, nordland_root, aerial_root)
    return cwd


# ------------------------------------------------------------------ the tests


def test_the_documents_are_read_whole():
    """Commands of both documents are found, set-up lines left out, continued
    lines joined, and the README's printed outputs found."""
    cmds = [c for _, c in documented_commands()]
    assert any(c.startswith("rhythmic-jax fit ref.npy") for c in cmds)
    assert "rhythmic-jax demo" in cmds
    assert not any(c.startswith(SETUP) for c in cmds)
    frontier = [c for c in cmds if c.startswith("rhythmic-jax frontier summer.npy")]
    assert frontier and "--plot frontier.png" in frontier[0]
    assert {d for d, _ in documented_commands()} == {"README.md", "usage.md"}
    assert set(shown_outputs()) == set(SHOWN)
    assert any(is_fast(c) for c in cmds) and not all(is_fast(c) for c in cmds)


def test_the_descriptor_file_commands(doc_folder, capsys):
    """The commands on descriptor files, as written, in this process."""
    from rhythmic_jax.app.cli import main

    ran, failed = [], []
    for doc, cmd in documented_commands():
        if not is_fast(cmd) or not inputs_present(cmd, doc_folder):
            continue
        code = main(shlex.split(cmd, comments=True)[1:])
        out, err = capsys.readouterr()
        ran.append(cmd)
        if code != 0:
            failed.append(f"{doc}: {cmd} -> {code}: {err.strip()[-300:]}")
    assert len(ran) >= 8, ran
    assert not failed, "\n".join(failed)


@pytest.mark.slow
def test_every_command_as_written(doc_folder):
    """Every documented command through bash, in order, from the folder of its
    files: each exits 0, and the README's printed outputs keep their shape."""
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env['PATH']}"
    env["PYTHONPATH"] = os.pathsep.join(
        p for p in (str(ROOT), env.get("PYTHONPATH")) if p
    )
    shown = shown_outputs()
    failed = []
    for doc, cmd in documented_commands():
        done = subprocess.run(
            ["bash", "-c", cmd], cwd=doc_folder, env=env, capture_output=True,
            text=True, timeout=900,
        )  # fmt: skip
        if done.returncode != 0:
            failed.append(f"{doc}: {cmd} -> {done.returncode}: "
                          f"{done.stderr.strip()[-400:]}")  # fmt: skip
            continue
        for prefix, lines in shown.items():
            if doc == DOCUMENTS[0].name and cmd.startswith(prefix):
                missing = unmatched_lines(lines, done.stdout)
                if missing:
                    failed.append(
                        f"{doc}: {cmd}: printed no line shaped like "
                        f"{missing[0]!r}:\n{done.stdout[-1500:]}"
                    )
                if cmd == prefix and prefix in FIGURES:
                    failed.extend(figure_differences(lines, done.stdout))
    assert not failed, "\n".join(failed)


# ------------------------------------------- the figures the documents quote

# words of a printed line that say how long something took: never compared
TIMING = (
    re.compile(r"fitted in [\d.]+ s"),
    re.compile(r"[\d.]+ ms\b"),
    re.compile(r"\b\d+ s$"),
    re.compile(r"rhythmic_demo-\d+"),  # the demo's fresh folder, not a figure
)
NUMBER = re.compile(r"[-+]?\d[\d,]*(?:\.\d+)?(?:[eE][-+]?\d+)?")


def figures(line: str) -> list[str]:
    """The numbers of a printed line as printed, its timings left out: the
    ``fitted in`` seconds, every ``ms``, the demo's folder and, in a table row
    (a name, then ten or more numbers), the last column (queries per second)."""
    for pattern in TIMING:
        line = pattern.sub("", line)
    found = NUMBER.findall(line)
    if re.match(r"^[A-Za-z][\w +/.-]*?\s{2,}\d", line) and len(found) >= 10:
        found = found[:-1]
    return found


def figure_differences(shown: list[str], printed: str) -> list[str]:
    """Lines of a shown output whose figures (timings aside) a printed line of
    the same shape does not have: each shown line is paired with the next
    printed line of its shape, in order."""
    lines = printed.splitlines()
    out, at = [], 0
    for line in shown:
        if not line.strip():
            continue
        for j in range(at, len(lines)):
            if shape(lines[j]) == shape(line):
                if figures(lines[j]) != figures(line):
                    out.append(f"README: {line.strip()}\n  run: {lines[j].strip()}")
                at = j + 1
                break
        else:
            out.append(f"README: {line.strip()}\n  run: (no line of this shape)")
    return out


def test_figure_differences_see_a_changed_figure_and_not_a_timing():
    shown = [
        "map: periods (62, 63), 512,500 bytes = 0.1302 of the 3,936,256-byte "
        "database; fitted in 3.2 s",
        "map                0.1613       0.1644       0.2393       0.3850       "
        "0.4495       0.5213       0.1150       0.0125      512,500     0.012 ms"
        "      495,571",
        "map: R@1: 23.9, R@5: 38.5, R@10: 45.0, R@20: 52.1 (over 961 queries)",
    ]
    timing_only = "\n".join(
        [shown[0].replace("3.2 s", "4.7 s"),
         shown[1].replace("0.012 ms", "0.020 ms").replace("495,571", "301,002"),
         shown[2]]
    )  # fmt: skip
    assert figure_differences(shown, timing_only) == []
    stale = timing_only.replace("0.5213", "0.5224").replace("52.1", "52.2")
    assert len(figure_differences(shown, stale)) == 2
    assert figure_differences(shown, "nothing printed")


@pytest.mark.slow
def test_the_demo_prints_the_figures_the_readme_shows(tmp_path):
    """``rhythmic-jax demo`` as the README runs it prints the figures of its
    "What the demo prints" block (accuracy, recall, PR-AUC, bytes, ratios;
    timings aside): a difference fails."""
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env['PATH']}"
    env["PYTHONPATH"] = os.pathsep.join(
        p for p in (str(ROOT), env.get("PYTHONPATH")) if p
    )
    env["RHYTHMIC_JAX_CACHE"] = str(tmp_path / "cache")
    done = subprocess.run(
        ["bash", "-c", "rhythmic-jax demo --no-progress"], cwd=tmp_path, env=env,
        capture_output=True, text=True, timeout=1800,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-1500:]
    shown = shown_outputs()["rhythmic-jax demo"]
    differences = figure_differences(shown, done.stdout)
    assert not differences, "the README's demo block is not what a run prints:\n" + (
        "\n".join(differences)
    )


# a README line ``expression  # -> value`` whose value is a list or dict shown
SHOWN_VALUE = re.compile(r"^(?P<expr>[^#]+?)\s+# -> (?P<value>[\[{].*)$")


def python_script(text: str) -> tuple[str, list[str]]:
    """The README's ```python blocks as one script, each line ``expression  #
    -> [...]`` (or ``{...}``) printing its value; and those values, in order."""
    import ast

    lines, shown = [], []
    for line in text.splitlines():
        m = SHOWN_VALUE.match(line)
        try:
            alone = m is not None and isinstance(ast.parse(m["expr"]).body[0], ast.Expr)
        except SyntaxError:
            alone = False
        if alone:
            lines.append(f"print('SHOWN', {m['expr'].strip()})")
            shown.append(m["value"])
        else:
            lines.append(line)
    return "\n".join(lines) + "\n", shown


def test_the_python_script_prints_the_shown_values():
    """A line showing a list or dict is printed; others are kept as written."""
    script, shown = python_script(
        "x = [1]   # -> [1]\nx   # -> [1]   (a list)\nf(a,  # -> [2]\n"
    )
    assert script.splitlines() == [
        "x = [1]   # -> [1]",
        "print('SHOWN', x)",
        "f(a,  # -> [2]",
    ]
    assert shown == ["[1]   (a list)"]


@pytest.mark.slow
def test_the_readme_python_runs_and_prints_what_it_shows(tmp_path):
    """The README's ```python blocks, in order as one script in a fresh
    interpreter, run; each ``expression  # -> [...]`` / ``{...}`` line prints
    the value its comment shows (the comment may add words after it)."""
    text = "\n".join(t for lang, t in fenced_blocks(DOCUMENTS[0]) if lang == "python")
    script, shown = python_script(text)
    assert len(shown) >= 4
    (tmp_path / "readme.py").write_text(script)
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(
        p for p in (str(ROOT), env.get("PYTHONPATH")) if p
    )
    env["RHYTHMIC_JAX_CACHE"] = str(tmp_path / "cache")
    done = subprocess.run(
        [sys.executable, "readme.py"], cwd=tmp_path, env=env,
        capture_output=True, text=True, timeout=1800,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-1500:]
    printed = [
        x[len("SHOWN ") :] for x in done.stdout.splitlines() if x.startswith("SHOWN ")
    ]
    assert len(printed) == len(shown)
    wrong = [(p, s) for p, s in zip(printed, shown, strict=True) if not s.startswith(p)]
    assert not wrong, f"printed, shown: {wrong}"


# the README's figures quoted from a report's JSON: (report, the README line's
# words, the figures as a function of the JSON, each formatted as the README
# rounds it)
def _row(rows, **match):
    return next(r for r in rows if all(r.get(k) == v for k, v in match.items()))


def _desc(d, name):
    return _row(d["results"], name=name)["recall_at_1"]


QUOTED = [
    ("reproduction.json", "Table 2, Nordland summer self-query", lambda d: [
        f"{_row(d['table2'], level=1, r=2)['accuracy']:.4f}",
        f"{_row(d['table2'], level=2, r=2)['accuracy']:.4f}"]),
    ("reproduction.json", "Table 3, summer self-query", lambda d: [
        f"{_row(d['table3']['rows'], method='map level 1')['summer (self-query)']['batch_queries_per_s']:,.0f}",  # noqa: E501
        f"{_row(d['table3']['rows'], method='brute force')['summer (self-query)']['batch_queries_per_s']:,.0f}",  # noqa: E501
        f"{_row(d['table3']['rows'], method='map level 1')['summer (self-query)']['accuracy']:.3f}",  # noqa: E501
        f"{_row(d['table3']['rows'], method='brute force')['summer (self-query)']['accuracy']:.3f}"]),  # noqa: E501
    ("descriptors.json", "descriptors, Nordland winter -> summer", lambda d: [
        f"{_desc(d, 'patchnorm'):.3f}", f"{_desc(d, 'hog'):.3f}",
        f"{_desc(d, 'efficientnet_lite0'):.3f}"]),
    ("span.json", "EfficientNet-Lite0 3576 x 10976, to the optimum", lambda d: [
        f"{d['rows'][0]['wall_s']:.1f} s", f"{d['rows'][1]['wall_s']:.1f} s",
        f"{d['speedup_wall']:.2f}x"]),
    ("decode.json", "batch decoding vs faiss IndexFlatIP", lambda d: [
        f"{d['cases'][0]['batch_speedup']:.1f}x",
        f"FLOP ratio {d['cases'][0]['flop_ratio']:.1f}"]),
]  # fmt: skip


def readme_line(words: str) -> str:
    lines = [x for x in DOCUMENTS[0].read_text().splitlines() if words in x]
    assert len(lines) == 1, f"README lines with {words!r}: {len(lines)}"
    return lines[0]


@pytest.mark.parametrize("report, words, want", QUOTED, ids=[q[1] for q in QUOTED])
def test_the_readme_shows_the_reports_figures(report, words, want):
    """Each figure the README's results table quotes, read from the report's
    JSON and rounded as the README shows it, is on the README's line."""
    from rhythmic_jax.io.reader import read_json

    data = read_json(ROOT / "reports" / report)
    line = readme_line(words)
    missing = [f for f in want(data) if f not in line]
    assert not missing, f"reports/{report} gives {missing}; README: {line}"


FRONTIER_COLUMNS = {  # README column -> the JSON row's key, the printed format
    "B/place": ("bytes_per_place", "{:,.0f}"),
    "share %": ("share", "{:.2f}"),
    "R@1": ("recall@1 L=1", "{:.4f}"),
    "R@100P": ("recall@100p", "{:.4f}"),
    "R@1 L=5": ("recall@1 L=5", "{:.4f}"),
    "R@1 L=10": ("recall@1 L=10", "{:.4f}"),
}


def readme_frontier() -> list[dict[str, str]]:
    """The README's frontier table (the ``frontier`` block) as rows of
    ``{column: cell}`` (cells right-aligned under their header)."""
    lines = shown_outputs()["rhythmic-jax frontier summer.npy winter.npy"]
    i = next(j for j, x in enumerate(lines) if x.lstrip().startswith("representation"))
    head = lines[i]
    ends = {c: head.index(c) + len(c) for c in FRONTIER_COLUMNS}
    start = min(head.index(c) for c in FRONTIER_COLUMNS)
    rows = []
    for line in lines[i + 1 :]:
        if not line.startswith(("*  ", "   ")):
            break
        row = {"name": line[3:start].strip()}
        row.update({c: line[ends[c] - 9 : ends[c]].split()[-1] for c in ends})
        rows.append(row)
    return rows


def test_the_readme_frontier_table_is_a_reports_rows():
    """The README's frontier table is the rows of a report (the one in
    ``reports/`` holding every row it names): each figure, as the table rounds
    it, is the report's."""
    from rhythmic_jax.io.reader import read_json

    table = readme_frontier()
    assert len(table) >= 5
    names = {r["name"] for r in table}
    best, rows = None, {}
    # benchmark reports, and the saved --json of commands the docs quote (runs/)
    for path in sorted((ROOT / "reports").glob("**/*.json")):
        data = read_json(path)
        got = data.get("rows") if isinstance(data, dict) else None
        if isinstance(got, list) and all(isinstance(r, dict) for r in got):
            named = {r.get("name"): r for r in got}
            if best is None or len(names & set(named)) > len(names & set(rows)):
                best, rows = path, named
    assert best is not None and names <= set(rows), (
        f"rows of the README's frontier table in no report: {sorted(names - set(rows))}"
    )
    stale = []
    for row in table:
        for col, (key, fmt) in FRONTIER_COLUMNS.items():
            value = rows[row["name"]].get(key)
            if key == "share" and value is not None:
                value = 100 * value
            want = "-" if value is None else fmt.format(value)
            if row[col] != want:
                stale.append(
                    f"{row['name']} {col}: README {row[col]}, {best.name} {want}"
                )
    assert not stale, "\n".join(stale)
