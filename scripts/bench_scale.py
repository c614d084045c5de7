"""Growth from real fits: storage, time, passes and memory against N, d, r, processes.

Every fit is the installed ``rhythmic-jax fit`` on a ``.npy`` file (``--gap
1e-3``), run under a wrapper that reads its peak resident memory (``ru_maxrss``
of its children, the processes of a ``--processes 2`` fit included). The growth
grid fits in memory (the exact Newton solver); ``stream`` cells stream the same
file under ``--memory`` and give the seconds per pass over the frames. Features
are route-like: a smooth random walk in feature space (unit rows), and Nordland
summer sub-routes (patch-normalised, 2048-d) where N allows. Self-query
accuracy: every reference frame queried against its own map, with the templates
as float32, float16 and int8. Storage slopes: least squares of log bytes on log
N per (source, d, r), against 1/r.

Each cell's result is saved as it completes (``--cells``), so a rerun skips the
cells already measured. ``--probe N`` writes N route-like 256-d frames to one
memory-mapped ``.npy`` and streams passes of an r = 3 fit over it under
``--probe-memory`` in a child process: the seconds per pass and the child's peak
resident memory, for the projection to 10^6 places.

    python scripts/bench_scale.py --quick          # a small grid (minutes)
    python scripts/bench_scale.py --budget 3000 --probe 1000000   # at nice 10
"""

from __future__ import annotations

import json
import logging
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import _bench_common as bc
import numpy as np

from rhythmic_jax import RhythmicMap
from rhythmic_jax.io.frame_files import open_frames

log = logging.getLogger("bench_scale")
NORDLAND = Path("/work/cache/nordland_summer_patchnorm.npy")
NICE = 10  # the machine is shared: every fit runs at this niceness
CELLS = Path("~/.cache/rhythmic_jax/bench_scale").expanduser()
_PEAK = """import json, resource, subprocess, sys, time
t = time.perf_counter()
done = subprocess.run(sys.argv[1:], capture_output=True, text=True)
sys.stderr.write(done.stderr[-3000:])
print(json.dumps(dict(rc=done.returncode, seconds=time.perf_counter() - t,
    peak=resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024,
    out=done.stdout)))"""


def walk(n: int, d: int, seed: int = 0, out=None) -> np.ndarray:
    """Route-like frames (n, d) float32, unit rows: a smooth random walk in
    feature space (the route's slow change) plus an independent perturbation per
    frame (what tells neighbouring places apart). ``out``: an (n, d) array to
    fill (a memory map), block by block."""
    rng = np.random.default_rng(seed)
    x = np.empty((n, d), np.float32) if out is None else out
    pos = rng.normal(size=d) * 4.0
    for lo in range(0, n, 8192):
        steps = rng.normal(size=(min(8192, n - lo), d)) * 0.05
        block = pos + np.cumsum(steps, axis=0)
        pos = block[-1]
        block = block / np.linalg.norm(block, axis=1, keepdims=True)
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


def run_fit(path: Path, out: Path, r: int, procs: int, mode: str, memory: str):
    """``rhythmic-jax fit`` under the peak-memory wrapper: seconds, peak, its JSON."""
    cmd = ["rhythmic-jax", "fit", str(path), "--out", str(out),
           "--r", str(r), "--gap", "1e-3", "--json", "--no-progress"]  # fmt: skip
    if procs > 1:
        cmd += ["--processes", str(procs)]
    if mode == "stream":
        cmd += ["--stream", "--memory", memory]
    done = subprocess.run(
        [sys.executable, "-c", _PEAK, *cmd], capture_output=True, text=True
    )
    res = json.loads(done.stdout)
    if res["rc"] != 0:
        raise RuntimeError(done.stderr[-2000:])
    text = res["out"]
    info = json.loads(text[text.index("{") :])
    return dict(seconds=res["seconds"], peak=res["peak"], info=info)


def one(cell: tuple, x_path: Path, tmp: Path, memory: str) -> dict:
    """Fit one cell (source, n, d, r, processes, mode) and measure it."""
    source, n, d, r, procs, mode = cell
    out = tmp / f"{source}-{n}-{d}-{r}-{procs}-{mode}.map"
    fit = run_fit(x_path, out, r, procs, mode, memory)
    model = RhythmicMap.load(out)
    frames = open_frames(x_path)
    acc = {"float32": accuracy(model, frames, n)}
    for dtype in ("float16", "int8"):
        acc[dtype] = accuracy(model.with_dtype(dtype), frames, n)
    info, run = fit["info"], fit["info"].get("fit") or {}
    row = dict(
        source=source,
        n=n,
        d=d,
        r=r,
        processes=procs,
        mode=mode,
        periods=info["periods"],
        storage_bytes=info["storage_bytes"],
        bytes_per_place=info["storage_bytes"] / n,
        float16_bytes=model.with_dtype("float16").storage_bytes,
        int8_bytes=model.with_dtype("int8").storage_bytes,
        fit_seconds=fit["seconds"],
        peak_bytes=fit["peak"],
        passes=run.get("passes"),
        pass_median_s=run.get("pass_median_s"),
        block_rows=run.get("block_rows"),
        accuracy=acc,
    )
    log.info("%s", row)
    return row


def slopes(rows: list[dict]) -> list[dict]:
    """Least-squares slope of log storage on log N per (source, d, r): one
    process, in memory."""
    out = []
    keys = sorted(
        {
            (r["source"], r["d"], r["r"])
            for r in rows
            if r["processes"] == 1 and r["mode"] == "memory"
        }
    )
    for source, d, r in keys:
        pts = [
            x
            for x in rows
            if (x["source"], x["d"], x["r"], x["processes"], x["mode"])
            == (source, d, r, 1, "memory")
        ]
        if len({p["n"] for p in pts}) < 2:
            continue
        lx = np.log([p["n"] for p in pts])
        ly = np.log([p["storage_bytes"] for p in pts])
        slope = float(np.polyfit(lx, ly, 1)[0])
        top = np.asarray([p["n"] for p in pts]) >= 10000
        upper = float(np.polyfit(lx[top], ly[top], 1)[0]) if top.sum() >= 2 else None
        out.append(
            dict(
                source=source,
                d=d,
                r=r,
                points=len(pts),
                slope=slope,
                slope_from_10k=upper,
                target=1 / r,
                within=abs(slope - 1 / r) <= 0.05,
            )
        )
    return out


def _group(r: dict) -> tuple:
    return r["source"], r["d"], r["r"], r["processes"], r["mode"]


def figures(rows: list[dict], out_dir: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = []
    for key, label, stem in (
        ("storage_bytes", "map bytes", "scale_storage"),
        ("fit_seconds", "fit seconds", "scale_time"),
        ("pass_median_s", "seconds per pass", "scale_pass"),
    ):
        fig, ax = plt.subplots(figsize=(5, 4))
        groups = sorted({_group(r) for r in rows if r[key] is not None})
        for g in groups:
            pts = sorted(
                (r["n"], r[key]) for r in rows if _group(r) == g and r[key] is not None
            )
            if pts:
                ax.loglog(
                    *zip(*pts, strict=True),
                    "o-",
                    label=f"{g[0]} d={g[1]} r={g[2]} K={g[3]} {g[4]}",
                )
        ax.set_xlabel("N (places)")
        ax.set_ylabel(label)
        ax.legend(fontsize=6)
        fig.tight_layout()
        fig.savefig(out_dir / f"{stem}.png", dpi=110)
        plt.close(fig)
        names.append(f"{stem}.png")
    return names


def _num(v, digits):
    return "-" if v is None else round(v, digits)


def markdown(report: dict) -> str:
    lines = bc.header("Growth from real fits (--gap 1e-3)", report)
    lines += [
        f"Every fit ran under `nice -n 10` beside other jobs (load above): the times"
        f" are pessimistic. Cells were measured between {report['cells_from']} and"
        f" {report['cells_to']} at a 1-minute load average of {report['load_cells']}"
        " (each cell's in the JSON); a rerun reuses cells already measured, so the"
        " command above may only have collected them.",
        "",
    ]
    head = ["source", "N", "d", "r", "K", "mode", "periods", "bytes", "B/place",
            "fit s", "passes", "s/pass", "peak MiB", "acc f32", "acc f16",
            "acc int8"]  # fmt: skip
    rows = [
        [
            r["source"],
            r["n"],
            r["d"],
            r["r"],
            r["processes"],
            r["mode"],
            "x".join(map(str, r["periods"])),
            r["storage_bytes"],
            round(r["bytes_per_place"], 2),
            round(r["fit_seconds"], 1),
            "-" if r["passes"] is None else r["passes"],
            _num(r["pass_median_s"], 3),
            round(r["peak_bytes"] / 2**20),
            round(r["accuracy"]["float32"], 4),
            round(r["accuracy"]["float16"], 4),
            round(r["accuracy"]["int8"], 4),
        ]  # fmt: skip
        for r in report["rows"]
    ]
    lines += [bc.table(head, rows), "", "Storage slopes (log bytes on log N):", ""]
    lines += [
        bc.table(
            [
                "source",
                "d",
                "r",
                "points",
                "slope",
                "1/r",
                "within 0.05",
                "slope N >= 10^4",
            ],  # fmt: skip
            [
                [
                    s["source"],
                    s["d"],
                    s["r"],
                    s["points"],
                    round(s["slope"], 4),
                    round(s["target"], 4),
                    str(s["within"]),
                    _num(s.get("slope_from_10k"), 4),
                ]
                for s in report["slopes"]
            ],
        )
    ]
    for sl in report["slopes"]:
        pts = sorted(
            (r["n"], int(np.prod(r["periods"])))
            for r in report["rows"]
            if (r["source"], r["d"], r["r"], r["processes"], r["mode"])
            == (sl["source"], sl["d"], sl["r"], 1, "memory")
        )
        (n0, m0), (n1, m1) = pts[0], pts[-1]
        lines += ["", f"{sl['source']} d = {sl['d']}, r = {sl['r']}: the chosen "
                  f"periods' product M is {m0 / n0:.2f} N at N = {n0:,} and "
                  f"{m1 / n1:.2f} N at N = {n1:,}; the periods sit further above "
                  f"N^(1/r) at small N, which flattens the slope over the whole "
                  "range."]  # fmt: skip
    gaps = [
        100 * (r["accuracy"]["float32"] - r["accuracy"]["float16"])
        for r in report["rows"]
    ]
    if gaps:
        worst = max(np.abs(gaps))
        lines += ["", f"float16 against float32 self-query accuracy: at most "
                  f"{worst:.2f} points apart over {len(gaps)} maps."]  # fmt: skip
    probe = report.get("probe")
    if probe:
        lines += ["", *probe_lines(probe)]
    if report.get("missing"):
        lines += ["", "Not measured (time budget, or failed as said): "
                  + ", ".join(report["missing"])]  # fmt: skip
    lines += ["", "Figures: " + ", ".join(report["figures"])]
    return "\n".join(lines)


def probe_lines(p: dict) -> list[str]:
    per = p["pass_seconds"]
    return [
        f"Streamed probe: N = {p['n']:,} route-like {p['d']}-d frames"
        f" ({p['file_bytes'] / 2**30:.2f} GiB memory-mapped .npy), r = 3,"
        f" {p['templates']} templates, `--memory {p['memory']}` ({p['block_rows']}"
        f" rows per block): {len(per)} passes measured, {np.median(per):.1f} s per"
        f" pass (median; {', '.join(f'{v:.1f}' for v in per)}), peak resident"
        f" {p['peak_bytes'] / 2**20:.0f} MiB. The whole fit was not run: at"
        f" {p['passes_assumed']} passes (the most any streamed r = 3 fit above"
        f" took) it is projected at {p['projected_hours']:.1f} hours on this"
        f" loaded machine (projection, not a measurement).",
    ]


def grid(quick: bool) -> list[tuple]:
    """Cells (source, n, d, r, processes, mode), cheapest first."""
    if quick:
        ns, ds = (1000, 3000), (256,)
    else:
        ns, ds = (1000, 3000, 10000, 30000, 100000), (256, 2048)
    cells = [("walk", n, d, r, 1, "memory") for d in ds for r in (3, 2) for n in ns]
    cells += [("walk", n, 256, 3, 2, "memory") for n in ns if n <= 10000]
    cells += [("walk", n, 256, 3, k, "stream") for n in ns if n <= 10000
              for k in (1, 2)]  # fmt: skip
    if NORDLAND.is_file() and not quick:
        cells += [("nordland", n, 2048, r, 1, "memory") for n in (1000, 3576)
                  for r in (2, 3)]  # fmt: skip
    cost = {"memory": 1, "stream": 4}

    def order(c):  # the storage slope at d = 256, r = 3 first, then by cost
        return c[0] != "walk" or c[2:] != (256, 3, 1, "memory"), (
            c[1] * c[2] * (6 - c[3]) * cost[c[5]]
        )

    return sorted(cells, key=order)


def _key(cell: tuple) -> str:
    return "-".join(map(str, cell))


def features(source: str, n: int, d: int, cells: Path) -> Path:
    path = cells / f"{source}-{n}-{d}.npy"
    if not path.exists():
        x = walk(n, d) if source == "walk" else np.load(NORDLAND, mmap_mode="r")[:n]
        np.save(cells / "partial.npy", x)
        os.replace(cells / "partial.npy", path)
    return path


def probe(n: int, memory: str, cells: Path, passes_assumed: int) -> dict:
    """Stream passes of an r = 3 fit over n memory-mapped 256-d frames in a child
    process under ``memory``; its seconds per pass and peak memory."""
    saved = cells / f"probe-{n}-{memory}.json"
    if saved.exists():
        return json.loads(saved.read_text())
    path = cells / f"walk-{n}-256.npy"
    if not path.exists():
        part = np.lib.format.open_memmap(
            cells / "partial.npy", "w+", np.float32, (n, 256)
        )
        walk(n, 256, out=part)
        part.flush()
        del part
        os.replace(cells / "partial.npy", path)
    cmd = [sys.executable, "-c", _CHILD, str(path), memory]
    done = subprocess.run(
        [sys.executable, "-c", _PEAK, *cmd], capture_output=True, text=True
    )
    res = json.loads(done.stdout)
    if res["rc"] != 0:
        raise RuntimeError(done.stderr[-2000:])
    out = json.loads(res["out"].strip().splitlines()[-1])
    out.update(peak_bytes=res["peak"], memory=memory, file_bytes=path.stat().st_size,
               passes_assumed=passes_assumed, load=bc.load_average())  # fmt: skip
    out["projected_hours"] = (
        float(np.median(out["pass_seconds"])) * passes_assumed / 3600
    )
    saved.write_text(json.dumps(out))
    return out


_CHILD = """import json, sys
import jax.numpy as jnp
import numpy as np
from rhythmic_jax import RhythmicMap
from rhythmic_jax.io.frame_files import open_frames
from rhythmic_jax.scale_fit import block_rows_for, parse_bytes
from rhythmic_jax.solvers import streamed
frames = open_frames(sys.argv[1])
cands, c = RhythmicMap(r=3)._plan(frames.n)
p = sum(cands)
rows = block_rows_for(parse_bytes(sys.argv[2]), frames.d, p)
labels = np.arange(frames.n, dtype=np.int32)
stream = streamed._Stream(frames, 0, frames.n, labels, tuple(cands), rows,
                          lambda t: t)
theta = jnp.zeros((frames.d + 1, p), jnp.float32)
stream.run(streamed._grad_pass, theta)  # a gradient pass and a CG pass
stream.run(streamed._hess_pass, theta, theta + 1e-3)
print(json.dumps(dict(n=frames.n, d=frames.d, templates=p, block_rows=rows,
                      pass_seconds=stream.seconds)))"""


def main(argv=None) -> None:
    ap = bc.parser(__doc__)
    ap.add_argument("--quick", action="store_true", help="a small grid")
    ap.add_argument("--budget", type=float, default=1200.0, help="seconds in all")
    ap.add_argument("--memory", default="1GiB", help="memory bound of stream cells")
    ap.add_argument("--cells", type=Path, default=CELLS, help="saved cells, features")
    ap.add_argument("--probe", type=int, default=0, help="frames of the probe")
    ap.add_argument("--probe-memory", default="1GiB")
    args = ap.parse_args(argv)
    if args.render:
        bc.rerender(args.render, markdown)
        return
    os.nice(max(0, NICE - os.nice(0)))  # this process and every fit it starts
    env, load0 = bc.begin(log)
    args.cells.mkdir(parents=True, exist_ok=True)
    rows, missing, t0 = [], [], time.perf_counter()
    stamps = []
    for cell in grid(args.quick):
        saved = args.cells / f"{_key(cell)}.json"
        if saved.exists():
            rows.append(json.loads(saved.read_text()))
            stamps.append(rows[-1]["measured"])
            continue
        name = "{} N={} d={} r={} K={} {}".format(*cell)
        failed = args.cells / f"{_key(cell)}.failed"
        if failed.exists():
            missing.append(f"{name} (failed: {failed.read_text().strip()})")
            continue
        if time.perf_counter() - t0 > args.budget:
            missing.append(name)
            continue
        x_path = features(cell[0], cell[1], cell[2], args.cells)
        try:
            row = one(cell, x_path, args.cells, args.memory)
        except RuntimeError as err:
            log.warning("%s failed: %s", name, err)
            reason = str(err).strip().splitlines()[-1][-300:]
            failed.write_text(reason)
            missing.append(f"{name} (failed: {reason})")
            continue
        row.update(measured=time.strftime("%H:%M UTC", time.gmtime()),
                   load=bc.load_average())  # fmt: skip
        saved.write_text(json.dumps(bc.plain(row)))
        rows.append(row)
        stamps.append(row["measured"])
    report = bc.run_record("bench_scale.py", argv, env, load0)
    passes = [r["passes"] for r in rows if r["mode"] == "stream" and r["r"] == 3]
    if args.probe:
        try:
            found = probe(args.probe, args.probe_memory, args.cells, 100)
            per = float(np.median(found["pass_seconds"]))
            found["passes_assumed"] = max(passes, default=100)
            found["projected_hours"] = per * found["passes_assumed"] / 3600
            report["probe"] = found
        except RuntimeError as err:
            log.warning("probe failed: %s", err)
            missing.append(f"probe N={args.probe} (failed)")
    report.update(
        rows=rows,
        slopes=slopes(rows),
        missing=missing,
        memory=args.memory,
        cells_from=min(stamps, default="-"),
        cells_to=max(stamps, default="-"),
        load_cells="{:.1f} - {:.1f}".format(
            min((r["load"][0] for r in rows), default=0),
            max((r["load"][0] for r in rows), default=0),
        ),
        self_rss=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024,
    )
    report["figures"] = figures(rows, args.out) if rows else []
    bc.write_report(args.out, "scale", bc.plain(report), markdown(bc.plain(report)))


if __name__ == "__main__":
    main()
