"""``rhythmic-jax frontier``: every representation's recall against its bytes,
the Pareto front, the choice under a budget, JSON, CSV and the plot."""

from __future__ import annotations

import csv
import json
import os
import re
import shutil
import subprocess

import numpy as np
import pytest

from rhythmic_jax.app.cli import main
from rhythmic_jax.eval.frontier import choose, pareto_front

N, D = 90, 16


@pytest.fixture(scope="module")
def route(tmp_path_factory):
    """A route of N places; queries are the places seen again with noise."""
    rng = np.random.default_rng(0)
    walk = np.cumsum(rng.standard_normal((N, D)), axis=0).astype(np.float32)
    walk -= walk.mean(axis=0)  # centred: the fit's scale check refuses an offset
    ref = walk + 0.3 * rng.standard_normal((N, D)).astype(np.float32)
    qry = walk + 0.8 * rng.standard_normal((N, D)).astype(np.float32)
    folder = tmp_path_factory.mktemp("route")
    np.save(folder / "ref.npy", ref)
    np.save(folder / "qry.npy", qry)
    return folder, ref, qry


def test_frontier_command_table_json_csv_plot(route, capsys):
    folder, ref, qry = route
    args = ["frontier", str(folder / "ref.npy"), str(folder / "qry.npy"),
            "--maps", "2:1,2:2", "--bits", "8,16", "--pq", "4,8",
            "--lengths", "1,5", "--tolerance", "1", "--budget", "40",
            "--no-progress"]  # fmt: skip
    csv_path, png = folder / "f.csv", folder / "f.png"
    assert main([*args, "--json", "--csv", str(csv_path), "--plot", str(png)]) == 0
    result = json.loads(capsys.readouterr().out)
    rows = {r["name"]: r for r in result["rows"]}
    kinds = {r["kind"] for r in result["rows"]}
    assert kinds == {"brute force", "SeqSLAM", "map", "codes", "hybrid"}
    assert {"PQ 4x6 bits", "PQ 8x6 bits", "int8 per place", "ITQ 8 bits"} <= set(rows)
    assert any("float16" in n for n in rows) and any("int8 +" in n for n in rows)
    # brute force against numpy float64: right within one frame
    sims = qry.astype(np.float64) @ ref.astype(np.float64).T
    want = np.mean(np.abs(sims.argmax(1) - np.arange(N)) <= 1)
    assert rows["brute force"]["recall@1 L=1"] == pytest.approx(want)
    assert rows["brute force"]["bytes_per_place"] == D * 4
    # the Pareto front by brute force over every pair of rows
    key = "recall@1 L=1"
    for r in result["rows"]:
        beaten = any(
            o[key] is not None and o["storage_bytes"] <= r["storage_bytes"]
            and o[key] >= r[key]
            and (o["storage_bytes"] < r["storage_bytes"] or o[key] > r[key])
            for o in result["rows"]
        )  # fmt: skip
        assert r["pareto"] == (not beaten), r["name"]
    fits = [r for r in result["rows"] if r["bytes_per_place"] <= 40]
    assert result["choice"] == max(fits, key=lambda r: r[key])["name"]
    for r in result["rows"]:
        assert r["kind"] == "SeqSLAM" or 0 <= r["recall@100p"] <= r[key] + 1e-12
    with csv_path.open() as f:
        lines = list(csv.DictReader(f))
    assert [x["name"] for x in lines] == [r["name"] for r in result["rows"]]
    scorers = {r["kind"]: r["sequence_scorer"] for r in result["rows"]}
    assert scorers == {"brute force": "diagonal sum", "SeqSLAM": "SeqSLAM",
                       "map": "phase domain", "codes": "diagonal sum",
                       "hybrid": "phase domain + diagonal sum, fused"}  # fmt: skip
    assert [x["sequence_scorer"] for x in lines] == [
        r["sequence_scorer"] for r in result["rows"]
    ]
    assert png.stat().st_size > 10_000
    assert main(args) == 0
    text = capsys.readouterr().out
    assert f"within 40 bytes per place: {result['choice']}" in text
    assert "* Pareto front" in text and "tolerance ±1 frames" in text
    head = text.splitlines()[1]
    assert "sequence scorer" in head and "diagonal sum" in text


def test_the_default_grid_and_faiss_warnings_in_one_line(route, capfd):
    """Without --maps/--bits/--pq the small grid is fitted (codes wider than d
    left out); faiss's k-means warnings (PQ trained on 90 points) reach stderr
    as one note line of the table, never one line each."""
    from rhythmic_jax.app.specs import GRIDS

    folder, _, _ = route
    base = ["frontier", str(folder / "ref.npy"), str(folder / "qry.npy"),
            "--lengths", "1", "--no-progress"]  # fmt: skip
    assert main([*base, "--json"]) == 0
    out, err = capfd.readouterr()
    result = json.loads(out)
    assert [tuple(m) for m in result["config"]["maps"]] == list(GRIDS["small"]["maps"])
    assert result["config"]["bits"] == [] and result["config"]["pq"] == [16]
    assert any(line.startswith("PQ 32") for line in result["skipped"])  # 32 ∤ d
    assert "PQ 16x6 bits" in {r["name"] for r in result["rows"]}
    assert "WARNING clustering" not in err
    assert len(result["notes"]) == 1 and "faiss warned" in result["notes"][0]
    assert "64 centroids from 90 points" in result["notes"][0]
    assert main([*base, "--grid", "full", "--bits", "8", "--pq", "", "--json"]) == 0
    out, err = capfd.readouterr()
    result = json.loads(out)
    assert [tuple(m) for m in result["config"]["maps"]] == list(GRIDS["full"]["maps"])
    assert result["config"]["bits"] == [8] and result["config"]["pq"] == []
    assert "WARNING clustering" not in err and result["notes"] == []


def test_frontier_refuses_in_one_line(route, capsys):
    folder, _, _ = route
    base = ["frontier", str(folder / "ref.npy"), str(folder / "qry.npy")]
    assert main([*base, "--bits", "a,b"]) == 2
    err = capsys.readouterr().err
    assert "--bits: expected comma-separated integers, got 'a,b'" in err
    assert main([*base, "--plot", str(folder / "f.pdf")]) == 2
    assert "--plot" in capsys.readouterr().err
    np.save(folder / "wide.npy", np.zeros((5, D + 1), np.float32))
    assert main(["frontier", str(folder / "ref.npy"), str(folder / "wide.npy")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "17-d descriptors" in err


def test_choose_and_pareto_by_hand():
    rows = [
        {"name": "a", "storage_bytes": 10, "bytes_per_place": 1, "recall@1 L=1": 0.2},
        {"name": "b", "storage_bytes": 20, "bytes_per_place": 2, "recall@1 L=1": 0.1},
        {"name": "c", "storage_bytes": 30, "bytes_per_place": 3, "recall@1 L=1": 0.5},
    ]
    assert pareto_front(rows) == [True, False, True]
    assert choose(rows, 2.5)["name"] == "a" and choose(rows, 0.5) is None


@pytest.mark.slow
def test_installed_command_on_nordland_frames(nordland_root, tmp_path):
    """The installed command on real frames (image folders), run elsewhere."""
    exe = shutil.which("rhythmic-jax")
    if exe is None:
        pytest.skip("the rhythmic-jax command is not installed")
    for season in ("summer", "winter"):
        (tmp_path / season).mkdir()
        names = sorted(os.listdir(nordland_root / season))[1300:1420]
        for name in names:
            shutil.copy(nordland_root / season / name, tmp_path / season / name)
    run = subprocess.run(
        [exe, "frontier", "summer", "winter", "--tolerance", "1", "--maps", "2:1",
         "--bits", "64", "--pq", "8", "--lengths", "1,5", "--json", "--no-progress"],
        cwd=tmp_path, capture_output=True, text=True, timeout=900,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    result = json.loads(run.stdout)
    rows = {r["name"]: r for r in result["rows"]}
    assert result["n"] == result["n_queries"] == 120
    best = max(r["recall@1 L=1"] for r in result["rows"])
    assert any(r["pareto"] and r["recall@1 L=1"] == best for r in result["rows"])
    assert rows["brute force"]["recall@1 L=1"] > 0.1  # winter against summer


def test_numeric_options_have_domains(route, capsys):
    """--pq 0, --lengths 0 and lengths beyond the queries: one line, exit 2."""
    folder, _, _ = route
    base = ["frontier", str(folder / "ref.npy"), str(folder / "qry.npy"),
            "--no-progress"]  # fmt: skip
    cases = [(["--pq", "0"], "--pq: must be comma-separated integers >= 1"),
             (["--pq", "8,-1"], "got -1"),
             (["--lengths", "1,0"], "--lengths: must be"),
             (["--bits", "0"], "--bits: must be"),
             (["--lengths", str(N + 1)], f"longer than the {N} queries"),
             (["--lengths", "9223372036854775808"], "in [1, 2147483647]")]  # fmt: skip
    for args, said in cases:
        assert main([*base, *args]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and said in err, (args, err)


def test_cache_that_is_an_input_is_refused(route, capsys, tmp_path):
    folder, _, _ = route
    ref = str(folder / "ref.npy")
    for cache in (ref, str(folder / "ref.npy" / "sub")):
        code = main(["frontier", ref, str(folder / "qry.npy"), "--cache", cache,
                     "--no-progress"])  # fmt: skip
        err = capsys.readouterr().err
        assert code == 2 and err.count("\n") == 1 and "--cache" in err, err
    images = tmp_path / "images"
    images.mkdir()
    from rhythmic_jax.app.frontier import check_cache
    from rhythmic_jax.errors import InputError

    with pytest.raises(InputError, match="is there"):
        check_cache(str(images / "cache"), [str(images), ref])
    check_cache(str(tmp_path / "cache"), [str(images), ref])  # a folder of its own


def test_header_names_listed_ground_truth_and_bytes_share_one_database(route, capsys):
    """A ground truth listing the right places: no 'None' in the header; every
    row's share is its bytes over brute force's (the one database searched)."""
    folder, _, _ = route
    gt = np.empty((N, 2), object)
    for j in range(N):
        gt[j] = [j, [p for p in (j - 1, j, j + 1) if 0 <= p < N]]
    np.save(folder / "gt.npy", gt, allow_pickle=True)
    args = ["frontier", str(folder / "ref.npy"), str(folder / "qry.npy"),
            "--ground-truth", str(folder / "gt.npy"), "--ground-truth-format",
            "vpr-bench", "--maps", "2:1", "--bits", "8", "--pq", "",
            "--lengths", "1", "--no-progress"]  # fmt: skip
    assert main(args) == 0
    text = capsys.readouterr().out
    head = text.splitlines()[0]
    assert "None" not in text and "the right places it lists" in head
    assert "ms/query: one query alone" in text
    assert main([*args, "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)["rows"]
    brute = next(r for r in rows if r["kind"] == "brute force")
    assert brute["storage_bytes"] == N * D * 4
    for r in rows:
        assert r["share"] == pytest.approx(r["storage_bytes"] / brute["storage_bytes"])
        assert "ITQ" not in r["name"] or "int8" not in r["name"].split("+")[-1]
    assert any(r["name"] == "int8 per place" for r in rows)


def test_maps_option_has_a_domain(route, capsys):
    """--maps pairs are read where the options are: r below 2, level below 1,
    values past the integer limit and pairs that are not r:level end in one
    line naming the option; r and level in range but beyond the route are
    refused by the fit in one line too."""
    folder, _, _ = route
    base = ["frontier", str(folder / "ref.npy"), str(folder / "qry.npy"),
            "--bits", "8", "--pq", "", "--lengths", "1", "--no-progress"]  # fmt: skip
    cases = [("1:1", "r must be an integer >= 2, got 1"),
             ("2:1,2:0", "level must be an integer >= 1, got 0"),
             ("2:-3", "got -3"),
             ("9223372036854775808:1", "r must be an integer in [2, 2147483647]"),
             ("2:99999999999999999999", "level must be an integer in [1, 2147483647]"),
             ("2", "expected comma-separated r:level pairs, got '2'"),
             ("2:1:1", "expected comma-separated r:level pairs"),
             ("a:b", "expected comma-separated r:level pairs"),
             ("2:1,", "expected comma-separated r:level pairs"),
             ("", "expected comma-separated r:level pairs"),
             ("2147483647:1", "count must be an integer >= r=2147483647")]  # fmt: skip
    for maps, said in cases:
        assert main([*base, "--maps", maps]) == 2, maps
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and said in err, (maps, err)
        assert "--maps" in err or "count" in err, (maps, err)


def _numpy_recall_at(ref, qry, right, k):
    """Brute force's recall@k by float64 numpy: a right place among the k most
    similar (``right[i]``: query i's right places)."""
    sims = qry.astype(np.float64) @ ref.astype(np.float64).T
    top = np.argsort(-sims, axis=1)[:, :k]
    return np.mean([bool(set(t) & set(r)) for t, r in zip(top, right, strict=True)])


def test_recall_values_on_every_ranking_row(route, capsys):
    """recall@K of the single-frame ranking on every row but SeqSLAM, brute
    force's against numpy (index-aligned within one frame, and a ground truth
    listing the right places); recall@N is 1 for every row (every place is
    among the N best), recall@K grows with K; the table shows R@K only when
    --recall-values is given; the CSV has the columns."""
    folder, ref, qry = route
    base = ["frontier", str(folder / "ref.npy"), str(folder / "qry.npy"),
            "--maps", "2:1", "--bits", "8", "--pq", "4", "--lengths", "1,5",
            "--no-progress"]  # fmt: skip
    csv_path = folder / "k.csv"
    given = [*base, "--tolerance", "1", "--recall-values", f"1,5,10,{N},{N + 1}"]
    assert main([*given, "--json", "--csv", str(csv_path)]) == 0
    rows = json.loads(capsys.readouterr().out)["rows"]
    near = [[p for p in (i - 1, i, i + 1) if 0 <= p < N] for i in range(N)]
    brute = next(r for r in rows if r["kind"] == "brute force")
    for k in (5, 10):
        want = _numpy_recall_at(ref, qry, near, k)
        assert brute[f"recall@{k} L=1"] == pytest.approx(want), k
    kinds = set()
    for r in rows:
        if r["kind"] == "SeqSLAM":
            assert "recall@5 L=1" not in r
            continue
        kinds.add(r["kind"])
        got = [r["recall@1 L=1"], r["recall@5 L=1"], r["recall@10 L=1"]]
        assert got == sorted(got), r["name"]
        assert r[f"recall@{N} L=1"] == 1.0, r["name"]
        assert f"recall@{N + 1} L=1" not in r  # more than the places: left out
    assert kinds == {"brute force", "map", "codes", "hybrid"}
    with csv_path.open() as f:
        lines = list(csv.DictReader(f))
    assert [float(x["recall@5 L=1"] or "nan") for x in lines[:1]] == [
        pytest.approx(rows[0]["recall@5 L=1"])
    ]
    head = list(lines[0])
    assert head.index("recall@5 L=1") == head.index("recall@1 L=1") + 1
    assert main(given) == 0
    heads = re.split(r"\s{2,}", capsys.readouterr().out.splitlines()[1].strip())
    assert heads[3:8] == ["R@1", "R@5", "R@10", f"R@{N}", "R@100P"]
    assert main([*base, "--tolerance", "1"]) == 0
    heads = re.split(r"\s{2,}", capsys.readouterr().out.splitlines()[1].strip())
    assert heads[3:6] == ["R@1", "R@100P", "R@1 L=5"]
    # a ground truth that lists each query's right places (VPR-Bench)
    lists = [[p for p in (j - 2, j, j + 3) if 0 <= p < N] for j in range(N)]
    gt = np.empty((N, 2), object)
    for j in range(N):
        gt[j] = [j, lists[j]]
    np.save(folder / "gt_k.npy", gt, allow_pickle=True)
    assert main([*base, "--ground-truth", str(folder / "gt_k.npy"),
                 "--recall-values", "5", "--json"]) == 0  # fmt: skip
    rows = json.loads(capsys.readouterr().out)["rows"]
    brute = next(r for r in rows if r["kind"] == "brute force")
    assert brute["recall@5 L=1"] == pytest.approx(_numpy_recall_at(ref, qry, lists, 5))
    assert main([*base, "--recall-values", "0,5"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--recall-values" in err


def test_tolerance_m_refused_where_it_acts_on_nothing(route, capsys):
    """--tolerance-m with a ground truth that lists the right places itself
    (VPR-Bench) is refused in one line, as evaluate and query refuse it."""
    folder, _, _ = route
    gt = np.empty((N, 2), object)
    for j in range(N):
        gt[j] = [j, [j]]
    np.save(folder / "gt_m.npy", gt, allow_pickle=True)
    base = ["frontier", str(folder / "ref.npy"), str(folder / "qry.npy"),
            "--ground-truth", str(folder / "gt_m.npy"), "--maps", "2:1", "--bits",
            "8", "--pq", "", "--lengths", "1", "--no-progress"]  # fmt: skip
    assert main([*base, "--tolerance-m", "10"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--tolerance-m" in err
    assert "would act on nothing" in err
    assert main([*base, "--json"]) == 0
    json.loads(capsys.readouterr().out)


def test_input_size_of_image_folders(corridor, capsys):
    """--input-size resizes image folders for the descriptor: patchnorm at
    32x16 gives 512-d rows, and the rows are those describe writes at that size
    (its files then frontier's: the same brute force); a described file of
    another size is refused in one line, as is a malformed size."""
    ref, query = corridor / "ref", corridor / "query"
    base = ["--maps", "2:1", "--bits", "8", "--pq", "", "--lengths", "1",
            "--no-progress", "--json"]  # fmt: skip
    assert main(["frontier", str(ref), str(query), "--input-size", "32x16",
                 *base]) == 0  # fmt: skip
    got = json.loads(capsys.readouterr().out)
    assert got["d"] == 32 * 16 and got["n"] == 60
    for name, folder in (("r.npy", ref), ("q.npy", query)):
        out = corridor / name
        assert main(["describe", str(folder), "--out", str(out), "--input-size",
                     "32x16"]) == 0  # fmt: skip
    capsys.readouterr()
    r, q = np.load(corridor / "r.npy"), np.load(corridor / "q.npy")
    assert r.shape == (60, 512)
    assert main(["frontier", str(corridor / "r.npy"), str(corridor / "q.npy"),
                 *base]) == 0  # fmt: skip
    files = json.loads(capsys.readouterr().out)
    brute = [next(x for x in res["rows"] if x["kind"] == "brute force")
             for res in (got, files)]  # fmt: skip
    want = np.mean((q.astype(np.float64) @ r.astype(np.float64).T).argmax(1)
                   == np.arange(60))  # fmt: skip
    assert brute[0]["recall@1 L=1"] == brute[1]["recall@1 L=1"] == pytest.approx(want)
    assert main(["frontier", str(corridor / "r.npy"), str(corridor / "q.npy"),
                 "--input-size", "64x32", *base]) == 2  # fmt: skip
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "32x16" in err
    assert main(["frontier", str(ref), str(query), "--input-size", "64", *base]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--input-size" in err
