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
TRAIN = range(0, 150)  # the training route, places apart from the scored ones
RUNS = range(0, 300)  # the RobotCar-style runs (500 places from 600 frames)
EAST, NORTH = 500_000, 7_000_000  # metres: place i lies at EAST + 10 i
# the README's printed outputs: the README command they belong to (its start)
# -> a line of the output block
SHOWN = {
    "rhythmic-jax demo": r"^map: periods",
    "rhythmic-jax frontier summer.npy winter.npy": r"places of .*queries; ground",
}


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
    for name, xy in (("ref_positions.csv", ref_xy), ("query_positions.csv", qry_xy),
                     ("db_positions.csv", ref_xy), ("q_positions.csv", qry_xy)):
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
                    failed.append(f"{doc}: {cmd}: printed no line shaped like "
                                  f"{missing[0]!r}:\n{done.stdout[-1500:]}")
    assert not failed, "\n".join(failed)
