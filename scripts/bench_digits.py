"""Digits that group frames that look alike: map layouts across seasons on Nordland.

python scripts/bench_digits.py          # writes reports/digits.{json,md}
"""

import itertools
from pathlib import Path

import jax.numpy as jnp
import numpy as np
from _harness import header, log, main, table, timed

from rhythmic_jax import database_bytes, storage_bytes
from rhythmic_jax.decoding.dispatch import decode_scores
from rhythmic_jax.decoding.sequence import sequence_decode
from rhythmic_jax.decoding.soft import calibrate
from rhythmic_jax.eval.metrics import accuracy, recall_at_k
from rhythmic_jax.eval.report import ranked_places
from rhythmic_jax.eval.seqslam import seqslam_decode
from rhythmic_jax.eval.split import NORDLAND_SPLIT
from rhythmic_jax.map.groups import Groups, parse_layout, resolve_layout
from rhythmic_jax.map.periods import candidate_periods, choose_periods
from rhythmic_jax.solvers.newton import NewtonConfig, newton_fit
from rhythmic_jax.solvers.objective import default_c, period_errors, scores, targets

TOL = 1
LENGTHS = (5, 10, 20)
QUICK = dict(levels="1")  # --quick


def layouts(n: int, levels) -> list[tuple[str, int, Groups]]:
    """(name, level, groups) of every map measured."""
    out = []
    for level in levels:
        cands = candidate_periods(n, 2, level)
        per = choose_periods(cands, [0.0] * len(cands), n, 2)
        out.append(("periods", level, Groups("periods", per)))
        for kind in ("mixed", "hierarchical"):
            out.append((kind, level, resolve_layout(parse_layout(kind), n, 2, level)))
        # the same storage as the periods (the budget rule keeps a little less)
        t = next(t for t in itertools.count(2) if -(-n // t) + t <= sum(per) + 6)
        equal = Groups("mixed", (-(-n // t), t))
        if sum(per) - out[-2][2].p > 10:
            out.append(("mixed, equal storage", level, equal))
    return out


def measure(groups: Groups, s_self, s_query, n: int, gt) -> dict:
    """Every figure of one map from its template scores (b, p) of both conditions."""
    self_hard = np.asarray(decode_scores(s_self, groups, n, "hard").index)
    hard = np.asarray(decode_scores(s_query, groups, n, "hard").index)
    row = {
        "self_query_hard": accuracy(self_hard, gt, 0),
        "hard": accuracy(hard, gt, TOL),
        # per group: winter queries whose argmax label is their place's label
        "label_accuracy": np.asarray(
            1.0 - period_errors(jnp.asarray(s_query), gt, groups)
        ).tolist(),
        "label_chance": [1.0 / t for t in groups.sizes],
    }
    soft = {}
    for name, sc in (("raw", s_query), ("calibrated", calibrate(s_query, groups))):
        soft[name] = np.asarray(decode_scores(sc, groups, n, "soft").index)
        ranked = ranked_places(sc, groups, n, 5)
        row[f"soft_{name}"] = accuracy(soft[name], gt, TOL)
        row[f"soft_{name}_exact"] = accuracy(soft[name], gt, 0)
        row[f"recall@5_{name}"] = recall_at_k(ranked, gt, (5,), tolerance=TOL)[5]
        for length in LENGTHS:
            idx, _ = sequence_decode(sc, groups, n, length, (1.0,), "soft")
            row[f"seq{length}_{name}"] = accuracy(np.asarray(idx), gt, TOL)
    row["calibrated_same_index"] = float(np.mean(soft["raw"] == soft["calibrated"]))
    return row


def brute(summer, winter, gt) -> dict:
    top = np.argsort(-(winter @ summer.T), axis=1)[:, :5]
    row = {
        "soft_raw": accuracy(top[:, 0], gt, TOL),
        "soft_raw_exact": accuracy(top[:, 0], gt, 0),
        "recall@5_raw": recall_at_k(top, gt, (5,), tolerance=TOL)[5],
    }
    for length in LENGTHS:
        idx, _ = seqslam_decode(winter, summer, length, (1.0,), progress=False)
        row[f"seq{length}_raw"] = accuracy(np.asarray(idx), gt, TOL)
    return row


def markdown(report: dict) -> str:
    lines = header("Digits that group frames that look alike (Nordland)", report)
    lines.append(
        f"Nordland test places {report['places']} (N = {report['n']}), "
        f"{report['descriptor']} d = {report['d']}: summer map, winter queries, "
        f"recall@1 within ±{TOL} frame unless marked exact. One joint Newton solve "
        f"of {report['templates_total']} templates, C = log N: "
        f"{report['fit_wall_s']:.0f} s wall. Storage: sum of group sizes x (d + 1) "
        f"float32 over the N x d float32 database."
    )
    cols = ["layout", "sizes", "storage %", "self hard", "hard", "soft", "soft exact",
            "R@5", "L=5", "L=10", "L=20", "label acc. (chance)"]  # fmt: skip
    rows = [[
        r["layout"], r["sizes"], round(100 * r["ratio"], 1),
        r.get("self_query_hard", "-"), r.get("hard", "-"), r["soft_raw"],
        r["soft_raw_exact"], r["recall@5_raw"],
        *(r[f"seq{length}_raw"] for length in LENGTHS),
        " ".join(f"{a:.3f} ({c:.3f})" for a, c in zip(r.get("label_accuracy", ()),
                 r.get("label_chance", ()), strict=True)) or "-",
    ] for r in report["rows"]]  # fmt: skip
    lines += ["", table(cols, rows), ""]
    same = [r for r in report["rows"] if "calibrated_same_index" in r]
    lines.append(
        "soft: argmax of the summed template scores of every group (a log-softmax "
        "within every group, rhythmic_jax.decoding.soft.calibrate, shifts every "
        "place of a query by the same constant: the same argmax, checked here); "
        "sequences sum the place scores at speed 1 (brute force: cosine sums along the "
        "diagonal); same index after calibration: "
        + ", ".join(f"{r['calibrated_same_index']:.3f}" for r in same)
        + ". label acc.: per group, the fraction of winter queries whose "
        "argmax class is their place's label (most significant digit / segment "
        "first), beside chance 1 / size."
    )
    return "\n".join(lines)


def options(ap) -> None:
    ap.add_argument("--cache", type=Path, default=Path("/work/cache"))
    ap.add_argument("--descriptor", default="efficientnet_lite0")
    ap.add_argument("--levels", default="1,2,4", help="storage levels (1,2,4)")


def run(args) -> dict:
    test = NORDLAND_SPLIT.test
    path = str(args.cache / f"nordland_%s_{args.descriptor}.npy")  # per season
    summer, winter = (np.ascontiguousarray(np.load(path % s, mmap_mode="r")[test])
                      for s in ("summer", "winter"))  # fmt: skip
    n, d = summer.shape
    gt, maps = np.arange(n), layouts(n, [int(v) for v in args.levels.split(",")])
    y = jnp.concatenate([targets(gt, g) for _, _, g in maps], axis=1)
    log.info("fitting %d templates on %d x %d", y.shape[1], n, d)
    fit = summer, y, default_c(n), NewtonConfig()
    (params, _), fit_wall, _ = timed(newton_fit, *fit, progress=args.progress)
    s_self = np.asarray(scores(params, jnp.asarray(summer)))
    s_query = np.asarray(scores(params, jnp.asarray(winter)))
    rows, start = [], 0
    for kind, level, groups in maps:
        cols = slice(start, start + groups.p)
        start += groups.p
        row = measure(groups, s_self[:, cols], s_query[:, cols], n, gt)
        row.update(
            layout=f"{kind} (level {level})", kind=kind, level=level,
            sizes=groups.describe(), templates=groups.p,
            storage_bytes=storage_bytes(groups.sizes, d),
            ratio=storage_bytes(groups.sizes, d, 1) / database_bytes(n, d, 1),
        )  # fmt: skip
        log.info("%s", row)
        rows.append(row)
    bf = brute(summer, winter, gt)
    bf.update(layout="brute force", sizes="-", ratio=1.0,
              storage_bytes=database_bytes(n, d))  # fmt: skip
    rows.append(bf)
    return dict(descriptor=args.descriptor, places=f"{int(test[0])}-{int(test[-1])}",
                n=n, d=d, templates_total=int(y.shape[1]), fit_wall_s=fit_wall,
                tolerance=TOL, rows=rows)  # fmt: skip


if __name__ == "__main__":
    main(__doc__, run, markdown, options, stem="digits", quick=QUICK)
