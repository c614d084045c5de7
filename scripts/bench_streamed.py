"""Streamed Newton-CG: its preconditioner and its compacted passes, in one run.

python scripts/bench_streamed.py [--repeats 2] [--walk-frames 100000]
"""

import itertools
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
from _harness import header, log, main, nordland_features, table, timed
from bench_scale import walk

from rhythmic_jax.io.frame_files import open_frames
from rhythmic_jax.solvers.newton import newton_fit
from rhythmic_jax.solvers.objective import default_c, targets
from rhythmic_jax.solvers.streamed import FAST_STREAM, streamed_newton_fit

BLOCK_ROWS = 4096
SETTINGS = (
    ("Jacobi, every template", dict(spectral_rank=0, compact=False)),
    ("spectral, every template", dict(compact=False)),
    ("spectral, compacted", dict(compact=True)),
)
QUICK = dict(repeats=1, walk_frames=5000, walk_periods="17,18,19")  # --quick


def run_case(name, path: Path, periods, repeats: int) -> dict:
    """Every setting in turns on the frames in ``path``; the case's record."""
    frames = open_frames(path)
    labels, c = np.arange(frames.n), default_c(frames.n)
    y = targets(labels, periods)
    (_, ref), ref_s, _ = timed(lambda: newton_fit(frames.read(0, frames.n), y, c))
    runs: dict[str, list[dict]] = {label: [] for label, _ in SETTINGS}
    for rep in range(repeats):
        for label, settings in SETTINGS:
            config = replace(FAST_STREAM, block_rows=BLOCK_ROWS, **settings)
            fit = frames, labels, periods, c, config
            (_, info), wall, _ = timed(streamed_newton_fit, *fit, progress=False)
            log.info("%s %s run %d: %.1f s, %d steps, columns %s", name, label,
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


def markdown(report: dict) -> str:
    lines = header("Streamed Newton-CG: preconditioner and compacted passes", report)
    lines += [
        "Each case runs the streamed fit (`FAST_STREAM`: a template stops once its"
        " estimated gap is <= 1e-3, CG capped at 3 rising to 8, at most 40 Newton"
        f" steps; blocks of {BLOCK_ROWS} frames read from a memory-mapped `.npy`) in"
        " three settings, in turns. Reached: templates whose estimated gap met 1e-3."
        " True gap: (f - f*) / f* of the final objectives against the in-memory Newton"
        " optimum (tight) of the same frames. Column-passes: templates carried, summed"
        " over every pass (gradient, CG and line-search passes of every step).",
        "",
    ]
    rows = []
    for case in report["cases"]:
        for label, runs in case["runs"].items():
            first = runs[-1]
            rows.append([case["name"], f"{case['n']} x {case['d']}",
                         ", ".join(map(str, case["periods"])), label,
                         case["median_wall_s"][label],
                         ", ".join(f"{r['wall_s']:.1f}" for r in runs), first["steps"],
                         first["passes"], f"{first['reached']} / {case['templates']}",
                         f"{first['true_gap_max']:.1e}",
                         f"{first['true_gap_median']:.1e}", _widths(first["columns"]),
                         first["column_passes"]])  # fmt: skip
    heads = ["case", "frames", "periods", "setting", "median wall s", "runs s",
             "steps", "passes", "reached", "true gap max", "true gap median",
             "templates per step", "column-passes"]  # fmt: skip
    lines += [table(heads, rows), ""]
    for case in report["cases"]:
        old, spec, comp = (case["median_wall_s"][label] for label, _ in SETTINGS)
        lines.append(
            f"- {case['name']}: the spectral preconditioner {old / spec:.2f}x"
            f" ({spec:.1f} s against {old:.1f} s with Jacobi); compacted passes"
            f" {spec / comp:.2f}x on top ({comp:.1f} s); the in-memory reference"
            f" took {case['reference_s']:.1f} s."
        )
    return "\n".join(lines)


def _widths(columns: list[int]) -> str:
    """Templates per step, runs of equal widths shortened: '126 x 12, 8 x 2'."""
    runs = [(w, len(list(same))) for w, same in itertools.groupby(columns)]
    return ", ".join(f"{w} x {k}" if k > 1 else str(w) for w, k in runs)


def options(ap) -> None:
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--walk-frames", type=int, default=100_000)
    ap.add_argument("--walk-periods", default="46,47,49")


def run(args) -> dict:
    cases = []
    with tempfile.TemporaryDirectory(prefix="bench_streamed_") as tmp:
        if (args.root / "nordland_64x32" / "summer").is_dir() and not args.quick:
            path = Path(tmp) / "nordland.npy"
            np.save(path, nordland_features(args.root, seasons=("summer",))[0])
            cases.append(run_case("nordland", path, (61, 65), args.repeats))
        else:
            log.warning("the Nordland case is left out (--quick or no frames)")
        path = Path(tmp) / "walk.npy"
        np.save(path, walk(args.walk_frames, 256))
        periods = tuple(int(t) for t in args.walk_periods.split(","))
        cases.append(run_case("walk", path, periods, args.repeats))
    return dict(cases=cases)


if __name__ == "__main__":
    main(__doc__, run, markdown, options, stem="streamed", quick=QUICK)
