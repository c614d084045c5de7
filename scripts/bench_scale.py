"""Growth from real fits: storage, time, passes and memory against N, d, r, processes.

Every fit is the installed ``rhythmic-jax fit`` streamed from a ``.npy`` file
(``--stream --gap 1e-3``), run under a wrapper that reads its peak resident
memory (``ru_maxrss`` of its children, the processes of a ``--processes 2``
fit included). Features are route-like: a smooth random walk in feature space
(unit rows), and Nordland summer sub-routes (patch-normalised, 2048-d) where N
allows. Self-query accuracy: every reference frame queried against its own
map, with the templates as float32, float16 and int8. Storage slopes: least
squares of log bytes on log N per (d, r), against 1/r.

    python scripts/bench_scale.py --quick          # a small grid (minutes)
    python scripts/bench_scale.py --budget 1500    # the grid, up to 25 minutes
"""

from __future__ import annotations

import json
import logging
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import _bench_common as bc
import numpy as np

from rhythmic_jax import RhythmicMap
from rhythmic_jax.io.frame_files import open_frames

log = logging.getLogger("bench_scale")
NORDLAND = Path("/work/cache/nordland_summer_patchnorm.npy")
_PEAK = """import resource, subprocess, sys, time
t = time.perf_counter()
done = subprocess.run(sys.argv[1:], capture_output=True, text=True)
sys.stderr.write(done.stderr[-3000:])
print(json.dumps(dict(rc=done.returncode, seconds=time.perf_counter() - t,
    peak=resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024,
    out=done.stdout)))"""


def walk(n: int, d: int, seed: int = 0) -> np.ndarray:
    """Route-like frames (n, d) float32, unit rows: a smooth random walk in
    feature space (the route's slow change) plus an independent perturbation per
    frame (what tells neighbouring places apart)."""
    rng = np.random.default_rng(seed)
    x = np.empty((n, d), np.float32)
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


def run_fit(path: Path, out: Path, r: int, procs: int, memory: str) -> dict:
    cmd = [
        "rhythmic-jax",
        "fit",
        str(path),
        "--out",
        str(out),
        "--r",
        str(r),
        "--gap",
        "1e-3",
        "--stream",
        "--memory",
        memory,
        "--json",
        "--no-progress",
        "--processes",
        str(procs),
    ]
    wrapper = "import json\n" + _PEAK
    done = subprocess.run(
        [sys.executable, "-c", wrapper, *cmd], capture_output=True, text=True
    )
    res = json.loads(done.stdout)
    if res["rc"] != 0:
        raise RuntimeError(done.stderr[-2000:])
    text = res["out"]
    info = json.loads(text[text.index("{") :])
    return dict(seconds=res["seconds"], peak=res["peak"], info=info)


def one(
    source: str,
    x_path: Path,
    n: int,
    d: int,
    r: int,
    procs: int,
    tmp: Path,
    memory: str,
) -> dict:
    out = tmp / f"{source}-{n}-{d}-{r}-{procs}.map"
    fit = run_fit(x_path, out, r, procs, memory)
    model = RhythmicMap.load(out)
    frames = open_frames(x_path)
    acc = {"float32": accuracy(model, frames, n)}
    for dtype in ("float16", "int8"):
        acc[dtype] = accuracy(model.with_dtype(dtype), frames, n)
    info = fit["info"]
    row = dict(
        source=source,
        n=n,
        d=d,
        r=r,
        processes=procs,
        periods=info["periods"],
        storage_bytes=info["storage_bytes"],
        bytes_per_place=info["storage_bytes"] / n,
        float16_bytes=model.with_dtype("float16").storage_bytes,
        int8_bytes=model.with_dtype("int8").storage_bytes,
        fit_seconds=fit["seconds"],
        peak_bytes=fit["peak"],
        steps=info["fit"]["steps"],
        passes=info["fit"]["passes"],
        pass_median_s=info["fit"]["pass_median_s"],
        block_rows=info["fit"]["block_rows"],
        accuracy=acc,
    )
    log.info("%s", row)
    return row


def slopes(rows: list[dict]) -> list[dict]:
    """Least-squares slope of log storage on log N per (source, d, r, processes=1)."""
    out = []
    keys = sorted({(r["source"], r["d"], r["r"]) for r in rows if r["processes"] == 1})
    for source, d, r in keys:
        pts = [
            x
            for x in rows
            if (x["source"], x["d"], x["r"], x["processes"]) == (source, d, r, 1)
        ]
        if len({p["n"] for p in pts}) < 2:
            continue
        lx = np.log([p["n"] for p in pts])
        ly = np.log([p["storage_bytes"] for p in pts])
        slope = float(np.polyfit(lx, ly, 1)[0])
        out.append(
            dict(
                source=source,
                d=d,
                r=r,
                points=len(pts),
                slope=slope,
                target=1 / r,
                within=abs(slope - 1 / r) <= 0.05,
            )
        )
    return out


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
        groups = sorted({(r["source"], r["d"], r["r"], r["processes"]) for r in rows})
        for g in groups:
            pts = sorted(
                (r["n"], r[key])
                for r in rows
                if (r["source"], r["d"], r["r"], r["processes"]) == g
            )
            if pts:
                ax.loglog(
                    *zip(*pts, strict=True),
                    "o-",
                    label=f"{g[0]} d={g[1]} r={g[2]} K={g[3]}",
                )
        ax.set_xlabel("N (places)")
        ax.set_ylabel(label)
        ax.legend(fontsize=6)
        fig.tight_layout()
        fig.savefig(out_dir / f"{stem}.png", dpi=110)
        plt.close(fig)
        names.append(f"{stem}.png")
    return names


def markdown(report: dict) -> str:
    lines = bc.header("Growth from real fits (streamed, --gap 1e-3)", report)
    head = [
        "source",
        "N",
        "d",
        "r",
        "K",
        "periods",
        "bytes",
        "B/place",
        "fit s",
        "passes",
        "s/pass",
        "peak MiB",
        "acc f32",
        "acc f16",
        "acc int8",
    ]
    rows = [
        [
            r["source"],
            r["n"],
            r["d"],
            r["r"],
            r["processes"],
            "x".join(map(str, r["periods"])),
            r["storage_bytes"],
            round(r["bytes_per_place"], 2),
            round(r["fit_seconds"], 1),
            r["passes"],
            round(r["pass_median_s"], 3),
            round(r["peak_bytes"] / 2**20),
            round(r["accuracy"]["float32"], 4),
            round(r["accuracy"]["float16"], 4),
            round(r["accuracy"]["int8"], 4),
        ]
        for r in report["rows"]
    ]
    lines += [bc.table(head, rows), "", "Storage slopes (log bytes on log N):", ""]
    lines += [
        bc.table(
            ["source", "d", "r", "points", "slope", "1/r", "within 0.05"],
            [
                [
                    s["source"],
                    s["d"],
                    s["r"],
                    s["points"],
                    round(s["slope"], 4),
                    round(s["target"], 4),
                    str(s["within"]),
                ]
                for s in report["slopes"]
            ],
        )
    ]
    if report.get("missing"):
        lines += ["", "Not run (time budget): " + ", ".join(report["missing"])]
    lines += ["", "Figures: " + ", ".join(report["figures"])]
    return "\n".join(lines)


def grid(quick: bool) -> list[tuple]:
    if quick:
        ns, ds = (1000, 3000, 10000), (256,)
    else:
        ns, ds = (1000, 3000, 10000, 30000, 100000), (256, 2048)
    cfgs = []
    for d in ds:
        for r in (3, 2):
            for n in ns:
                cfgs.append(("walk", n, d, r, 1))
    cfgs += [("walk", n, 256, 3, 2) for n in ns if n <= 30000]  # two processes
    if NORDLAND.is_file():
        cfgs += [
            ("nordland", n, 2048, r, 1) for n in (1000, 3000, 3576) for r in (2, 3)
        ]
    return sorted(cfgs, key=lambda c: c[1] * c[2] * (2 if c[3] == 2 else 1))


def main(argv=None) -> None:
    ap = bc.parser(__doc__)
    ap.add_argument("--quick", action="store_true", help="a small grid")
    ap.add_argument("--budget", type=float, default=1200.0, help="seconds in all")
    ap.add_argument("--memory", default="2GiB", help="memory bound of every fit")
    args = ap.parse_args(argv)
    if args.render:
        bc.rerender(args.render, markdown)
        return
    env, load0 = bc.begin(log)
    rows, missing, t0 = [], [], time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for source, n, d, r, procs in grid(args.quick):
            name = f"{source} N={n} d={d} r={r} K={procs}"
            if time.perf_counter() - t0 > args.budget:
                missing.append(name)
                continue
            x_path = tmp / f"{source}-{n}-{d}.npy"
            if not x_path.exists():
                if source == "walk":
                    np.save(x_path, walk(n, d))
                else:
                    np.save(x_path, np.load(NORDLAND, mmap_mode="r")[:n])
            try:
                rows.append(one(source, x_path, n, d, r, procs, tmp, args.memory))
            except RuntimeError as err:
                log.warning("%s failed: %s", name, err)
                missing.append(name + " (failed)")
    report = bc.run_record("bench_scale.py", argv, env, load0)
    report.update(
        rows=rows,
        slopes=slopes(rows),
        missing=missing,
        memory=args.memory,
        self_rss=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024,
    )
    report["figures"] = figures(rows, args.out) if rows else []
    bc.write_report(args.out, "scale", bc.plain(report), markdown(bc.plain(report)))


if __name__ == "__main__":
    main()
