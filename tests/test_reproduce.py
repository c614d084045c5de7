"""scripts/reproduce.py: its numbers are the library's numbers.

The default tests check the Table 1 arithmetic against the paper's printed bytes,
the Markdown renderer and the candidate count for r = 5. The slow test runs the
quick reproduction into a temporary folder and checks the report against the
library: Table 1 bytes against ``storage_bytes``, the named periods against the
saved maps and a fresh fit, every accuracy against the saved predictions, and the
Markdown against the JSON.
"""

from __future__ import annotations

import importlib.util
import itertools
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

import rhythmic_jax as rj
from rhythmic_jax.eval.metrics import accuracy

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "reproduce.py"


@pytest.fixture(scope="module")
def repro():
    sys.path.insert(0, str(SCRIPT.parent))  # the scripts' harness
    spec = importlib.util.spec_from_file_location("reproduce", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules["reproduce"] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    yield module
    sys.modules.pop("reproduce", None)
    sys.path.remove(str(SCRIPT.parent))


def test_table1_paper_rows_are_the_library_bytes(repro):
    rows = repro.table1_paper()
    assert [r["name"] for r in rows] == [p[0] for p in repro.PAPER_TABLE1]
    for row, (_, n, periods, orig, comp, printed) in zip(
        rows, repro.PAPER_TABLE1, strict=True
    ):
        assert row["compressed_bytes"] == rj.storage_bytes(periods, 4096)
        assert row["compressed_bytes"] == sum(periods) * 4097 * 4
        assert row["original_bytes"] == rj.database_bytes(n, 4096) == n * 4096 * 4
        # the paper's printed bytes are exactly the library's
        assert (row["original_bytes"], row["compressed_bytes"]) == (orig, comp)
        assert row["bytes_match"]
        assert row["ratio"] == pytest.approx(comp / orig, rel=1e-12)
        assert row["printed_ratio"] == printed
    flags = {r["name"]: r["flag"] for r in rows}
    assert flags["Nordland spring"].startswith("misprint")
    assert "0.0197" in flags["Nordland spring"]
    assert flags["Nordland summer"].startswith("rounding slip")
    assert "0.0245" in flags["Nordland summer"]
    assert round(2_966_228 / 121_290_752, 4) == 0.0245  # what the flag claims
    for name in ("Nordland fall", "Nordland winter", "Aerial Brisbane"):
        assert flags[name] == ""


def test_table1_markdown_holds_every_number(repro):
    rows = repro.table1_paper()
    here = [repro.storage_row("run", 3576, 2048, (61, 65))]
    here[0]["ratio_d4096"] = rj.compression_ratio((61, 65), 3576, 4096)
    md = repro.h.render("Table 1", {}, *repro.h.figures(dict(paper=rows, here=here)))
    for r in rows + here:
        assert str(r["original_bytes"]) in md and str(r["compressed_bytes"]) in md
        assert r["name"] in md and repro.h._cell(r["ratio"]) in md
        assert repro.h._cell(r.get("printed_ratio", r.get("ratio_d4096"))) in md
    assert str(126 * 2049 * 4) in md and str(3576 * 2048 * 4) in md
    for table in md.split("\n\n"):  # every row of a table has its columns
        if table.startswith("|"):
            assert len({line.count("|") for line in table.splitlines()}) == 1


def test_tables_format_lists_fractions_and_alignment(repro):
    rows = [[2, "3, 5", "12.30, 500.00", 0.123456]]
    heads = ["r", "periods", "e", "acc"]
    assert repro.h.table(heads, rows).splitlines() == [
        "| r | periods | e | acc |",
        "|---:|---|---|---:|",
        "| 2 | 3, 5 | 12.30, 500.00 | 0.1235 |",
    ]
    assert repro.h.table(heads, rows, "lr").splitlines()[1] == "|---|---:|---|---|"


def test_min_count_matches_a_brute_force_search(repro):
    def feasible(n, r, level, count):
        cands = rj.candidate_periods(n, r, level, count)
        return any(
            math.prod(c) >= n and rj.pairwise_coprime(c)
            for c in itertools.combinations(cands, r)
        )

    for n, r in ((3576, 5), (3576, 3), (600, 5), (769, 3), (7403, 2)):
        count = repro.min_count(n, r, 1)
        assert count >= 7 and feasible(n, r, 1, count)
        assert count == 7 or not feasible(n, r, 1, count - 1)
    assert repro.min_count(3576, 5, 1) == 8  # 6..12 hold no 5 co-prime periods


def _records(node, key):
    """Every dict in a JSON tree that has ``key``."""
    if isinstance(node, dict):
        if key in node:
            yield node
        for v in node.values():
            yield from _records(v, key)
    elif isinstance(node, list):
        for v in node:
            yield from _records(v, key)


@pytest.mark.slow
def test_quick_reproduction_agrees_with_the_library(
    repro, nordland_root, aerial_root, tmp_path
):
    preds_path = tmp_path / "predictions.npz"
    repro.main(
        ["--quick", "--out", str(tmp_path), "--predictions", str(preds_path)]
        + ["--no-progress"]
    )
    res = json.loads((tmp_path / "reproduction_quick.json").read_text())
    md = (tmp_path / "REPRODUCTION_quick.md").read_text()
    for name in res["figures"]:
        assert (tmp_path / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    # Table 1: bytes are storage_bytes / database_bytes of the named periods
    for row in res["table1"]["paper"] + res["table1"]["here"]:
        assert row["compressed_bytes"] == rj.storage_bytes(row["periods"], row["d"])
        assert row["original_bytes"] == rj.database_bytes(row["n"], row["d"])
        assert str(row["compressed_bytes"]) in md

    # every map the report names: reloaded, its periods and errors are the JSON's
    maps = list(_records(res, "map_path"))
    assert len(maps) >= 12
    for rec in maps:
        model = rj.RhythmicMap.load(rec["map_path"])
        assert list(model.periods) == rec["periods"]
        assert list(model.candidate_errors) == rec["candidate_errors"]
        assert model.storage_bytes == rec["storage_bytes"]
        assert model.storage_bytes == rj.storage_bytes(model.periods, model.d)

    # a fresh fit with the same settings chooses the periods the report names
    from rhythmic_jax.frames.features import describe, get_descriptor
    from rhythmic_jax.io.images import nordland

    summer, _ = nordland(nordland_root, progress=False)
    x = describe(summer.images[:600], get_descriptor("patchnorm"), progress=False)
    fresh = rj.RhythmicMap(r=2, level=1).fit(x, progress=False)
    t2 = next(
        r
        for r in res["table2"]
        if r["dataset"] == "Nordland summer" and r["level"] == 1
    )
    assert list(fresh.periods) == t2["periods"]
    np.testing.assert_allclose(
        fresh.candidate_errors, t2["candidate_errors"], atol=2e-3
    )
    assert accuracy(fresh.predict(x), np.arange(600)) == pytest.approx(
        t2["accuracy"], abs=2e-3
    )

    # every accuracy equals the one recomputed from the saved predictions
    preds = np.load(preds_path, allow_pickle=False)
    scored = [r for r in _records(res, "predictions") if "accuracy" in r]
    assert len(scored) >= 20
    for rec in scored:
        key = rec["predictions"]
        pred, gt = preds[key], preds[key + "_gt"]
        assert len(pred) == rec["n_queries"]
        assert accuracy(pred, gt, rec["tolerance"]) == rec["accuracy"]
        assert repro.h._cell(rec["accuracy"]) in md

    # the Markdown carries the named periods and the Table 3 timings
    for rec in res["table2"]:
        assert ", ".join(map(str, rec["periods"])) in md
    for row in res["table3"]["rows"]:
        for label in res["table3"]["query_sets"]:
            assert f"{row[label]['batch_queries_per_s']:,.0f}" in md
    assert "scripts/bench_decode.py decoders" in md
    assert res["settings"]["frames"] == 600 and res["meta"]["frames"] == 600


def test_figures_draw_the_numbers_given(tmp_path):
    from rhythmic_jax.eval import figures

    fig = figures.plot_training_error(
        {"level 1": ([5, 6, 7], [0.1, 0.05, 0.2], [5, 6])}, path=tmp_path / "f3.png"
    )
    line, chosen = fig.axes[0].get_lines()
    np.testing.assert_allclose(line.get_ydata(), [10.0, 5.0, 20.0])
    np.testing.assert_array_equal(chosen.get_xdata(), [5, 6])
    fig = figures.plot_r([2, 3], [0.1, 0.05], [0.9, 0.5], path=tmp_path / "f4.png")
    heights = [[p.get_height() for p in ax.patches] for ax in fig.axes]
    np.testing.assert_allclose(heights, [[0.1, 0.05], [0.9, 0.5]])
    fig = figures.plot_augmentation(
        ["none", "hflip"], [0.2, 0.3], {"brute force": 0.5}, path=tmp_path / "f6.png"
    )
    np.testing.assert_allclose(
        [p.get_height() for p in fig.axes[0].patches], [0.2, 0.3]
    )
    assert fig.axes[0].get_lines()[0].get_ydata()[0] == 0.5
    series = {"a": dict(levels=[1, 2], accuracy=[0.1, 0.2], ratio=[0.05, 0.1])}
    fig = figures.plot_levels(series, path=tmp_path / "f8.png")
    np.testing.assert_allclose(fig.axes[1].get_lines()[0].get_ydata(), [0.05, 0.1])
    for name in ("f3", "f4", "f6", "f8"):
        assert (tmp_path / f"{name}.png").read_bytes()[:4] == b"\x89PNG"
    assert not list(tmp_path.glob("*.tmp*"))
    with pytest.raises(rj.InputError, match="must end in .png"):
        figures.save_figure(fig, tmp_path / "f.jpg")
    with pytest.raises(rj.InputError, match="2 periods, 1 errors"):
        figures.plot_training_error({"x": ([1, 2], [0.1], [])})
