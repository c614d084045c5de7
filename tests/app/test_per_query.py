"""Results per query from the command line, on real frames in a corridor layout:
``evaluate --per-query`` (CSV and JSON) with ``--num-preds`` and
``--recall-values``, ``query --csv`` with ``correct``, and ``query --pairs``
in hloc's layout; and the small refusals around ground truth."""

from __future__ import annotations

import csv
import json

import numpy as np

import rhythmic_jax as rj
from rhythmic_jax.app.cli import main


def run(capsys, *argv):
    code = main([*argv, "--no-progress"])
    out, err = capsys.readouterr()
    return code, out, err


def ok(capsys, *argv) -> str:
    code, out, err = run(capsys, *argv)
    assert code == 0, (argv, err)
    return out


def refused(capsys, *argv) -> str:
    code, _, err = run(capsys, *argv)
    assert code == 2 and len(err.strip().splitlines()) == 1, (argv, err)
    return err


def _vpr_bench(path, right: list[list[int]]) -> str:
    """A VPR-Bench ``ground_truth_new.npy``: rows ``[query, [places]]``."""
    gt = np.empty((len(right), 2), object)
    for j, places in enumerate(right):
        gt[j] = [j, places]
    np.save(path, gt, allow_pickle=True)
    return str(path)


def test_evaluate_writes_each_querys_answer(corridor, capsys, monkeypatch):
    """Each query's record: its name and index, the chosen place (the map's
    prediction) and name, the right places (index-aligned, ±1), correct (the
    chosen place among them) and its K best; recall@K recomputed from the
    records' K best is the recall evaluate prints, at the K asked for."""
    monkeypatch.setenv("RHYTHMIC_JAX_CACHE", str(corridor / "cache"))
    c = corridor
    ok(capsys, "fit", str(c / "ref"), "--out", str(c / "m.map"))
    base = ["evaluate", str(c / "m.map"), str(c / "query"), "--tolerance", "1",
            "--num-preds", "7", "--recall-values", "1,2,7"]  # fmt: skip
    result = json.loads(ok(capsys, *base, "--per-query", str(c / "pq.json"), "--json"))
    out = ok(capsys, *base, "--per-query", str(c / "pq.csv"))
    assert out.rstrip().endswith(
        f"each query's result and its 7 best -> {c / 'pq.csv'}"
    )
    assert result["recall_values"] == [1, 2, 7]
    assert "recall@5" not in result["methods"]["map"]
    rows = json.loads((c / "pq.json").read_text())["queries"]
    names = sorted(p.name for p in (c / "query").iterdir())
    assert [r["query"] for r in rows] == names
    assert [r["index"] for r in rows] == list(range(60))
    model = rj.RhythmicMap.load(c / "m.map")
    x = rj.describe_frames(c / "query", "patchnorm")
    assert [r["place"] for r in rows] == model.predict(x).tolist()
    for i, r in enumerate(rows):
        assert r["right_places"] == list(range(max(0, i - 1), min(60, i + 2)))
        assert r["correct"] == (r["place"] in r["right_places"])
        assert len(r["top"]) == 7 and r["place_name"] == (
            names[r["place"]] if r["place"] >= 0 else None
        )
    for k in (1, 2, 7):
        hits = [any(t["place"] in r["right_places"] for t in r["top"][:k])
                for r in rows]  # fmt: skip
        assert np.mean(hits) == result["methods"]["map"][f"recall@{k}"], k
    with open(c / "pq.csv", newline="") as fh:
        table = list(csv.DictReader(fh))
    assert [t["query"] for t in table] == names
    assert [t["correct"] == "True" for t in table] == [r["correct"] for r in rows]
    assert [t["right_places"] for t in table] == [
        " ".join(map(str, r["right_places"])) for r in rows
    ]
    assert [t["top7"] for t in table] == [str(r["top"][6]["place"]) for r in rows]
    assert "--per-query" in refused(capsys, *base, "--per-query", str(c / "pq.txt"))


def test_query_correct_column_and_hloc_pairs(corridor, capsys, monkeypatch):
    """query --csv --ground-truth adds 'correct' (the place among the file's
    right places); query --pairs writes hloc's pairs_from_retrieval layout:
    'query reference' lines, K per query in rank order, joined by newlines."""
    monkeypatch.setenv("RHYTHMIC_JAX_CACHE", str(corridor / "cache"))
    c = corridor
    ok(capsys, "fit", str(c / "ref"), "--out", str(c / "m.map"))
    right = [[i, i + 1] if i % 3 else [] for i in range(59)] + [[59]]
    gt = _vpr_bench(c / "ground_truth_new.npy", right)
    ok(capsys, "query", str(c / "m.map"), str(c / "query"), "--csv",
       str(c / "r.csv"), "--ground-truth", gt, "--top", "3")  # fmt: skip
    with open(c / "r.csv", newline="") as fh:
        table = list(csv.DictReader(fh))
    assert list(table[0])[:6] == ["query", "place", "place_name", "score",
                                  "confidence", "correct"]  # fmt: skip
    want = [str(int(t["place"]) in right[i]) for i, t in enumerate(table)]
    assert [t["correct"] for t in table] == want
    out = ok(capsys, "query", str(c / "m.map"), str(c / "query"), "--pairs",
             str(c / "pairs.txt"), "--top", "4")  # fmt: skip
    assert "pairs.txt (hloc retrieval pairs, 4 per query)" in out
    text = (c / "pairs.txt").read_text()
    assert not text.endswith("\n")  # hloc joins its lines with newlines
    pairs = [line.split() for line in text.split("\n")]
    names = sorted(p.name for p in (c / "query").iterdir())
    assert [q for q, _ in pairs] == [n for n in names for _ in range(4)]
    top = {r["query"]: [t["name"] for t in r["top"]] for r in json.loads(ok(
        capsys, "query", str(c / "m.map"), str(c / "query"), "--json", "--top",
        "4"))["queries"]}  # fmt: skip
    assert [r for _, r in pairs] == [n for q in names for n in top[q]]


def test_ground_truth_refusals_say_what_is_wrong(corridor, capsys, monkeypatch):
    """--tolerance-m with VPR-Bench lists (it would act on nothing) and a file
    of no ground-truth format are refused in one line that says so."""
    monkeypatch.setenv("RHYTHMIC_JAX_CACHE", str(corridor / "cache"))
    c = corridor
    ok(capsys, "fit", str(c / "ref"), "--out", str(c / "m.map"))
    gt = _vpr_bench(c / "ground_truth_new.npy", [[i] for i in range(60)])
    ev = ["evaluate", str(c / "m.map"), str(c / "query"), "--ground-truth"]
    err = refused(capsys, *ev, gt, "--tolerance-m", "10")
    assert "--tolerance-m acts on positions" in err and "act on nothing" in err
    (c / "ReadMe.txt").write_text("Nordland frames, summer and winter.\n")
    err = refused(capsys, *ev, str(c / "ReadMe.txt"))
    assert "not a ground-truth file" in err and "reference positions" not in err
    ok(capsys, *ev, gt)


def test_verbose_after_the_command(corridor, capsys):
    """-v/--verbose is taken after the command's name and listed in its help."""
    c = corridor
    code = main(["fit", str(c / "ref"), "--out", str(c / "m.map"), "-v",
                 "--no-progress"])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    capsys.readouterr()
    for command in ("fit", "query", "evaluate", "describe", "info", "frontier"):
        assert main([command, "--help"]) == 0
        assert "-v, --verbose" in capsys.readouterr().out, command
