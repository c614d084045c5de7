"""Streamed Newton-CG: passes compacted to the templates still going, against
passes over every template, in one run.

A streamed fit (:func:`rhythmic_jax.solvers.streamed.streamed_newton_fit`) reads
its frames from a ``.npy`` in blocks on every pass. Templates stop at different
Newton steps; with ``StreamConfig.compact`` the later passes carry only the
templates still going (padded to a power of two), without it every pass
carries all of them. Both settings run on the same file in turns
(``--repeats`` each), with ``FAST_STREAM`` (0.1 % estimated gap):

- ``nordland``: Nordland summer, patch-normalised 64x32 (3576 x 2048), the
  periods an in-memory fit of the same frames chooses (61, 65);
- ``walk``: route-like 256-d frames (``bench_scale.walk``: a smooth random
  walk, unit rows), N = ``--walk-frames``, r = 3 with fixed periods near N^(1/3).

The report gives each setting's wall time, steps, passes, the templates each
step carried and the largest relative difference of the final objectives.

    python scripts/bench_streamed.py [--repeats 2] [--walk-frames 100000]
"""

from __future__ import annotations

import logging
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from _bench_common import begin, header, parser, run_record, table, write_report
from bench_scale import walk
from bench_solver import nordland_summer

from rhythmic_jax.io.frame_files import open_frames
from rhythmic_jax.objective import default_c
from rhythmic_jax.solvers.streamed import FAST_STREAM, streamed_newton_fit

log = logging.getLogger("bench_streamed")
BLOCK_ROWS = 4096


def run_case(name, path: Path, periods, repeats: int) -> dict:
    """Both settings in turns on the frames in ``path``; the case's record."""
    frames = open_frames(path)
    labels = np.arange(frames.n)
    c = default_c(frames.n)
    runs: dict[str, list[dict]] = {"every template": [], "compacted": []}
    objectives = {}
    for rep in range(repeats):
        for label, compact in (("every template", False), ("compacted", True)):
            config = replace(FAST_STREAM, block_rows=BLOCK_ROWS, compact=compact)
            t0 = time.perf_counter()
            _, info = streamed_newton_fit(
                frames, labels, periods, c, config, progress=False
            )
            wall = time.perf_counter() - t0
            log.info("%s %s run %d: %.1f s, %d steps, columns %s", name, label,
                     rep, wall, info.steps, info.columns)  # fmt: skip
            runs[label].append(
                dict(
                    wall_s=wall,
                    steps=info.steps,
                    passes=len(info.pass_seconds),
                    cg_iterations=list(info.cg_iterations),
                    columns=list(info.columns),
                    column_passes=_column_passes(info),
                )
            )
            objectives[label] = info.objective
    ref, got = objectives["every template"], objectives["compacted"]
    return dict(
        name=name,
        n=frames.n,
        d=frames.d,
        periods=list(periods),
        templates=int(sum(periods)),
        runs=runs,
        median_wall_s={
            k: float(np.median([r["wall_s"] for r in v])) for k, v in runs.items()
        },
        objective_max_rel_diff=float(np.max(np.abs(got - ref) / np.abs(ref))),
    )


def _column_passes(info) -> int:
    """Template-columns carried over all passes: each step's gradient pass,
    CG passes and two line-search passes times its width."""
    return int(
        sum(w * (3 + k) for w, k in zip(info.columns, info.cg_iterations, strict=True))
    )


def markdown(report: dict) -> str:
    lines = header(
        "Streamed Newton-CG: compacted passes against every template", report
    )
    lines += [
        "Each case runs the streamed fit (`FAST_STREAM`: estimated gap <= 1e-3,"
        f" CG capped at 3 rising to 8; blocks of {BLOCK_ROWS} frames read from a"
        " memory-mapped `.npy`) with passes over every template and with passes"
        " compacted to the templates still going, in turns. Column-passes: the"
        " templates carried, summed over every pass (gradient, CG, two line-search"
        " passes per step).",
        "",
    ]
    rows = []
    for case in report["cases"]:
        for label, runs in case["runs"].items():
            first = runs[0]
            rows.append(
                [
                    case["name"],
                    f"{case['n']} x {case['d']}",
                    ", ".join(map(str, case["periods"])),
                    label,
                    case["median_wall_s"][label],
                    ", ".join(f"{r['wall_s']:.1f}" for r in runs),
                    first["steps"],
                    first["passes"],
                    " ".join(map(str, first["columns"])),
                    first["column_passes"],
                ]
            )
    lines.append(
        table(
            [
                "case",
                "frames",
                "periods",
                "passes carry",
                "median wall s",
                "runs s",
                "steps",
                "passes",
                "templates per step",
                "column-passes",
            ],
            rows,
        )  # fmt: skip
    )
    lines.append("")
    for case in report["cases"]:
        med = case["median_wall_s"]
        ratio = med["every template"] / med["compacted"]
        lines.append(
            f"- {case['name']}: compacted passes take {ratio:.2f}x less wall time"
            f" ({med['compacted']:.1f} s against {med['every template']:.1f} s);"
            " largest relative difference of the final objectives"
            f" {case['objective_max_rel_diff']:.1e}."
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict:
    ap = parser(__doc__)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--walk-frames", type=int, default=100_000)
    ap.add_argument("--walk-periods", default="46,47,49")
    args = ap.parse_args(argv)
    if args.render:
        from _bench_common import rerender

        return rerender(args.render, markdown)
    env, load0 = begin(log)
    cases = []
    with tempfile.TemporaryDirectory(prefix="bench_streamed_") as tmp:
        if (args.root / "nordland_64x32" / "summer").is_dir():
            path = Path(tmp) / "nordland.npy"
            np.save(path, nordland_summer(args.root, 3576, args.progress))
            cases.append(run_case("nordland", path, (61, 65), args.repeats))
        else:
            log.warning("no Nordland frames under %s: that case is left out", args.root)
        path = Path(tmp) / "walk.npy"
        np.save(path, walk(args.walk_frames, 256))
        periods = tuple(int(t) for t in args.walk_periods.split(","))
        cases.append(run_case("walk", path, periods, args.repeats))
    report = run_record("bench_streamed.py", argv, env, load0)
    report["cases"] = cases
    write_report(args.out, "streamed", report, markdown(report))
    return report


if __name__ == "__main__":
    main()
