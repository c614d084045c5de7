"""Recognition under appearance change, on a split by place.

Everything learned sees the training places only; maps are fitted on one
condition of the *test* places and queried with the other, in both directions:

- Nordland 64x32 (EfficientNet-Lite0 block 10, and patchnorm): places 0-1199
  train, 1220-3575 test (``rhythmic_jax.NORDLAND_SPLIT``); summer and winter.
- Aerial pairs (patchnorm 64-pixel tiles, stride 32): the DSIFN pairs train, the
  LEVIR pairs are scored (whole pairs held out); image A and image B.

Rows, on the same test frames in one run: brute force (cosine, faiss-free
exact search) on the raw descriptor and on every embedding; SeqSLAM on the raw
descriptor at the same L; the map (squared-hinge templates, soft place-domain
decode, phase-domain sequences) on the raw descriptor and with every embedding,
in the sub-linear regime (``level`` as on main) and as the best map that fits
in 15 % of the raw database's bytes, the embedding's parameters included.
Recall@1 within +-1 (and exact), recall@5 within +-1, sequences L = 5, 10, 20.

    python scripts/bench_cross_condition.py            # reports/cross_condition.*
    python scripts/bench_cross_condition.py --quick    # patchnorm, closed form only
"""

from __future__ import annotations

import logging
import math
import time
from pathlib import Path

import numpy as np
from _bench_common import (
    begin,
    header,
    parser,
    rerender,
    run_record,
    table,
    write_report,
)

from rhythmic_jax.embedding import apply, embedding_bytes
from rhythmic_jax.eval.seqslam import seqslam_decode
from rhythmic_jax.features import cached_describe, get_descriptor
from rhythmic_jax.io.images import nordland
from rhythmic_jax.io.tiles import load_aerial_route
from rhythmic_jax.learn import LearnConfig, learn_embedding
from rhythmic_jax.periods import database_bytes, period_offsets
from rhythmic_jax.rhythmic_map import RhythmicMap
from rhythmic_jax.split import NORDLAND_SPLIT

log = logging.getLogger("bench_cross_condition")
TOL = 1
LENGTHS = (5, 10, 20)
BUDGET = 0.15


def nordland_data(root: Path, name: str, progress: bool):
    desc = get_descriptor(name)
    trav = nordland(root / "nordland_64x32", progress=progress)
    s, w = (
        cached_describe(t.images, desc, f"nordland_{season}", progress=progress)
        for t, season in zip(trav, ("summer", "winter"), strict=True)
    )
    tr, te = NORDLAND_SPLIT.train, NORDLAND_SPLIT.test
    return dict(train=[s[tr], w[tr]], test=[s[te], w[te]], names=("summer", "winter"))


def aerial_data(root: Path, progress: bool):
    desc = get_descriptor("patchnorm")
    out = {}
    for part, folder in (("train", "samples_DSIFN"), ("test", "samples_LEVIR")):
        route = load_aerial_route(root / "aerial_pairs" / folder, progress=progress)
        out[part] = [
            cached_describe(tiles, desc, f"{folder}-64-32-{side}", progress=progress)
            for tiles, side in ((route.map_tiles, "a"), (route.query_tiles, "b"))
        ]
    out["names"] = ("A", "B")
    return out


def _recall(scores: np.ndarray, k: int) -> float:
    gt = np.arange(len(scores))
    top = np.argsort(-scores, axis=1)[:, :k]
    return float(np.mean(np.any(np.abs(top - gt[:, None]) <= TOL, axis=1)))


def _acc(pred, tol=TOL) -> float:
    pred = np.asarray(pred)
    return float(np.mean(np.abs(pred - np.arange(len(pred))) <= tol))


def brute_row(ref, qry, label, extra_bytes=0, k_bytes=None):
    r = ref / np.linalg.norm(ref, axis=1, keepdims=True)
    q = qry / np.linalg.norm(qry, axis=1, keepdims=True)
    sim = q @ r.T
    pred = sim.argmax(1)
    return dict(
        method=label,
        r1=_acc(pred),
        r1_exact=_acc(pred, 0),
        r5=_recall(sim, 5),
        template_bytes=int(r.size * 4),
        embedding_bytes=int(extra_bytes),
    )


def seqslam_row(ref, qry):
    row = dict(method="SeqSLAM raw", template_bytes=int(ref.size * 4))
    for L in LENGTHS:
        idx, _ = seqslam_decode(qry, ref, L, progress=False)
        row[f"L{L}"] = _acc(idx)
    return row


def map_row(ref, qry, label, level, emb=None, fit_seconds=None):
    t0 = time.perf_counter()
    m = RhythmicMap(r=2, level=level, gap=1e-3, embedding=emb).fit(ref, progress=False)
    fit_s = time.perf_counter() - t0
    s = np.asarray(m.scores(qry))
    offs = period_offsets(m.periods)
    place = sum(
        s[:, o + np.arange(m.n) % t] for o, t in zip(offs, m.periods, strict=True)
    )
    row = dict(
        method=label,
        level=level,
        periods=list(m.periods),
        r1=_acc(m.predict(qry, "soft")),
        r1_exact=_acc(m.predict(qry, "soft"), 0),
        r5=_recall(place, 5),
        template_bytes=m.storage_bytes,
        embedding_bytes=m.embedding_bytes,
        fit_seconds=fit_s,
    )
    for L in LENGTHS:
        row[f"L{L}"] = _acc(m.predict(qry, "soft", sequence=L))
    return row


def budget_level(n: int, d_raw: int, k: int, emb_bytes: int) -> int:
    """Largest level whose r = 2 periods fit in BUDGET of the raw database."""
    room = BUDGET * database_bytes(n, d_raw, 4) - emb_bytes
    step = math.isqrt(n - 1) + 1
    per_period = room / (4 * (k + 1)) / 2 - 6
    return max(1, min(int(per_period // step), (n - 7) // step))


def run_dataset(name: str, data: dict, cfg: dict, progress: bool) -> dict:
    train, test = data["train"], data["test"]
    n, d_raw = test[0].shape
    embeddings, learn_info = {}, {}
    for label, lc in cfg["levers"].items():
        t0 = time.perf_counter()
        emb, info = learn_embedding(train, lc)
        info["seconds"] = time.perf_counter() - t0
        embeddings[label], learn_info[label] = emb, info
        log.info("%s: learned %s in %.1f s", name, label, info["seconds"])
    directions = {}
    for a, b in ((0, 1), (1, 0)):
        key = f"{data['names'][a]}->{data['names'][b]}"
        ref, qry = test[a], test[b]
        rows = [brute_row(ref, qry, "brute force raw"), seqslam_row(ref, qry)]
        rows.append(map_row(ref, qry, "map raw", cfg["level"]))
        for label, emb in embeddings.items():
            eb = embedding_bytes(emb)
            rows.append(
                brute_row(apply(emb, ref), apply(emb, qry), f"brute force {label}", eb)
            )
            rows.append(map_row(ref, qry, f"map {label}", cfg["level"], emb))
            lvl = budget_level(n, d_raw, emb.k, eb)
            rows.append(map_row(ref, qry, f"map {label} (15 % budget)", lvl, emb))
            log.info("%s %s %s done", name, key, label)
        db = database_bytes(n, d_raw, 4)
        for r in rows:
            r["ratio"] = (r["template_bytes"] + r.get("embedding_bytes", 0)) / db
        directions[key] = rows
    return dict(n=n, d=d_raw, learn=learn_info, directions=directions)


def markdown(report: dict) -> str:
    lines = header("Recognition under appearance change (split by place)", report)
    lines += [
        "Maps are fitted on one condition of the test places and queried with the "
        "other; every embedding was learned on the training places only. R@1 and "
        "R@5 within +-1 frame; `exact` without tolerance; L = phase-domain sequence "
        "(map) or SeqSLAM (raw descriptor). Storage: templates (or the database for "
        "brute force) and, apart, the embedding's parameters (stored once, not "
        "growing with N); ratio = both over the raw database.",
        "",
        "Digits that group frames that look alike (mixed-radix and hierarchical "
        "maps): rows to be added here once those maps are on main.",
        "",
    ]
    heads = ["method", "R@1", "exact", "R@5", "L=5", "L=10", "L=20",
             "templates B", "embedding B", "ratio", "periods", "fit s"]  # fmt: skip
    for name, ds in report["datasets"].items():
        lines += [f"## {name} (N = {ds['n']}, d = {ds['d']})", ""]
        learn = ", ".join(
            f"{k}: {v['seconds']:.1f} s (kept step {v.get('kept_step', '-')})"
            for k, v in ds["learn"].items()
        )
        lines += [f"Learning time on the training places: {learn}.", ""]
        for key, rows in ds["directions"].items():
            lines += [f"### {key}", ""]
            body = [
                [r["method"]]
                + [r.get(c, "") for c in ("r1", "r1_exact", "r5", "L5", "L10", "L20")]
                + [
                    r.get("template_bytes", ""),
                    r.get("embedding_bytes", 0),
                    r["ratio"],
                    str(tuple(r.get("periods", ()))) or "",
                    r.get("fit_seconds", ""),
                ]  # fmt: skip
                for r in rows
            ]
            lines += [table(heads, body), ""]
    return "\n".join(lines)


def draw(report: dict, path: Path) -> None:
    """R@1 (+-1) and L = 10 of every row, one panel per data set (first direction)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sets = report["datasets"]
    fig, axes = plt.subplots(1, len(sets), figsize=(6 * len(sets), 5), squeeze=False)
    for ax, (name, ds) in zip(axes[0], sets.items(), strict=True):
        key, rows = next(iter(ds["directions"].items()))
        y = np.arange(len(rows))
        ax.barh(y - 0.2, [r.get("r1", 0) for r in rows], 0.4, label="R@1 single frame")
        ax.barh(y + 0.2, [r.get("L10", 0) for r in rows], 0.4, label="L = 10")
        ax.set_yticks(y, [f"{r['method']} ({100 * r['ratio']:.1f} %)" for r in rows])
        ax.invert_yaxis()
        ax.set_xlim(0, 1)
        ax.set_title(f"{name}, {key}", fontsize=9)
        ax.tick_params(labelsize=7)
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> None:
    ap = parser(__doc__)
    ap.add_argument(
        "--quick", action="store_true", help="patchnorm, the closed form, level 1"
    )
    args = ap.parse_args(argv)
    if args.render:
        rerender(args.render, markdown)
        return
    env, load0 = begin(log)
    levers = {
        "invariant": LearnConfig(method="invariant"),
        "learned through the map": LearnConfig(method="map", steps=150),
        "InfoNCE": LearnConfig(method="infonce", steps=150),
    }
    sets = [("Nordland patchnorm", "patchnorm", 4)]
    if args.quick:  # the closed form only, shorter periods: minutes on 2 cores
        levers = {"invariant": LearnConfig(method="invariant")}
        sets = [("Nordland patchnorm", "patchnorm", 1)]
    else:
        sets.insert(0, ("Nordland EfficientNet-Lite0", "efficientnet_lite0", 4))
    datasets = {}
    for title, desc, level in sets:
        data = nordland_data(args.root, desc, args.progress)
        datasets[title] = run_dataset(
            title, data, dict(levers=levers, level=level), args.progress
        )
    if not args.quick:
        cfg = dict(levers={"invariant": LearnConfig(method="invariant", k=128, p=256)},
                   level=1)  # fmt: skip
        datasets["Aerial pairs patchnorm"] = run_dataset(
            "aerial", aerial_data(args.root, args.progress), cfg, args.progress
        )
    report = dict(
        **run_record("bench_cross_condition.py", argv, env, load0), datasets=datasets
    )
    stem = "cross_condition_quick" if args.quick else "cross_condition"
    write_report(args.out, stem, report, markdown(report))
    draw(report, args.out / f"{stem}.png")


if __name__ == "__main__":
    main()
