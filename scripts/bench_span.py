"""Wide frames: the joint solve over the frames' span against the direct solve.

python scripts/bench_span.py [--frames 3576] [--level 1]
"""

import dataclasses

import jax
import numpy as np
from _harness import header, main, nordland_features, stats, table, timed

from rhythmic_jax.frames.features import get_descriptor
from rhythmic_jax.map.periods import candidate_periods
from rhythmic_jax.solvers.newton import NewtonConfig, newton_fit
from rhythmic_jax.solvers.objective import Templates, default_c, objective, targets

QUICK = dict(frames=400)  # --quick


def markdown(report: dict) -> str:
    rows = [[r["solver"], r["wall_s"], r["cpu_s"], r["steps"], r["cg_iterations"]]
            for r in report["rows"]]  # fmt: skip
    gap = report["gap_span_vs_direct"]
    title = "Wide frames: solve in the frames' span vs directly"
    return "\n".join([*header(title, report), "\n\n".join([
        f"Nordland summer, {report['descriptor']} ({report['settings']}): "
        f"n = {report['n']}, d = {report['d']}, level {report['level']}, "
        f"p = {report['p']} templates, C = log N. Both to the optimum (default "
        "NewtonConfig); each time includes its compilation (a few seconds).",
        table(["solver", "wall s", "CPU s", "Newton steps", "CG iterations"], rows),
        f"Span / direct: {report['speedup_wall']:.2f}x faster (wall), "
        f"{report['speedup_cpu']:.2f}x (CPU). Relative objective gap, span "
        f"minus direct, over all templates: max {gap['max']:+.2e}, median "
        f"{gap['median']:+.2e}, min {gap['min']:+.2e}.",
    ])])  # fmt: skip


def options(ap) -> None:
    ap.add_argument("--frames", type=int, default=3576)
    ap.add_argument("--level", type=int, default=1)
    ap.add_argument("--descriptor", default="efficientnet_lite0")


def run(args) -> dict:
    desc = get_descriptor(args.descriptor)
    (x,) = nordland_features(args.root, desc, ("summer",), progress=args.progress)
    x = x[: args.frames]
    n, d = x.shape
    cands = candidate_periods(n, 2, args.level, 7)
    y, c = targets(np.arange(n), cands), default_c(n)
    rows, answers = [], {}
    for name, cfg in (
        ("span (n-dim)", NewtonConfig()),
        ("direct (d-dim)", dataclasses.replace(NewtonConfig(), span=False)),
    ):
        (params, info), wall, cpu = timed(newton_fit, x, y, c, cfg, False)
        with jax.enable_x64(True):  # every template's objective, in float64
            w, b = (np.asarray(v, np.float64) for v in params)
            x64, y64 = np.asarray(x, np.float64), np.asarray(y, np.float64)
            answers[name] = np.asarray(objective(Templates(w, b), x64, y64, c))
        rows.append(dict(solver=name, wall_s=wall, cpu_s=cpu, steps=info.steps,
                         cg_iterations=sum(info.cg_iterations)))  # fmt: skip
        print(rows[-1], flush=True)
    span, direct = answers["span (n-dim)"], answers["direct (d-dim)"]
    return dict(descriptor=args.descriptor, settings=desc.settings(), n=n, d=d,
                level=args.level, p=sum(cands), rows=rows,
                speedup_wall=rows[1]["wall_s"] / rows[0]["wall_s"],
                speedup_cpu=rows[1]["cpu_s"] / rows[0]["cpu_s"],
                gap_span_vs_direct=stats((span - direct) / direct))  # fmt: skip


if __name__ == "__main__":
    main(__doc__, run, markdown, options, stem="span", quick=QUICK)
