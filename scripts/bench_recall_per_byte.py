"""Recall per byte: maps, ITQ codes and map + code hybrids at equal storage.

python scripts/bench_recall_per_byte.py          # reports/recall_per_byte.*
python scripts/bench_recall_per_byte.py --quick  # 2 maps, 2 code sizes
"""

import dataclasses
import logging
import time
from pathlib import Path

import faiss
import jax
from _harness import fastest, header, main, nordland_features, table

from rhythmic_jax.decoding.fusion import fused_decode
from rhythmic_jax.decoding.soft import soft_decode
from rhythmic_jax.eval import frontier as fr
from rhythmic_jax.eval.split import NORDLAND_SPLIT
from rhythmic_jax.map.codes import code_bytes, pack_bits

BUDGETS = (0.03, 0.05, 0.08, 0.10, 0.15, 0.20, 0.25, 0.30)
NS = tuple(10**k for k in range(4, 10))
DS = (256, 2048, 4096, 10976)
BITS = (64, 128, 256, 512)
BUDGET = ["budget", "best", "map or hybrid", "ITQ", "own - ITQ"]
QUICK = dict(maps=((2, 1), (3, 2)), bits=(64, 128))  # --quick


def projections() -> list[dict]:
    """Map and code bytes for N = 1e4 .. 1e9, and the N where the map gets smaller."""
    return fr.projection_rows(DS, NS, BITS)


def timing(ref, q, cache, bits=64, r=2, level=4, gap=5e-4) -> dict:
    """Batch decode of every query: map alone, hybrid, codes alone (JAX) and
    faiss IndexBinaryFlat on the same codes; best of 5 after a compiling call."""
    w, b, per = fr.fitted_map(ref, r, level, gap, cache)
    book, n = fr.fitted_codes(ref, bits, cache), len(ref)
    wj, bj, qj = (jax.numpy.asarray(v) for v in (w, b, q))
    index = faiss.IndexBinaryFlat(bits)
    index.add(pack_bits(book.codes))
    codes = lambda: pack_bits(book.transform.encode(q))  # noqa: E731
    fns = {
        "map alone": lambda: soft_decode(qj @ wj + bj, per, n).index,
        "hybrid (map + codes, fused)": lambda: (
            fused_decode(qj @ wj + bj, book.similarity(qj), per, n).index
        ),
        "codes alone (JAX)": lambda: book.similarity(qj).argmax(1),
        "codes alone (faiss IndexBinaryFlat)": lambda: index.search(codes(), 1)[1],
    }
    secs = {name: fastest(fn, 5)[1] for name, fn in fns.items()}
    out = {k: {"seconds": s, "queries_per_s": len(q) / s} for k, s in secs.items()}
    for v in out.values():
        v["x map alone"] = v["seconds"] / out["map alone"]["seconds"]
    out["setting"] = f"map r={r} level {level} {per} + ITQ {bits}, {len(q)} queries"
    return out


def _span(until, since) -> str:
    """Where the map is smaller: "<= 3e4 and >= 1.2e8", ">= 1e8", "never"."""
    if until and until >= 10**12:
        return "every N"
    parts = [f"{op} {v:.2g}" for op, v in (("<=", until), (">=", since)) if v]
    return " and ".join(parts) or "never <= 1e12"


def _targets(rep: dict) -> list[str]:
    """The hybrid at <= 20 % against the targets, and own - ITQ per length."""
    hyb = [r for r in rep["rows"] if r["kind"] == "hybrid" and r["share"] <= 0.20]
    out = []
    for length, goal in ((1, 0.27), (10, 0.88)):
        key = f"recall@1 L={length}"
        if not hyb or key not in hyb[0]:
            continue
        best = max(hyb, key=lambda r: r[key])
        met = "met" if best[key] >= goal else "not met"
        out.append(
            f"- Hybrid at <= 20 %, L = {length}: best {best[key]:.3f} "
            f"({best['name']}, {100 * best['share']:.1f} %); target {goal}: {met}."
        )
    for length in rep["lengths"]:
        b = rep["budgets"][str(length)]
        none = [x for x in b if x["own"] is None]
        short = [x for x in b if x["own"] is not None and x["own_minus_itq"] < 0]
        line = f"- L = {length}: the map or a hybrid is at least ITQ's best at "
        line += f"{len(b) - len(none) - len(short)} of {len(b)} budgets"
        if none:
            at = ", ".join(f"{100 * x['budget']:g} %" for x in none)
            line += f"; none of them fits in {at}"
        if short:
            worst = min(short, key=lambda x: x["own_minus_itq"])
            at = ", ".join(
                f"{100 * x['budget']:g} % ({x['own_minus_itq']:+.3f})" for x in short
            )
            line += f"; behind at {at}, at most by {-worst['own_minus_itq']:.3f}"
        out.append(line + ".")
    return out


def markdown(rep: dict) -> str:
    lines = header("Recall per byte: map, ITQ codes and hybrids", rep)
    lines += [rep["protocol"], ""]
    lines += [
        f"Run time {rep['seconds']:.0f} s on the shared machine (fitted templates"
        " and code books are kept in the cache folder, so a re-run of settings"
        " already fitted only decodes).",
        "",
    ]
    lines += ["### Targets", ""] + _targets(rep) + [""]
    ls, heads = rep["lengths"], ["representation", "kind", "storage B", "share %"]
    heads += [f"R@1 L={k}" for k in ls] + ["sequence scorer", "weight"]
    keys = [f"recall@1 L={k}" for k in ls]
    rows = [[r["name"], r["kind"], r["storage_bytes"], 100 * r["share"],
             *("-" if r[k] is None else r[k] for k in keys),
             r.get("sequence_scorer") or "-", r.get("weight", "-")]
            for r in sorted(rep["rows"], key=lambda r: r["share"])]  # fmt: skip
    lines.append(table(heads, rows))
    for length in ls:
        key = f"recall@1 L={length}"
        body = [[f"{100 * b['budget']:g} %",
                 *(f"{x['name']} ({x[key]:.3f})" if x else "none fits"
                   for x in (b["best"], b["own"], b["itq"])),
                 round(b["own_minus_itq"], 3)]
                for b in rep["budgets"][str(length)]]  # fmt: skip
        lines += ["", f"### Budget by budget, L = {length}", "", table(BUDGET, body)]
    t = rep["timing"] or {"setting": "not measured in this run"}
    lines += ["", f"### Decode speed ({t['setting']}, every test query at once)", ""]
    body = [[k, v["seconds"], v["queries_per_s"], v["x map alone"]]
            for k, v in t.items() if k != "setting"]  # fmt: skip
    lines.append(table(["decode", "seconds", "queries/s", "time / map alone"], body))
    lines += ["", "### Projected bytes (level 1) and the N from which the map is "
              "smaller than each code", "",
              "Map: `sum(tau) (d + 1) 4` with the least-sum pairwise co-prime periods"
              " from `ceil(N^(1/r))` up; codes: `N ceil(bits/8) + (bits d + d) 4`.",
              ""]  # fmt: skip
    proj = rep["projections"]
    keys = [k for k in proj[0] if k.startswith("map")]
    body = [[p["d"], p["r"], *(f"{p[k]:.3g}" for k in keys),
             *(_span(p[f"until {b}"], p[f"since {b}"]) if b <= p["d"] else "bits > d"
               for b in BITS)] for p in proj]  # fmt: skip
    lines.append(table(["d", "r", *keys, *(f"map < ITQ {b}: N" for b in BITS)], body))
    lines += ["", "Codes at N = 1e4 .. 1e9 (bytes, d = 10,976): "]
    for b in BITS:
        sizes = ", ".join(f"{code_bytes(n, 10976, b)['total']:.3g}" for n in NS)
        lines.append(f"- ITQ {b}: {sizes}")
    return "\n".join(lines)


def _ints(text: str) -> tuple:
    """``64,128`` -> (64, 128); ``2:4,3:4`` -> ((2, 4), (3, 4))."""
    parts = [tuple(int(v) for v in part.split(":")) for part in text.split(",")]
    return tuple(p if len(p) > 1 else p[0] for p in parts)


def options(ap) -> None:
    cache = Path.home() / ".cache" / "rhythmic_jax" / "frontier"
    ap.add_argument("--cache", default=str(cache), help="fitted maps, codes ('': none)")
    ap.add_argument("--maps", type=_ints, help="maps as r:level,... (e.g. 2:4,3:4)")
    ap.add_argument("--bits", type=_ints, help="code sizes, e.g. 64,128")
    ap.add_argument("--no-timing", action="store_true", help="skip the speed table")


def run(args) -> dict:
    logging.getLogger("rhythmic_jax.eval.frontier").setLevel(logging.INFO)
    s, w = nordland_features(args.root, "efficientnet_lite0", key="nordland_",
                             progress=args.progress)  # fmt: skip
    tr, te = NORDLAND_SPLIT.train, NORDLAND_SPLIT.test
    given = {k: v for k in ("maps", "bits") if (v := getattr(args, k))}
    cfg, t0 = dataclasses.replace(fr.FrontierConfig(), **given), time.perf_counter()
    cache = args.cache or None
    rows = fr.frontier_rows(s[te], w[te], cfg, train=(s[tr], w[tr]), cache=cache)
    rep = {
        "protocol": (
            f"Nordland split: test places {int(te[0])}-{int(te[-1])} (N = {len(te)}),"
            f" summer references, winter queries, recall@1 within ±{cfg.tolerance};"
            f" training places {int(tr[0])}-{int(tr[-1])} for the fusion weights."
            f" Maps: squared-hinge RhythmicMap (gap {cfg.gap}), soft decode; int8"
            f" rows are the same templates stored as int8 with a float32 scale per"
            f" template (rhythmic_jax.map.quantize). Codes: ITQ fitted on the summer"
            f" references, its mean and projection counted. Fusion weights:"
            f" learned per map + code pair on the training places' single frames"
            f" and kept for sequences. Sequences at velocity 1, the scorer named"
            f" per row: maps accumulate their scores in the phase domain; codes"
            f" and brute force sum their per-frame z-scored similarities along"
            f" the diagonal; hybrids fuse the two; SeqSLAM on the raw descriptors."
            f" The ITQ fit runs on one thread (rhythmic_jax.map.codes.fit_codes)."
        ),
        "config": dataclasses.asdict(cfg),
        "lengths": list(cfg.lengths),
        "rows": rows,
        "budgets": {str(k): fr.budget_table(rows, BUDGETS, k) for k in cfg.lengths},
        "timing": {}
        if args.no_timing
        else timing(s[te], w[te], cache, cfg.bits[0], *cfg.maps[-1], cfg.gap),
        "projections": projections(),
        "seconds": time.perf_counter() - t0,
    }
    from rhythmic_jax.eval.figures import plot_frontier

    args.out.mkdir(parents=True, exist_ok=True)
    plot_frontier(rows, args.out / f"{args.stem}.png", cfg.lengths)
    return rep


if __name__ == "__main__":
    main(__doc__, run, markdown, options, stem="recall_per_byte", quick=QUICK)
