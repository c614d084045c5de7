"""An oracle for every figure ``evaluate``, ``frontier`` and the demo print.

Each command runs as a user runs it, on a real route (400 Nordland places,
summer frames as the reference, winter frames as the queries, patch-normalised
descriptors written to ``.npy``; the demo on its own mosaic), and every figure it
prints is recomputed here from the raw arrays with numpy alone: the map's
templates as ``rj.load`` reads them, the descriptors, and the per-query answers
(``query --json``, ``rj.decode``). Nothing of ``rhythmic_jax.eval`` computes a
figure here. The definitions, as the package documents them:

* recall@K: a right place (``|place - i| <= tolerance``) among the K best, out
  of the queries with a right place (every query here);
* accuracy: the answer is the right place exactly (a -1, no match, is wrong);
  ``acc_tol`` within the tolerance;
* the PR curve of single-best answers: a query answered (not -1) is retrieved
  when its confidence is at least the threshold, every distinct confidence a
  threshold, precision = right / retrieved, recall = right / queries with a
  right place, and the point (recall 0, precision 1) added; R@100P is the
  largest recall at precision exactly 1, PR-AUC the trapezoid area under it
  (VPR_Tutorial's ``createPR`` and ``np.trapz``);
* bytes: float32 templates ``sum(periods) (d + 1) 4``, float16 half that, int8
  ``sum(periods) (d + 1)`` plus a float32 scale per template; the database
  ``n d 4``; shares are bytes over the database's bytes; per place over n.

Latencies are bounded by arithmetic: this machine's float32 GEMM speed is
measured here (numpy, best of a few), and no method's printed time may be below
the multiply-adds its own products need at four times that speed.

Printed tables are read by their column names, so added rows and columns keep
this working. Marked ``slow`` (about two minutes on 2 cores); skipped, with the
reason, without ``../shared/data``.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
PLACES = range(1000, 1400)  # 400 Nordland places
TOL = 1
KS = (1, 5, 10, 20)
SPEEDUP = 4.0  # no time below the products' flops at 4x the measured GEMM speed

pytestmark = pytest.mark.slow


# ----------------------------------------------------------- running commands


def run_cli(*args: str, cwd: Path) -> str:
    """``rhythmic-jax ARGS`` in a fresh process (this checkout imported); its
    stdout, after asserting exit status 0."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(
        p for p in (str(ROOT), env.get("PYTHONPATH")) if p
    )
    env["RHYTHMIC_JAX_CACHE"] = str(cwd / "cache")
    code = "import sys; from rhythmic_jax.app.cli import main; sys.exit(main())"
    done = subprocess.run(
        [sys.executable, "-c", code, *args], cwd=cwd, env=env,
        capture_output=True, text=True, timeout=900,
    )  # fmt: skip
    assert done.returncode == 0, f"{args}: {done.stderr[-1500:]}"
    return done.stdout


def printed_table(text: str, first: str = "method") -> list[dict[str, str]]:
    """Every table of ``text`` whose header starts with ``first``, as rows of
    ``{column: cell}``: cells are right-aligned under their column's name, the
    row's name before the first column. Rows end at the first line that does
    not reach the header's last column."""
    lines = text.splitlines()
    tables = []
    for i, head in enumerate(lines):
        if not head.startswith(first + " "):
            continue
        names = [(m.group(), m.end()) for m in re.finditer(r"\S+", head)][1:]
        start = re.search(r"\S", head[len(first) :]).start() + len(first)
        rows = []
        for line in lines[i + 1 :]:
            if len(line) < names[-1][1] - 2 or ":" in line[:start]:
                break
            row = {first: line[:start].strip()}
            left = start
            for name, end in names:
                row[name] = line[left:end].strip()
                left = end
            rows.append(row)
        tables.append(rows)
    return tables


def number(cell: str) -> float:
    """A printed number: ``1,234`` / ``0.0123`` / ``0.012 ms`` (as seconds)."""
    cell = cell.strip()
    if cell.endswith(" ms"):
        return float(cell[:-3].replace(",", "")) / 1e3
    return float(cell.replace(",", ""))


@contextlib.contextmanager
def descriptor_cache(folder: Path):
    """Descriptors cached under ``folder`` (not the user's cache) meanwhile."""
    old = os.environ.get("RHYTHMIC_JAX_CACHE")
    os.environ["RHYTHMIC_JAX_CACHE"] = str(folder)
    try:
        yield
    finally:
        if old is None:
            os.environ.pop("RHYTHMIC_JAX_CACHE")
        else:
            os.environ["RHYTHMIC_JAX_CACHE"] = old


# --------------------------------------------------------- the numpy oracle


def place_scores(q: np.ndarray, w, b, periods, n: int) -> np.ndarray:
    """(b, n): ``S(i) = sum_k s_k[i mod tau_k]`` with ``s = q w + b`` in float64."""
    s = np.asarray(q, np.float64) @ np.asarray(w, np.float64) + np.asarray(b)
    out = np.zeros((len(q), n))
    off = 0
    for t in periods:
        out += s[:, off + np.arange(n) % t]
        off += t
    return out


def hard_places(q, w, b, periods, n: int) -> np.ndarray:
    """The paper's decode: argmax phase per period, the place with those phases
    (Chinese remainder, found by search), -1 when it is n or beyond."""
    s = np.asarray(q, np.float64) @ np.asarray(w, np.float64) + np.asarray(b)
    offs = np.cumsum((0, *periods))
    phases = np.stack(
        [s[:, a:z].argmax(1) for a, z in zip(offs, offs[1:], strict=False)], 1
    )
    table = np.stack([np.arange(n) % t for t in periods], 1)  # (n, k)
    same = (phases[:, None, :] == table[None]).all(2)  # (b, n)
    return np.where(same.any(1), same.argmax(1), -1)


def top_k(scores: np.ndarray, k: int) -> np.ndarray:
    return np.argsort(-scores, axis=1, kind="stable")[:, :k]


def recall_at(ranked: np.ndarray, k: int, tol: int = TOL) -> float:
    truth = np.arange(len(ranked))[:, None]
    near = (ranked[:, :k] >= 0) & (np.abs(ranked[:, :k] - truth) <= tol)
    return float(near.any(1).mean())


def correct(pred: np.ndarray, tol: int) -> np.ndarray:
    return (pred >= 0) & (np.abs(pred - np.arange(len(pred))) <= tol)


def pr_figures(pred: np.ndarray, conf: np.ndarray, tol: int = TOL):
    """(R@100P, PR-AUC) of single-best answers, by a loop over thresholds."""
    ok, kept = correct(pred, tol), pred >= 0
    conf = np.asarray(conf, np.float64)
    points = [(0.0, 1.0)]  # (recall, precision), thresholds from the top
    for t in np.unique(conf[kept])[::-1]:
        got = kept & (conf >= t)
        right = int((ok & got).sum())
        points.append((right / len(pred), right / int(got.sum())))
    r100 = max(r for r, p in points if p == 1.0)
    pairs = zip(points, points[1:], strict=False)
    area = sum((r1 - r0) * (p0 + p1) / 2 for (r0, p0), (r1, p1) in pairs)
    return r100, area


def confidence_of(conf) -> np.ndarray:
    """A decode's confidence as the metrics take it: +-inf at float64's limits."""
    big = np.finfo(np.float64).max
    return np.clip(np.asarray(conf, np.float64), -big, big)


def map_bytes(periods, d: int, dtype: str = "float32") -> int:
    p = sum(periods)
    if dtype == "int8":
        return p * (d + 1) + 4 * p
    return p * (d + 1) * {"float32": 4, "float16": 2}[dtype]


def gemm_flops() -> float:
    """This machine's float32 matrix-product speed (flop/s), best of ten."""
    rng = np.random.default_rng(0)
    a = rng.normal(size=(1024, 1024)).astype(np.float32)
    c = rng.normal(size=(1024, 1024)).astype(np.float32)
    best = np.inf
    for _ in range(10):
        t = time.perf_counter()
        a @ c
        best = min(best, time.perf_counter() - t)
    return 2 * 1024**3 / best


def floor_s(flops: float, speed: float) -> float:
    """The least time ``flops`` can take: at :data:`SPEEDUP` times ``speed``."""
    return flops / (SPEEDUP * speed)


# ----------------------------------------------------------------- the route


@pytest.fixture(scope="module")
def route(nordland_root, tmp_path_factory):
    """A folder with ref.npy, q.npy (400 places), the fitted map, and every
    command's output."""
    import rhythmic_jax as rj

    cwd = tmp_path_factory.mktemp("oracle")
    for season in ("summer", "winter"):
        frames = sorted((nordland_root / season).iterdir())
        (cwd / season).mkdir()
        for i in PLACES:
            (cwd / season / frames[i].name).symlink_to(frames[i])
    with descriptor_cache(cwd / "cache"):
        x = rj.describe_frames(cwd / "summer", "patchnorm")
        q = rj.describe_frames(cwd / "winter", "patchnorm")
    np.save(cwd / "ref.npy", x)
    np.save(cwd / "q.npy", q)
    run_cli("fit", "ref.npy", "--out", "m.map", "--no-progress", cwd=cwd)
    tol = ("--tolerance", str(TOL))
    out = {
        "x": np.load(cwd / "ref.npy"),
        "q": np.load(cwd / "q.npy"),
        "map": rj.load(cwd / "m.map"),
        "evaluate_json": json.loads(
            run_cli(
                "evaluate", "m.map", "q.npy", *tol, "--json", "--no-progress", cwd=cwd
            )  # fmt: skip
        ),
        "evaluate_text": run_cli(
            "evaluate", "m.map", "q.npy", *tol, "--no-progress", cwd=cwd
        ),  # fmt: skip
        "query": json.loads(
            run_cli(
                "query",
                "m.map",
                "q.npy",
                "--json",
                "--top",
                "20",
                "--no-progress",
                cwd=cwd,
            )  # fmt: skip
        ),
    }
    out["frontier"] = json.loads(
        run_cli(
            "frontier",
            "ref.npy",
            "q.npy",
            *tol,
            "--maps",
            "2:1",
            "--bits",
            "64",
            "--pq",
            "8",
            "--lengths",
            "1,5",
            "--cache",
            "fitted",
            "--json",
            "--csv",
            "fr.csv",
            "--no-progress",
            cwd=cwd,
        )  # fmt: skip
    )
    out["frontier_csv"] = (cwd / "fr.csv").read_text()
    out["cwd"] = cwd
    return out


@pytest.fixture(scope="module")
def speed() -> float:
    return gemm_flops()


# ------------------------------------------------------------------ evaluate


def test_evaluate_map_figures_recomputed(route):
    """The map's row: recall@K from numpy place scores of the loaded templates,
    accuracy and the PR figures from the per-query answers, bytes and share
    from the periods."""
    m, q, got = route["map"], route["q"], route["evaluate_json"]
    b, n, d = len(q), m.n, m.d
    row = got["methods"]["map"]
    total = place_scores(q, m.w, m.b, m.periods, n)
    ranked = top_k(total, max(KS))
    for k in KS:
        assert row[f"recall@{k}"] == pytest.approx(recall_at(ranked, k), abs=1.5 / b)
    # the per-query answers: query --json, and the paper's decode in numpy
    answers = route["query"]
    pred = np.asarray(answers["predictions"])
    np.testing.assert_array_equal(pred, hard_places(q, m.w, m.b, m.periods, n))
    assert row["accuracy"] == pytest.approx(float((pred == np.arange(b)).mean()))
    assert row["accuracy_tol"] == pytest.approx(float(correct(pred, TOL).mean()))
    tops = np.array([[t["place"] for t in a["top"]] for a in answers["queries"]])
    assert (tops[:, 0] == ranked[:, 0]).mean() > 0.98
    import rhythmic_jax as rj

    conf = confidence_of(rj.decode(m, q).confidence)
    r100, area = pr_figures(pred, conf)
    assert row["recall@100p"] == pytest.approx(r100, abs=1e-12)
    assert row["pr_auc"] == pytest.approx(area, rel=1e-9, abs=1e-12)
    assert row["storage_bytes"] == map_bytes(m.periods, d)
    assert got["database_bytes"] == n * d * 4
    assert row["storage_share"] == pytest.approx(map_bytes(m.periods, d) / (n * d * 4))
    assert got["compression_ratio"] == pytest.approx(row["storage_share"])


def test_evaluate_brute_force_figures_recomputed(route):
    """Brute force: cosine similarities in numpy, the best reference first."""
    x, q, got = route["x"], route["q"], route["evaluate_json"]
    row = got["methods"]["brute force"]
    sims = np.asarray(q, np.float64) @ np.asarray(x, np.float64).T
    ranked = top_k(sims, max(KS))
    for k in KS:
        assert row[f"recall@{k}"] == pytest.approx(
            recall_at(ranked, k), abs=1.5 / len(q)
        )
    best = ranked[:, 0]
    assert row["accuracy"] == pytest.approx(float((best == np.arange(len(q))).mean()))
    assert row["accuracy_tol"] == pytest.approx(float(correct(best, TOL).mean()))
    r100, area = pr_figures(best, sims[np.arange(len(q)), best])
    assert row["recall@100p"] == pytest.approx(r100, abs=1.5 / len(q))
    assert row["pr_auc"] == pytest.approx(area, abs=2e-3)
    assert row["storage_bytes"] == x.size * 4


def test_evaluate_prints_its_json(route):
    """Every printed cell of every row, read by column name, is the JSON's
    figure as printed (four decimals; bytes whole; latency in ms)."""
    got = route["evaluate_json"]["methods"]
    (table,) = printed_table(route["evaluate_text"])
    names = {r["method"] for r in table}
    assert {"map", "brute force"} <= names and names <= set(got)
    columns = {"accuracy": "accuracy", "acc_tol": "accuracy_tol",
               "pr_auc": "pr_auc", "recall@100p": "recall@100p",
               **{f"recall@{k}": f"recall@{k}" for k in KS}}  # fmt: skip
    for row in table:
        want = got[row["method"]]
        for col, key in columns.items():
            if col in row and row[col] not in ("", "-"):
                assert number(row[col]) == pytest.approx(want[key], abs=5.1e-5), (
                    row["method"], col)  # fmt: skip
        if row.get("bytes") not in (None, "", "-"):
            assert number(row["bytes"]) == want["storage_bytes"]


# ------------------------------------------------------------------ frontier


def _frontier_rows(route) -> dict[str, dict]:
    return {r["name"]: r for r in route["frontier"]["rows"]}


def test_frontier_figures_recomputed(route):
    """Brute force and the float32/float16/int8 map rows from the kept templates
    (``--cache``), recomputed in numpy: R@1 (the soft decode: the best place
    score), R@100P (its confidence: best minus runner-up), bytes, shares."""
    got, x, q = _frontier_rows(route), route["x"], route["q"]
    n, d = x.shape
    assert route["frontier"]["n"] == n and route["frontier"]["d"] == d
    bf = got["brute force"]
    sims = np.asarray(q, np.float64) @ np.asarray(x, np.float64).T
    best = sims.argmax(1)
    assert bf["recall@1 L=1"] == pytest.approx(correct(best, TOL).mean(), abs=1.5 / n)
    r100, _ = pr_figures(best, sims.max(1))
    assert bf["recall@100p"] == pytest.approx(r100, abs=1.5 / n)
    # the cache keeps each fitted map as a map folder
    (kept,) = (route["cwd"] / "fitted").glob("map-*-r2-l1-*")
    from rhythmic_jax.map import map_file

    m = map_file.load(kept)
    w, b = np.asarray(m.w, np.float32), np.asarray(m.b, np.float32)
    periods = tuple(int(t) for t in m.periods)
    for dtype in ("float32", "float16", "int8"):
        name = f"map r=2 level 1 {periods}" + (
            "" if dtype == "float32" else f" {dtype}"
        )
        row = got[name]
        if dtype == "float16":
            wq, bq = w.astype(np.float16), b.astype(np.float16)
        elif dtype == "int8":  # a float32 scale per template, bias included
            scale = np.maximum(np.abs(w).max(0), np.abs(b)) / 127.0
            wq = np.clip(np.rint(w / scale), -127, 127) * scale
            bq = np.clip(np.rint(b / scale), -127, 127) * scale
        else:
            wq, bq = w, b
        total = place_scores(q, wq, bq, periods, n)
        order = np.sort(total, axis=1)
        pred, conf = total.argmax(1), order[:, -1] - order[:, -2]
        assert row["recall@1 L=1"] == pytest.approx(correct(pred, TOL).mean(),
                                                    abs=2.5 / n), name  # fmt: skip
        r100, _ = pr_figures(pred, conf)
        assert row["recall@100p"] == pytest.approx(r100, abs=2.5 / n), name
        assert row["storage_bytes"] == map_bytes(periods, d, dtype), name
    codes = {"ITQ 64 bits": n * 8 + (64 * d + d) * 4,
             "PQ 8x8 bits": n * 8 + 256 * d * 4,
             "int8 per place": n * d + 2 * d * 4}  # fmt: skip
    for name, nbytes in codes.items():
        assert got[name]["storage_bytes"] == nbytes, name
    for name, row in got.items():  # every row, whatever rows are added
        assert row["share"] == pytest.approx(row["storage_bytes"] / (n * d * 4)), name
        assert row["bytes_per_place"] == pytest.approx(row["storage_bytes"] / n), name


def test_frontier_pareto_and_csv_agree_with_the_rows(route):
    """The Pareto marks are recomputed (no other row has at least its recall@1
    in fewer bytes) and the CSV holds the JSON's figures."""
    import csv
    import io

    rows = route["frontier"]["rows"]
    scored = [r for r in rows if r.get("recall@1 L=1") is not None]
    for r in scored:
        beaten = any(
            o is not r and o["storage_bytes"] < r["storage_bytes"]
            and o["recall@1 L=1"] >= r["recall@1 L=1"] for o in scored
        )  # fmt: skip
        if r.get("pareto"):
            assert not beaten, r["name"]
    marked = {r["name"] for r in rows if r.get("pareto")}
    assert marked == set(route["frontier"]["pareto"])
    table = {r["name"]: r for r in csv.DictReader(io.StringIO(route["frontier_csv"]))}
    assert set(table) == {r["name"] for r in rows}
    for r in rows:
        for key in ("storage_bytes", "share", "recall@1 L=1", "recall@100p"):
            if r.get(key) is not None and table[r["name"]].get(key) not in (None, ""):
                assert float(table[r["name"]][key]) == pytest.approx(r[key]), key


# ----------------------------------------------------------------- latencies


def _flops(name: str, n: int, d: int, periods) -> float | None:
    """Multiply-adds x 2 one query needs for a row named ``name`` (None: a row
    this oracle does not know)."""
    p = sum(periods)
    if name in ("map", "brute force", "int8 per place", "codes alone", "map + codes"):
        return {"map": p * d, "map + codes": p * d, "codes alone": 0}.get(
            name, n * d
        ) * 2.0
    if name.startswith("map r="):
        per = tuple(int(t) for t in re.search(r"\(([\d, ]+)\)", name)[1].split(","))
        return 2.0 * sum(per) * d
    if m := re.match(r"ITQ (\d+) bits$", name):
        return 2.0 * int(m[1]) * d
    if re.match(r"PQ \d+x8 bits$", name):
        return 2.0 * 256 * d
    if m := re.match(r"PCA (\d+)", name):
        return 2.0 * int(m[1]) * (d + n)
    return None


def test_no_latency_is_faster_than_its_products(route, speed):
    """Every printed time is at least its products' flops at 4x this machine's
    measured GEMM speed: a query alone, and a whole batch per query."""
    m, q = route["map"], route["q"]
    n, d, b = m.n, m.d, len(q)
    checked = []
    for name, row in route["evaluate_json"]["methods"].items():
        flops = _flops(name, n, d, m.periods)
        if flops is None or "latency_median_s" not in row:
            continue
        assert row["latency_median_s"] >= floor_s(flops, speed), name
        assert row["batch_s"] >= floor_s(b * flops, speed), name
        checked.append(name)
    for name, row in _frontier_rows(route).items():
        flops = _flops(name, n, d, m.periods)
        if flops is None or row.get("latency_s") is None:
            continue
        assert row["latency_s"] >= floor_s(flops, speed), name
        checked.append(name)
    assert {"map", "brute force", "ITQ 64 bits", "int8 per place"} <= set(checked)
    assert any(c.startswith("map r=") for c in checked)


# ---------------------------------------------------------------------- demo


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """``rhythmic-jax demo --quick``: its printed text, report.json and map, and
    its descriptors made again by the demo's own route functions."""
    import rhythmic_jax as rj
    from rhythmic_jax.app.demo import DemoConfig, changed_appearance, demo_mosaic
    from rhythmic_jax.frames.sources import describe_images
    from rhythmic_jax.io.tiles import tile_image

    cwd = tmp_path_factory.mktemp("demo")
    text = run_cli("demo", "--quick", "--out", "out", "--no-progress", cwd=cwd)
    cfg = DemoConfig.quick()  # the route the demo describes, made again
    mosaic = demo_mosaic(cfg.grid, cfg.photo)
    settings = {"width": cfg.thumb, "height": cfg.thumb, "patch": 8}
    tag = f"demo-{cfg.grid}x{cfg.photo}-{cfg.tile}-{cfg.stride}"
    with descriptor_cache(cwd / "cache"):
        x = describe_images(tile_image(mosaic, cfg.tile, cfg.stride).tiles,
                            "patchnorm", settings, tag + "-a", False)[0]  # fmt: skip
        changed = tile_image(changed_appearance(mosaic), cfg.tile, cfg.stride)
        q = describe_images(changed.tiles, "patchnorm", settings, tag + "-b",
                            False)[0]  # fmt: skip
    return {
        "text": text,
        "report": json.loads((cwd / "out" / "report.json").read_text()),
        "map": rj.load(cwd / "out" / "map"),
        "x": np.asarray(x),
        "q": np.asarray(q),
        "tol": cfg.tolerance,
    }


def test_demo_figures_recomputed(demo, speed):
    """Both of the demo's tables (same and changed appearance), read by column
    name from what it printed, against numpy on its descriptors and map; its
    bytes, ratio and the list of decodes too; no latency beats the arithmetic."""
    import rhythmic_jax as rj

    m, x, tol = demo["map"], demo["x"], demo["tol"]
    n, d = m.n, m.d
    assert x.shape == (n, d)
    tables = printed_table(demo["text"])
    assert len(tables) == 2
    for table, q in zip(tables, (x, demo["q"]), strict=True):
        rows = {r["method"]: r for r in table}
        total = place_scores(q, m.w, m.b, m.periods, n)
        ranked = top_k(total, max(KS))
        pred = hard_places(q, m.w, m.b, m.periods, n)
        np.testing.assert_array_equal(pred, rj.predict(m, q))
        conf = confidence_of(rj.decode(m, q).confidence)
        r100, area = pr_figures(pred, conf, tol)
        want = {
            "accuracy": (pred == np.arange(n)).mean(),
            "acc_tol": correct(pred, tol).mean(),
            **{f"recall@{k}": recall_at(ranked, k, tol) for k in KS},
            "pr_auc": area,
            "recall@100p": r100,
            "bytes": map_bytes(m.periods, d),
        }
        sims = np.asarray(q, np.float64) @ np.asarray(x, np.float64).T
        bf = top_k(sims, max(KS))
        r100, area = pr_figures(bf[:, 0], sims[np.arange(n), bf[:, 0]], tol)
        brute = {
            "accuracy": (bf[:, 0] == np.arange(n)).mean(),
            "acc_tol": correct(bf[:, 0], tol).mean(),
            **{f"recall@{k}": recall_at(bf, k, tol) for k in KS},
            "pr_auc": area,
            "recall@100p": r100,
            "bytes": n * d * 4,
        }
        for name, figures in (("map", want), ("brute force", brute)):
            for col, value in figures.items():
                slack = 1 if col == "bytes" else 5.1e-5 + 1.5 / n
                assert number(rows[name][col]) == pytest.approx(value, abs=slack), (
                    name, col)  # fmt: skip
        for name, flops in (
            ("map", 2.0 * sum(m.periods) * d),
            ("brute force", 2.0 * n * d),
        ):
            assert number(rows[name]["latency"]) >= floor_s(flops, speed), name
            per_s = number(rows[name]["queries/s"])
            assert per_s <= 1 / floor_s(flops, speed), name
    report = demo["report"]
    assert report["storage_bytes"] == map_bytes(m.periods, d)
    assert report["database_bytes"] == n * d * 4
    assert report["compression_ratio"] == pytest.approx(
        map_bytes(m.periods, d) / (n * d * 4)
    )
    head = re.search(r"map: periods .*?([\d,]+) bytes = ([\d.]+) of the ([\d,]+)-byte",
                     demo["text"])  # fmt: skip
    assert number(head[1]) == report["storage_bytes"]
    assert float(head[2]) == pytest.approx(report["compression_ratio"], abs=5e-5)
    assert number(head[3]) == report["database_bytes"]
    # the decodes after the change: the soft single frame is the best place score
    q = demo["q"]
    soft = place_scores(q, m.w, m.b, m.periods, n).argmax(1)
    decodes = report["changed_appearance_decodes"]
    assert decodes["soft, sequence 1"] == pytest.approx(correct(soft, tol).mean(),
                                                        abs=1.5 / n)  # fmt: skip
    hard = hard_places(q, m.w, m.b, m.periods, n)
    assert decodes["hard, sequence 1"] == pytest.approx(correct(hard, tol).mean())
    for key, value in decodes.items():
        line = re.search(rf"^\s+{re.escape(key)}\s+([\d.]+)$", demo["text"], re.M)
        assert float(line[1]) == pytest.approx(value, abs=5.1e-5), key
