"""Scale, by part: growth from real fits (storage, time, passes and memory against N,
d, r, processes), the streamed Newton-CG's preconditioner and compacted passes, and
the memory estimate of a full-batch fit against its measured peak.

python scripts/bench_scale.py grid --quick          # a small grid (minutes)
python scripts/bench_scale.py grid --budget 3000 --probe 1000000   # at nice 19
python scripts/bench_scale.py grid --budget 0 --full 1000000 --full-work /tmp/f
python scripts/bench_scale.py streamed [--repeats 2] [--walk-frames 100000]
python scripts/bench_scale.py memory [--shapes 1000x64 3000x128 ...] [--repeats 2]
"""

import itertools
import json
import math
import os
import resource
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import _harness as h
import numpy as np

from rhythmic_jax import RhythmicMap, candidate_periods, pairwise_coprime
from rhythmic_jax.fitting.fit_plan import plan
from rhythmic_jax.io.frame_files import open_frames
from rhythmic_jax.map.config import MapConfig
from rhythmic_jax.map.periods import nominal_periods
from rhythmic_jax.solvers.memory import check_memory, fit_bytes, peak_growth
from rhythmic_jax.solvers.newton import newton_fit
from rhythmic_jax.solvers.objective import default_c, targets
from rhythmic_jax.solvers.streamed import FAST_STREAM, streamed_newton_fit

NICE = 19  # the machine is shared: every fit runs at this niceness (idle CPU only)
CELLS = Path("~/.cache/rhythmic_jax/bench_scale").expanduser()
DTYPES = ("float32", "float16", "int8")
PASSES = ("gradient", "CG", "gradient + bits", "CG from bits", "line search")


def fit_command(path: Path, out: Path, *options: str) -> list[str]:
    """``rhythmic-jax fit`` of the frames in ``path`` to ``out``, gap 1e-3."""
    return ["rhythmic-jax", "fit", str(path), "--out", str(out), *options,
            "--gap", "1e-3", "--json", "--no-progress"]  # fmt: skip


def fitted(stdout: str) -> dict:
    """The JSON record ``rhythmic-jax fit --json`` printed."""
    return json.loads(stdout[stdout.index("{") :])


def walk(n: int, d: int, seed: int = 0, out=None) -> np.ndarray:
    """Route-like unit rows (n, d) float32: a smooth random walk, perturbed per row."""
    rng = np.random.default_rng(seed)
    x = np.empty((n, d), np.float32) if out is None else out
    pos = rng.normal(size=d) * 4.0
    for lo in range(0, n, 8192):
        block = pos + np.cumsum(rng.normal(size=(min(8192, n - lo), d)) * 0.05, axis=0)
        pos, block = block[-1], block / np.linalg.norm(block, axis=1, keepdims=True)
        block += rng.normal(size=block.shape) * (0.5 / np.sqrt(d))
        x[lo : lo + len(block)] = block / np.linalg.norm(block, axis=1, keepdims=True)
    return x


def accuracy(model: RhythmicMap, frames, n: int) -> float:
    """Fraction of the n reference frames that the map puts at their own index."""
    hits = 0
    for lo in range(0, n, 8192):
        hi = min(n, lo + 8192)
        hits += int(np.sum(model.predict(frames.read(lo, hi)) == np.arange(lo, hi)))
    return hits / n


def dtypes(model: RhythmicMap) -> dict[str, RhythmicMap]:
    """The map in each of ``DTYPES``."""
    return {t: model if t == "float32" else model.with_dtype(t) for t in DTYPES}


def one(cell: tuple, args) -> dict:
    """Fit one cell (source, n, d, r, processes, mode, rule) afresh; measure it."""
    source, n, d, r, procs, mode, rule = cell
    root = args.root if source == "nordland" else None
    x_path = frames_file(args.cells / f"{source}-{n}-{d}.npy", n, d, root)
    out, memory = args.cells / f"{_key(cell)}.map", args.memory
    if rule == "least":  # fixed periods imply r
        options = ["--layout", "periods:" + ",".join(map(str, nominal_periods(n, r)))]
    else:
        options = ["--r", str(r)]
    options += ["--processes", str(procs)] if procs > 1 else []
    options += ["--stream", "--memory", memory] if mode == "stream" else []
    fit = h.child(fit_command(x_path, out, *options), cwd=Path.cwd())
    models, frames = dtypes(RhythmicMap.load(out)), open_frames(x_path)
    info = fitted(fit["stdout"])
    run = info.get("fit") or {}
    row = dict(
        source=source, n=n, d=d, r=r, processes=procs, mode=mode, rule=rule,
        periods=info["periods"], storage_bytes=info["storage_bytes"],
        bytes_per_place=info["storage_bytes"] / n,
        float16_bytes=models["float16"].storage_bytes,
        int8_bytes=models["int8"].storage_bytes, fit_seconds=fit["wall"],
        peak_bytes=fit["peak"], memory=memory if mode == "stream" else None,
        passes=run.get("passes"), pass_median_s=run.get("pass_median_s"),
        block_rows=run.get("block_rows"), nice=os.nice(0),
        accuracy={t: accuracy(m, frames, n) for t, m in models.items()},
        measured=time.strftime("%H:%M UTC", time.gmtime()), load=h.load_average(),
    )  # fmt: skip
    h.log.info("%s", row)
    return row


def rule_sums(n: int, r: int) -> tuple[int, int]:
    """Least and largest summed periods the candidate rule can choose at n places."""
    sets = itertools.combinations(candidate_periods(n, r), r)
    sums = [sum(c) for c in sets if pairwise_coprime(c) and math.prod(c) >= n]
    return min(sums), max(sums)


def rule_range(ns: list[int], r: int) -> tuple[float, float]:
    """Least and largest storage slope the candidate rule allows over ``ns``."""
    lx = np.log(np.asarray(ns, float))
    w = (lx - lx.mean()) / np.sum((lx - lx.mean()) ** 2)
    sums = np.log([rule_sums(int(n), r) for n in ns])  # (points, 2): least, largest
    low, high = (np.where(w > 0, sums[:, i], sums[:, 1 - i]) for i in (0, 1))
    return float(w @ low), float(w @ high)


def _rule(row: dict) -> str:
    return row.get("rule", "errors")


def series(rows: list[dict], source: str, d: int, r: int, rule="errors") -> list:
    """One process's fits of (source, d, r, rule) by N: in memory, else streamed."""
    one = [x for x in rows if (x["source"], x["d"], x["r"], x["processes"], _rule(x))
           == (source, d, r, 1, rule)]  # fmt: skip
    held = {x["n"] for x in one if x["mode"] == "memory"}
    kept = [x for x in one if x["mode"] == "memory" or x["n"] not in held]
    return sorted(kept, key=lambda x: x["n"])


def slopes(rows: list[dict]) -> list[dict]:
    """Least-squares slope of log storage on log N per (source, d, r, rule)."""
    out, one = [], [r for r in rows if r["processes"] == 1 and r["mode"] == "memory"]
    keys = sorted({(r["source"], r["d"], r["r"], _rule(r)) for r in one})
    for source, d, r, rule in keys:
        pts = series(rows, source, d, r, rule)
        ns = [p["n"] for p in pts]
        if len(set(ns)) < 2:
            continue
        lx, ly = np.log(ns), np.log([p["storage_bytes"] for p in pts])
        slope, top = float(np.polyfit(lx, ly, 1)[0]), np.asarray(ns) >= 10000
        upper = float(np.polyfit(lx[top], ly[top], 1)[0]) if top.sum() >= 2 else None
        if rule == "errors":
            low, high = rule_range(ns, r)
        else:  # the least-storage co-prime sets
            sums = [sum(nominal_periods(int(n), r)) for n in ns]
            low = high = float(np.polyfit(lx, np.log(sums), 1)[0])
        out.append(dict(source=source, d=d, r=r, rule=rule, points=len(pts),
                        slope=slope, slope_from_10k=upper, target=1 / r,
                        within=abs(slope - 1 / r) <= 0.05, rule_low=low,
                        rule_high=high))  # fmt: skip
    return out


def _group(r: dict) -> tuple:
    return r["source"], r["d"], r["r"], r["processes"], r["mode"], _rule(r)


def figures(rows: list[dict], out_dir: Path) -> list[str]:
    from rhythmic_jax.eval.figures import new_figure, save_figure

    plots = (("storage_bytes", "map bytes", "scale_storage"),
             ("fit_seconds", "fit seconds", "scale_time"),
             ("pass_median_s", "seconds per pass", "scale_pass"))  # fmt: skip
    for key, label, stem in plots:
        fig, (ax,) = new_figure(width=5, height=4)
        for g in sorted({_group(r) for r in rows if r[key] is not None}):
            pts = sorted((r["n"], r[key]) for r in rows
                         if _group(r) == g and r[key] is not None)  # fmt: skip
            label_g = "{} d={} r={} K={} {} {}".format(*g)
            ax.loglog(*zip(*pts, strict=True), "o-", label=label_g)
        ax.set(xlabel="N (places)", ylabel=label)
        ax.legend(fontsize=6)
        save_figure(fig, out_dir / f"{stem}.png", dpi=110)
    return [f"{stem}.png" for _, _, stem in plots]


def grid_notes(report: dict) -> list[str]:
    """Each series' periods' product M against N; the full fit's search projected."""
    notes = []
    for sl in report["slopes"]:
        pts = series(report["rows"], sl["source"], sl["d"], sl["r"], _rule(sl))
        n0, n1 = pts[0]["n"], pts[-1]["n"]
        m0, m1 = (math.prod(p["periods"]) for p in (pts[0], pts[-1]))
        notes.append(f"- {sl['source']} d = {sl['d']}, r = {sl['r']}, {_rule(sl)}:"
                     f" M = {m0 / n0:.2f} N at N = {n0:,}, {m1 / n1:.2f} N at N ="
                     f" {n1:,}.")  # fmt: skip
    if f := report.get("full"):
        hours = search_hours(f, report.get("probe"))
        notes.append(f"- The full fit's candidate search ({sum(f['candidates'])}"
                     f" templates) projected at {hours:.2f} hours (a projection).")
    return ["\n".join(notes)]


markdown_grid = h.markdown(
    "Growth from real fits (--gap 1e-3)",
    "Every fit ran niced beside other jobs (pessimistic times). K: processes;"
    " accuracy: self-query per storage type. Slopes: log bytes on log N;"
    " rule_low/rule_high: the least and largest slope the candidate rule allows;"
    " rule 'least': the least-storage periods (docs/SCALE.md).",
    grid_notes,
)


def grid(quick: bool, real: bool = True) -> list[tuple]:
    """Cells (source, n, d, r, processes, mode, rule), cheapest first."""
    ns = (1000, 3000) if quick else (1000, 3000, 10000, 30000, 100000)
    ds = (256,) if quick else (256, 2048)
    cells = [("walk", n, d, r, 1, "memory") for d in ds for r in (3, 2) for n in ns]
    cells += [("walk", n, 256, 3, 2, "memory") for n in ns if n <= 30000]
    cells += [("walk", n, 256, 3, k, "stream") for n in ns if n <= 10000
              for k in (1, 2)]  # fmt: skip
    if not quick:  # in memory, the guard refuses them (18 GiB and more)
        cells += [("walk", 100000, d, 2, 1, "stream") for d in ds]
    if real and not quick:
        cells += [("nordland", n, 2048, r, 1, "memory")
                  for n in (1000, 2000, 3000, 3576) for r in (2, 3)]  # fmt: skip
    cells = [(*c, "errors") for c in cells]
    cells += [(*c[:6], "least") for c in cells if c[4] == 1 and (
        c[5] == "memory" or c[1] == 100000 and c[2] == 2048)]  # fmt: skip
    cost = {"memory": 1, "stream": 4}

    def order(c):  # the storage slope at d = 256, r = 3 first, then by cost
        first = c[0] == "walk" and c[2:6] == (256, 3, 1, "memory")
        return not first, c[1] * c[2] * (6 - c[3]) * cost[c[5]]

    return sorted(cells, key=order)


def _key(cell: tuple) -> str:
    return "-".join(map(str, cell[:6] if cell[6:] in ((), ("errors",)) else cell))


def frames_file(path: Path, n: int, d: int = 256, root: Path | None = None) -> Path:
    """n route-like frames (or Nordland summer's under ``root``) kept at ``path``."""
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        partial = path.with_name("partial.npy")
        if root is None:
            part = np.lib.format.open_memmap(partial, "w+", np.float32, (n, d))
            walk(n, d, out=part).flush()
        else:
            np.save(partial, h.nordland_features(root, seasons=("summer",))[0][:n])
        os.replace(partial, path)
    return path


def pass_kinds(cg: list[int], seconds: list[float], line=None) -> dict:
    """A streamed fit's pass seconds by kind: basis, then per Newton step gradient,
    CG and line-search passes (default two a step), then a last gradient pass."""
    line = [2] * len(cg) if line is None else line
    at = len(seconds) - (sum(cg) + sum(line) + len(cg) + 1)
    kinds = {"basis": list(seconds[:at]), "gradient": [], "cg": [], "line": [],
             "step": []}  # fmt: skip
    for its, k in zip(cg, line, strict=True):
        kinds["gradient"].append(seconds[at])
        kinds["cg"] += seconds[at + 1 : at + 1 + its]
        kinds["line"] += seconds[at + 1 + its : at + 1 + its + k]
        kinds["step"].append(sum(seconds[at : at + 1 + its + k]))
        at += 1 + its + k
    return kinds


def full(args) -> dict:
    """The streamed fit of ``--full`` route-like frames with fixed periods."""
    n, periods, memory = args.full, args.full_periods, args.full_memory
    work = args.full_work
    path = frames_file(work / f"walk-{n}-256.npy", n)
    out, attempts = work / f"walk-{n}.map", work / "attempts.jsonl"
    options = "--layout", f"periods:{periods}", "--stream", "--memory", memory
    cmd = fit_command(path, out, *options)
    if not out.exists():
        start = time.strftime("%H:%M UTC", time.gmtime())
        r = h.child(cmd, cwd=Path.cwd(), check=False)
        res = dict(rc=r["rc"], seconds=r["wall"], peak=r["peak"], out=r["stdout"],
                   start=start, load=h.load_average())  # fmt: skip
        with open(attempts, "a") as fh:
            fh.write(json.dumps(res) + "\n")
        if res["rc"] != 0:
            raise RuntimeError(r["stderr"][-2000:])
    tries = [json.loads(line) for line in attempts.read_text().splitlines()]
    info = fitted(tries[-1]["out"])
    run, model = info["fit"], RhythmicMap.load(out)
    picks = np.linspace(0, n - 1, min(n, 20000)).astype(int)
    x = np.asarray(np.load(path, mmap_mode="r")[picks])
    acc = {t: float(np.mean(m.predict(x) == picks)) for t, m in dtypes(model).items()}
    kinds = pass_kinds(run["cg"], run["pass_seconds"], run.get("line"))
    row = dict(n=n, d=256, r=3, periods=info["periods"], memory=memory,
               command=" ".join(["nice", "-n", str(NICE), *cmd]),
               file_bytes=path.stat().st_size, storage_bytes=info["storage_bytes"],
               wall_seconds=sum(t["seconds"] for t in tries), attempts=len(tries),
               starts=[t["start"] for t in tries], loads=[t["load"] for t in tries],
               peak_bytes=max(t["peak"] for t in tries), steps=run["steps"],
               passes=run["passes"], pass_seconds=run["pass_seconds"], cg=run["cg"],
               line=run.get("line"),
               block_rows=run["block_rows"],
               kept_active_bytes=run.get("kept_active_bytes"),
               pass_median_s=float(np.median(run["pass_seconds"])),
               kinds={k: float(np.median(v)) for k, v in kinds.items() if v},
               group_errors=info["group_errors"], accuracy=acc, sample=len(picks),
               candidates=list(plan(MapConfig(r=3), n, 1).candidates),
               code=h.git_commit())  # fmt: skip
    return row


def search_hours(f: dict, probe: dict | None) -> float:
    """Hours of the candidate search with the full fit's steps and passes, at the
    probe's pass seconds (same N), else the fit's median pass times the templates."""
    if not probe or probe["n"] != f["n"]:
        return f["pass_median_s"] * sum(f["candidates"]) / sum(f["periods"]) * (
            f["passes"] / 3600
        )
    sec, steps = probe["sets"][-1]["seconds"], len(f["cg"])
    total = (steps + 1) * sec["gradient + bits"] + sum(f["cg"]) * sec["CG from bits"]
    return (total + sum(f.get("line") or [2] * steps) * sec["line search"]) / 3600


def probe(args) -> dict:
    """One streamed pass of each kind over ``--probe`` frames, in a fresh process."""
    n, memory, periods = args.probe, args.probe_memory, args.full_periods
    path = frames_file(args.full_work / f"walk-{n}-256.npy", n)
    res = h.call(passes, str(path), memory, periods)
    return res["result"] | dict(
        peak_bytes=res["peak"], memory=memory, file_bytes=path.stat().st_size,
        load=h.load_average(), nice=NICE,
        measured=time.strftime("%H:%M UTC", time.gmtime()),
    )  # fmt: skip


def passes(path: str, memory: str, periods: str) -> dict:
    """The probe's process: one pass of each kind (seconds, compiling included)."""
    import jax

    from rhythmic_jax.fitting.scale_fit import block_rows_for, parse_bytes
    from rhythmic_jax.solvers.objective import default_c
    from rhythmic_jax.solvers.passes import Passes

    frames, fixed = open_frames(path), tuple(int(t) for t in periods.split(","))
    c, sets = default_c(frames.n), []
    for periods in (fixed, plan(MapConfig(r=3), frames.n, 1).candidates):
        p = sum(periods)
        bits = frames.n * -(-p // 8)
        rows = min(frames.n, block_rows_for(parse_bytes(memory) - bits, frames.d, p))
        labels = np.arange(frames.n, dtype=np.int32)
        st = Passes(frames, 0, frames.n, labels, periods, rows, lambda t: t, True)
        theta = np.zeros((frames.d + 1, p), np.float32)
        v = theta + 1e-3
        st.gradient(theta, c)
        st.hessian(theta, v, c)  # nothing kept yet: two products with the frames
        st.gradient(theta, c, keep=True)
        st.hessian(theta, v, c)  # from the kept bits
        with jax.enable_x64(True):  # as in a fit: the search's sums in float64
            st.line(theta, v, np.ones((1, p)), c)
        sec = dict(zip(PASSES, st.seconds, strict=False))
        sets.append(dict(periods=periods, templates=p, block_rows=rows, seconds=sec))
        del st
    return dict(n=frames.n, d=frames.d, sets=sets)


OPTIONS_GRID = dict(
    budget=(1200.0, "seconds in all"), memory=("1GiB", "memory bound of stream cells"),
    cells=(CELLS, "saved cells, features"), probe=(0, "frames of the probe"),
    probe_memory="1GiB", full=(0, "frames of the full fit"),
    full_periods="100,101,103", full_memory="1GiB",
    full_work=(Path("/tmp/bench_scale_full"),
               "scratch folder of the full fit (features, map)"),
)  # fmt: skip


def run_grid(args) -> dict:
    """Growth from real fits against N, d, r, processes (scale)."""
    os.nice(max(0, NICE - os.nice(0)))  # this process and every fit it starts
    args.cells.mkdir(parents=True, exist_ok=True)
    rows, missing, t0 = [], [], time.perf_counter()
    for cell in grid(args.quick, (args.root / "nordland_64x32" / "summer").is_dir()):
        name = "{} N={} d={} r={} K={} {} {}".format(*cell)
        saved, failed = (args.cells / (_key(cell) + e) for e in (".json", ".failed"))
        if failed.exists() and not saved.exists():
            missing.append(f"{name} (failed: {failed.read_text().strip()})")
        elif not saved.exists() and time.perf_counter() - t0 > args.budget:
            missing.append(name)
        else:
            try:
                rows.append(h.kept(saved, lambda cell=cell: one(cell, args)))
            except RuntimeError as err:
                h.log.warning("%s failed: %s", name, err)
                reason = str(err).strip().splitlines()[-1][-300:]
                failed.write_text(reason)
                missing.append(f"{name} (failed: {reason})")
    report, stamps = {}, [r["measured"] for r in rows]
    fixed = args.full_periods.replace(",", "x")
    for what, n, measure, saved in (  # each kept under the settings it ran with
        ("probe", args.probe, probe, "passes-{probe}-{probe_memory}-{fixed}"),
        ("full fit", args.full, full, "full-{full}-{fixed}-{full_memory}"),
    ):
        try:
            if n:
                path = args.cells / (saved.format(**vars(args), fixed=fixed) + ".json")
                report[what.split()[0]] = h.kept(path, lambda m=measure: m(args))
        except RuntimeError as err:
            h.log.warning("%s failed: %s", what, err)
            missing.append(f"{what} N={n} (failed)")
    loads = [r["load"][0] for r in rows] or [0]
    nices = [r.get("nice", 10) for r in rows]
    report.update(
        rows=rows, slopes=slopes(rows), missing=missing, memory=args.memory,
        cells_from=min(stamps, default="-"), cells_to=max(stamps, default="-"),
        load_cells=f"{min(loads):.1f} - {max(loads):.1f}",
        self_rss=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024,
        nices=", ".join(f"{v}: {nices.count(v)} cells" for v in sorted(set(nices))),
    )  # fmt: skip
    args.out.mkdir(parents=True, exist_ok=True)
    report["figures"] = figures(rows, args.out) if rows else []
    return report


BLOCK_ROWS = 4096
SETTINGS = (
    ("Jacobi, every template", dict(spectral_rank=0, compact=False)),
    ("spectral, every template", dict(compact=False)),
    ("spectral, compacted", dict(compact=True)),
)
QUICK_STREAMED = dict(repeats=1, walk_frames=5000, walk_periods="17,18,19")  # --quick


def run_case(name, path: Path, periods, repeats: int) -> dict:
    """Every setting in turns on the frames in ``path``; the case's record."""
    frames = open_frames(path)
    labels, c = np.arange(frames.n), default_c(frames.n)
    y = targets(labels, periods)
    (_, ref), ref_s, _ = h.timed(lambda: newton_fit(frames.read(0, frames.n), y, c))
    runs: dict[str, list[dict]] = {label: [] for label, _ in SETTINGS}
    for rep in range(repeats):
        for label, settings in SETTINGS:
            config = replace(FAST_STREAM, block_rows=BLOCK_ROWS, **settings)
            fit = frames, labels, periods, c, config
            (_, info), wall, _ = h.timed(streamed_newton_fit, *fit, progress=False)
            h.log.info("%s %s run %d: %.1f s, %d steps, columns %s", name, label,
                     rep, wall, info.steps, info.columns)  # fmt: skip
            gap = (info.objective - ref.objective) / np.abs(ref.objective)
            runs[label].append(dict(
                wall_s=wall, steps=info.steps, passes=len(info.pass_seconds),
                cg_iterations=list(info.cg_iterations), columns=list(info.columns),
                column_passes=int(np.dot(info.columns, np.add(
                    np.add(info.cg_iterations, 1), info.line_passes))),
                reached=int(np.sum(info.gap_estimate <= config.gap_tol)),
                true_gap_max=float(np.max(gap)), true_gap_median=float(np.median(gap)),
            ))  # fmt: skip
    med = {k: float(np.median([r["wall_s"] for r in v])) for k, v in runs.items()}
    return dict(name=name, n=frames.n, d=frames.d, periods=list(periods),
                templates=int(sum(periods)), reference_s=ref_s, runs=runs,
                median_wall_s=med)  # fmt: skip


markdown_streamed = h.markdown(
    "Streamed Newton-CG: preconditioner and compacted passes",
    f"FAST_STREAM, blocks of {BLOCK_ROWS} frames of a memory-mapped .npy, the three"
    " settings in turns. reached: templates whose estimated gap met 1e-3; true_gap:"
    " against the in-memory optimum; column_passes: templates carried, over passes.",
)


OPTIONS_STREAMED = dict(repeats=2, walk_frames=100_000, walk_periods="46,47,49")


def run_streamed(args) -> dict:
    """Streamed Newton-CG: preconditioner, compacted passes (streamed)."""
    cases = []
    with tempfile.TemporaryDirectory(prefix="bench_streamed_") as tmp:
        if (args.root / "nordland_64x32" / "summer").is_dir() and not args.quick:
            path = Path(tmp) / "nordland.npy"
            np.save(path, h.summer(args))
            cases.append(run_case("nordland", path, (61, 65), args.repeats))
        else:
            h.log.warning("the Nordland case is left out (--quick or no frames)")
        path = Path(tmp) / "walk.npy"
        np.save(path, walk(args.walk_frames, 256))
        periods = tuple(int(t) for t in args.walk_periods.split(","))
        cases.append(run_case("walk", path, periods, args.repeats))
    return dict(cases=cases)


SHAPES = ["1000x64", "3000x128", "2000x256", "800x800", "400x1024", "250x4096"]
QUICK_MEMORY = dict(shapes=["600x32"], repeats=1)  # --quick


def fit_peak(x: np.ndarray) -> int:
    """Bytes a fit of x (n, d) adds to this process at its peak (x included)."""
    return peak_growth(lambda: RhythmicMap().fit(x, progress=False)) + x.nbytes


def measure(repeats: int, shapes: list[str]) -> list[dict]:
    """The fresh process: a record per shape."""
    rng, rows = np.random.default_rng(0), []
    RhythmicMap().fit(rng.normal(size=(48, 8)).astype(np.float32), progress=False)
    for shape in shapes:
        n, d = map(int, shape.split("x"))
        p, x = sum(candidate_periods(n)), rng.normal(size=(n, d)).astype(np.float32)
        estimate = sum(fit_bytes(n, d, p).values())
        admitted = check_memory(n, d, p, limit_bytes=estimate) == estimate
        t0 = time.perf_counter()
        cold = fit_peak(x)
        t1 = time.perf_counter()
        RhythmicMap().fit(x, progress=False)  # the first run of compiled code
        warm = [fit_peak(x) for _ in range(repeats)]
        warm_s = (time.perf_counter() - t1) / max(repeats, 1)
        rows.append(dict(n=n, d=d, p=p, admitted=admitted, cold=cold, warm=warm,
                         cold_s=t1 - t0, warm_s=warm_s))  # fmt: skip
    return rows


markdown_memory = h.markdown(
    "Memory of a full-batch fit: estimate against measured peak",
    "Random float32 frames, the default map. Peaks: resident memory's growth during"
    " the fit (cold: the shape's first fit, compiling; warm: refits). estimate: the"
    " sum of `fit_bytes`; admitted: the guard admits the fit at that limit.",
    lambda r: h.targets([h.target(f"{x['n']} x {x['d']}: cold peak / estimate",
                                  x["cold"] / x["estimate"], 1.0, False, "{:.3f}")
                         for x in r["rows"]]),
)  # fmt: skip


OPTIONS_MEMORY = dict(shapes=(SHAPES, "NxD ..."), repeats=(2, "warm refits a shape"))


def run_memory(args) -> dict:
    """A full-batch fit's memory estimate against its peak (memory)."""
    rows = h.call(measure, args.repeats, args.shapes)["result"]
    for r in rows:
        n, d = r["n"], r["d"]
        parts = fit_bytes(n, d, r["p"])
        kind = "wide (span)" if d > 2 * n else ("tall" if n > 2 * d else "square")
        est = sum(parts.values())
        r.update(kind=kind, parts=parts, estimate=est, arrays=est - parts["compile"])
    compile_bytes = rows[0]["parts"]["compile"] if rows else 0
    return dict(repeats=args.repeats, compile_bytes=compile_bytes, rows=rows)


PARTS = {
    "grid": h.Part(run_grid, markdown_grid, OPTIONS_GRID, "scale"),
    "streamed": h.Part(run_streamed, markdown_streamed, OPTIONS_STREAMED, "streamed",
                       QUICK_STREAMED),  # fmt: skip
    "memory": h.Part(run_memory, markdown_memory, OPTIONS_MEMORY, "memory",
                     QUICK_MEMORY),  # fmt: skip
}

if __name__ == "__main__":
    h.main(__doc__, PARTS)
