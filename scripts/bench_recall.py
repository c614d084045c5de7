"""Storage and recall, by part: recall per byte of maps, ITQ codes and map + code
hybrids at equal storage; recognition under appearance change on a split by place
(maps, hybrids and baselines fitted on one condition of the test places, queried
with the other: Nordland summer/winter, aerial A/B; docs/appearance.md); digits that
group frames that look alike (map layouts across seasons on Nordland).

python scripts/bench_recall.py per-byte          # reports/recall_per_byte.*
python scripts/bench_recall.py per-byte --quick  # 2 maps, 2 code sizes
python scripts/bench_recall.py cross-condition --no-progress  # cross_condition.*
python scripts/bench_recall.py cross-condition --quick        # patchnorm
python scripts/bench_recall.py digits            # reports/digits.{json,md}
"""

import copy
import dataclasses
import itertools
import json
import logging
import math
import time
from dataclasses import asdict, replace
from functools import partial
from pathlib import Path

import _harness as h
import faiss
import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax import database_bytes, storage_bytes
from rhythmic_jax.decoding.dispatch import decode_scores
from rhythmic_jax.decoding.fusion import fused_decode, learn_weight
from rhythmic_jax.decoding.group_decode import place_scores as group_place_scores
from rhythmic_jax.decoding.sequence import sequence_decode
from rhythmic_jax.decoding.soft import calibrate, soft_decode
from rhythmic_jax.eval import frontier as fr
from rhythmic_jax.eval.metrics import accuracy, recall_at_k
from rhythmic_jax.eval.report import ranked_places
from rhythmic_jax.eval.seqslam import seqslam_decode
from rhythmic_jax.eval.split import NORDLAND_SPLIT
from rhythmic_jax.fitting.learn import LearnConfig, learn_embedding
from rhythmic_jax.frames.cache_files import default_cache_dir
from rhythmic_jax.frames.features import describe, get_descriptor
from rhythmic_jax.map import embedding as emb_files
from rhythmic_jax.map.codes import fit_codebook, pack_bits
from rhythmic_jax.map.embedding import apply, embedding_bytes
from rhythmic_jax.map.groups import Groups, parse_layout, resolve_layout
from rhythmic_jax.map.periods import candidate_periods, choose_periods
from rhythmic_jax.map.scalar_codes import scalar_code_bytes
from rhythmic_jax.rhythmic_map import RhythmicMap
from rhythmic_jax.solvers.newton import NewtonConfig, newton_fit
from rhythmic_jax.solvers.objective import default_c, period_errors, scores, targets

RPB_BUDGETS = (0.03, 0.05, 0.08, 0.10, 0.15, 0.20, 0.25, 0.30)
NS = tuple(10**k for k in range(4, 10))
DS = (256, 2048, 4096, 10976)
BITS = (64, 128, 256, 512)

QUICK_BYTES = dict(maps=((2, 1), (3, 2)), bits=(64, 128))  # --quick


def timing(ref, q, cache, bits=64, r=2, level=4, gap=5e-4) -> dict:
    """Batch decode: map, hybrid, codes (JAX and faiss), best of 5."""
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
    secs = {name: h.fastest(fn, 5)[1] for name, fn in fns.items()}
    out = {k: {"seconds": s, "queries_per_s": len(q) / s} for k, s in secs.items()}
    for v in out.values():
        v["x map alone"] = v["seconds"] / out["map alone"]["seconds"]
    out["setting"] = f"map r={r} level {level} {per} + ITQ {bits}, {len(q)} queries"
    return out


def hybrid_targets(rep: dict) -> list:
    """The best hybrid within 20 %: R@1 >= 0.27 single frame, >= 0.88 at L = 10."""
    hyb = [r for r in rep["rows"] if r["kind"] == "hybrid" and r["share"] <= 0.20]
    rows = []
    for length, goal in ((1, 0.27), (10, 0.88)):
        key = f"recall@1 L={length}"
        if hyb and key in hyb[0]:
            best = max(hyb, key=lambda r: r[key])
            what = f"hybrid <= 20 %, L = {length}: {best['name']}"
            rows.append(h.target(what, best[key], goal, fmt="{:.3f}"))
    return h.targets(rows)


markdown_bytes = h.markdown(
    "Recall per byte: map, ITQ codes and hybrids",
    "Fitted maps and code books are cached. budgets: the best representation, map or"
    " hybrid and code per storage budget; projections: bytes at level 1 against N.",
    hybrid_targets,
)


def _ints(text: str) -> tuple:
    """``64,128`` -> (64, 128); ``2:4,3:4`` -> ((2, 4), (3, 4))."""
    parts = [tuple(int(v) for v in part.split(":")) for part in text.split(",")]
    return tuple(p if len(p) > 1 else p[0] for p in parts)


OPTIONS_BYTES = dict(
    cache=(str(Path.home() / ".cache" / "rhythmic_jax" / "frontier"),
           "fitted maps, codes ('': none)"),
    maps=(_ints, "maps as r:level,... (e.g. 2:4,3:4)"),
    bits=(_ints, "code sizes, e.g. 64,128"),
    no_timing=(False, "skip the speed table"),
)  # fmt: skip


def run_bytes(args) -> dict:
    """Recall per byte: maps, ITQ codes, hybrids (recall_per_byte)."""
    logging.getLogger("rhythmic_jax.eval.frontier").setLevel(logging.INFO)
    s, w = h.nordland_features(args.root, "efficientnet_lite0", key="nordland_",
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
        "budgets": {str(k): fr.budget_table(rows, RPB_BUDGETS, k) for k in cfg.lengths},
        "timing": {}
        if args.no_timing
        else timing(s[te], w[te], cache, cfg.bits[0], *cfg.maps[-1], cfg.gap),
        "projections": fr.projection_rows(DS, NS, BITS),
        "seconds": time.perf_counter() - t0,
    }
    from rhythmic_jax.eval.figures import plot_frontier

    args.out.mkdir(parents=True, exist_ok=True)
    plot_frontier(rows, args.out / f"{args.stem}.png", cfg.lengths)
    return rep


TOL = 1
LENGTHS = (5, 10, 20)
BUDGETS = (0.15, 0.20)
GAP = 1e-3  # the solver's relative gap: the templates' ranking is settled well before
COUNT = 3  # candidate periods per group (the paper: 7); a third of the solve
MAX_LEVEL = 4  # budget maps: periods at most 4 ceil(sqrt N) (longer: minutes a map)
LITE = "Nordland EfficientNet-Lite0"
PATCH = "Nordland patchnorm"
AERIAL = "Aerial pairs patchnorm"


def _acc(pred, tol=TOL) -> float:
    return accuracy(np.asarray(pred), np.arange(len(pred)), tol)


def _recall(scores, k: int) -> float:
    top = np.argpartition(-np.asarray(scores), k, axis=1)[:, :k]
    return recall_at_k(top, np.arange(len(top)), (k,), tolerance=TOL)[k]


def nordland_data(root: Path, progress: bool, name="patchnorm", images=True):
    desc = get_descriptor(name)
    s, w = h.nordland_features(root, desc, key="nordland_", progress=progress)
    tr, te = NORDLAND_SPLIT.train, NORDLAND_SPLIT.test
    out = dict(train=[s[tr], w[tr]], test=[s[te], w[te]], names=("summer", "winter"))
    if images:
        trav = h.nordland_images(root)
        out.update(images=[trav[0].images[te], trav[1].images[te]], descriptor=desc)
    return out


def aerial_data(root: Path, progress: bool):
    desc = get_descriptor("patchnorm")
    out = dict(names=("A", "B"), descriptor=desc)
    for part, folder in (("train", "samples_DSIFN"), ("test", "samples_LEVIR")):
        key = f"{folder}-64-32-"
        a, b, route = h.aerial_features(root, desc, folder, key, progress)
        out[part] = [a, b]
        if part == "test":
            out["images"] = [route.map_tiles, route.query_tiles]
    return out


def cached_embedding(dataset: str, train, cfg: LearnConfig):
    """Learn (or read back) the embedding of ``cfg`` on ``train`` -> (emb, info)."""
    ident = json.dumps([dataset, asdict(cfg), [list(t.shape) for t in train]])
    key = h.digest(ident, *(t[:: max(1, len(t) // 64)] for t in train))
    folder = default_cache_dir() / "cross_condition" / f"{key}.emb"
    if folder.exists():
        emb, meta = emb_files.load_embedding(folder)
        return emb, {**meta["learn_info"], "cached": True}
    emb, info = learn_embedding(train, cfg)
    folder.parent.mkdir(parents=True, exist_ok=True)
    emb_files.save_embedding(folder, emb, {"descriptor": dataset, "learn_info": info})
    return emb, {**info, "cached": False}


def brute_row(ref, qry, label, emb_bytes=0) -> dict:
    t0 = time.perf_counter()
    r, q = h.unit_rows(ref), h.unit_rows(qry)
    sim = q @ r.T
    pred = sim.argmax(1)
    return dict(method=label, r1=_acc(pred), r1_exact=_acc(pred, 0), r5=_recall(sim, 5),
                storage_bytes=int(r.size * 4), embedding_bytes=int(emb_bytes),
                seconds=time.perf_counter() - t0)  # fmt: skip


def seqslam_row(ref, qry) -> dict:
    t0 = time.perf_counter()
    row = dict(method="SeqSLAM raw", storage_bytes=int(np.asarray(ref).size * 4))
    row |= {f"L{L}": _acc(seqslam_decode(qry, ref, L)[0]) for L in LENGTHS}
    return row | dict(seconds=time.perf_counter() - t0)


def fit_map(ref, *, labels=None, emb=None, **kw) -> tuple[RhythmicMap, float]:
    """``RhythmicMap(r=2, **kw)`` fitted on ref (with ``emb``) -> (map, seconds)."""
    m = RhythmicMap(r=2, gap=GAP, count=COUNT, embedding=emb, **kw)
    return m, h.timed(m.fit, ref, labels, progress=False)[1]


def with_codes(m: RhythmicMap, ref, codes, fusion: float = 0.5) -> RhythmicMap:
    """A fitted map plus ``codes`` of its reference frames, with no new solve."""
    hy = copy.copy(m)
    hy.config = replace(m.config, codes=codes, fusion=fusion)
    x = ref if m.embedding is None else apply(m.embedding, ref)
    hy.codebook = fit_codebook(x, codes)
    return hy


def train_weight(train, emb, pair, codes, n: int) -> tuple[float, dict]:
    """The fusion weight of best recall@1 on the *training* places' two conditions."""
    ref, qry = train
    t = max(2, round(pair[0] * len(ref) / n))  # as many places a phase as on test
    m, _ = fit_map(ref, emb=emb, layout=f"periods:{t},{t + 1}")
    hy = with_codes(m, ref, codes)
    sims = hy.codebook.similarity(apply(emb, qry) if emb is not None else qry)
    return learn_weight(m.scores(qry), sims, m.periods, m.n, np.arange(len(qry)), TOL)


def eval_row(m: RhythmicMap, ref, qry, label: str, fit_s: float) -> dict:
    """Recall of a fitted map's soft decode, sequences, self-query and bytes."""
    t0 = time.perf_counter()
    if m.groups.kind == "periods":
        place = m.place_scores(qry)
    else:
        place = group_place_scores(m.scores(qry), m.groups, m.n)
    pred = m.predict(qry, "soft")
    row = dict(method=label, layout=m.groups.describe(), sizes=list(m.groups.sizes),
               codes_bits=m.codebook.bits if m.codebook else None, r1=_acc(pred),
               r1_exact=_acc(pred, 0), r5=_recall(place, 5),
               self_r1=_acc(m.predict(ref[: m.n], "soft"), 0),
               storage_bytes=m.storage_bytes, embedding_bytes=m.embedding_bytes,
               fit_seconds=fit_s)  # fmt: skip
    row |= {f"L{L}": _acc(m.predict(qry, "soft", sequence=L)) for L in LENGTHS}
    return row | dict(seconds=fit_s + time.perf_counter() - t0)


def map_row(ref, qry, label, *, labels=None, emb=None, **kw) -> dict:
    """Fit ``RhythmicMap(r=2, **kw)`` on ref (with ``emb``), query with qry."""
    m, fit_s = fit_map(ref, labels=labels, emb=emb, **kw)
    return eval_row(m, ref, qry, label, fit_s)


def budget_periods(n, d_raw, k, budget, fixed=0, per_place=0):
    """The largest periods (t, t + 1) whose map and codes fit ``budget``."""
    room = budget * database_bytes(n, d_raw, 4) - fixed - n * per_place
    cap = MAX_LEVEL * (math.isqrt(n - 1) + 1)
    t = min(int((room / (4 * (k + 1)) - 1) // 2), cap, n - 1)
    return (t, t + 1) if t >= 2 and t * (t + 1) >= n else None


def budget_rows(ref, qry, label, emb, n, d_raw, train) -> list[dict]:
    """The largest map within 15 % and its hybrids with ITQ and 8-bit codes."""
    k, eb = emb.k, embedding_bytes(emb)
    bits = min(k, 256)
    code = eb + (bits * k + k) * 4
    pair = budget_periods(n, d_raw, k, BUDGETS[0], code, math.ceil(bits / 8))
    if pair is None:
        return []
    m, fit_s = fit_map(ref, emb=emb, layout=f"periods:{pair[0]},{pair[1]}")
    rows = [eval_row(m, ref, qry, f"map {label}, periods near {pair[0]}", fit_s)]
    hy = with_codes(m, ref, bits)
    share = (hy.storage_bytes + eb) / database_bytes(n, d_raw, 4)
    fits = [b for b in BUDGETS if share <= b]
    where = f"<= {100 * fits[0]:.0f} %" if fits else f"{100 * share:.1f} %"
    rows.append(eval_row(hy, ref, qry, f"hybrid {label} + {bits} bits ({where})",
                         fit_s))  # fmt: skip
    sq = scalar_code_bytes(n, k)
    pair8 = budget_periods(n, d_raw, k, BUDGETS[0], eb + sq["fixed"], k)
    if pair8 is None:
        return rows
    if pair8 != pair:
        m, fit_s = fit_map(ref, emb=emb, layout=f"periods:{pair8[0]},{pair8[1]}")
    (w, table), learn_s, _ = h.timed(train_weight, train, emb, pair8, "int8", n)
    h8 = with_codes(m, ref, "int8", w)
    row = eval_row(h8, ref, qry, f"hybrid {label} + int8 codes (w = {w:g} "
                   "learned on the training places)", fit_s)  # fmt: skip
    row.update(chosen=True, fusion=w, fusion_table=table, fusion_seconds=learn_s)
    rows.append(row)
    codes_only = copy.copy(h8)  # the same codes, none of the map's score
    codes_only.config = replace(h8.config, fusion=0.0)
    alone = eval_row(codes_only, ref, qry, f"int8 codes alone {label}", fit_s)
    for key in ("layout", "sizes", "fit_seconds"):
        alone.pop(key)  # not a map: the codes' own search
    alone["storage_bytes"] = sq["total"]
    rows.append(alone)
    return rows


def augmented_row(ref, images, desc, qry, level, seed=0) -> dict:
    """The map fitted on the reference frames and an augmented copy of each."""
    import torch

    from rhythmic_jax.augment import kornia_ops as ko

    t0 = time.perf_counter()
    torch.manual_seed(seed)
    cfg = ko.AugmentConfig()
    aug = [ko.to_images(ko.augment(ko.to_batch(images[i : i + 256]), cfg, seed + i)[0])
           for i in range(0, len(images), 256)]  # fmt: skip
    x = np.concatenate([ref, describe(np.concatenate(aug), desc)])
    labels = np.concatenate([np.arange(len(ref))] * 2)
    row = map_row(x, qry, "map raw + augmentation (all seven, 2 exemplars)",
                  labels=labels, level=level)  # fmt: skip
    row["seconds"] = time.perf_counter() - t0
    return row


def run_dataset(name: str, data: dict, cfg: dict) -> dict:
    train, test = data["train"], data["test"]
    n, d_raw = test[0].shape
    embeddings, learn_info = {}, {}
    for label, lc in cfg["levers"].items():
        (emb, info), wall, _ = h.timed(cached_embedding, name, train, lc)
        info.update(wall_seconds_this_run=wall, bytes=embedding_bytes(emb))
        embeddings[label], learn_info[label] = emb, info
        h.log.info("%s: %s ready in %.1f s", name, label, info["wall_seconds_this_run"])
    directions, first = {}, next(iter(embeddings))
    for a, b in ((0, 1), (1, 0)):
        key = f"{data['names'][a]}->{data['names'][b]}"
        ref, qry = np.asarray(test[a]), np.asarray(test[b])
        rows = [brute_row(ref, qry, "brute force raw"), seqslam_row(ref, qry)]
        rows.append(map_row(ref, qry, "map raw", level=cfg["level"]))
        if "images" in data and a == 0:
            args = ref, data["images"][a], data["descriptor"], qry, cfg["level"]
            rows.append(augmented_row(*args))
        for i, (label, emb) in enumerate(embeddings.items()):
            er, eq = apply(emb, ref), apply(emb, qry)
            rows.append(brute_row(er, eq, f"brute force {label}", embedding_bytes(emb)))
            if label not in cfg.get("map_levers", (first,)):
                continue  # the gradient-trained heads: reference rows, brute force
            rows.append(map_row(ref, qry, f"map {label}", emb=emb,
                                level=cfg["level"]))  # fmt: skip
            train_pair = (np.asarray(train[a]), np.asarray(train[b]))
            rows += budget_rows(ref, qry, label, emb, n, d_raw, train_pair)
            if a == 0 and i == 0:  # digits on the first embedding
                for kind in ("mixed", "hierarchical"):
                    rows.append(map_row(ref, qry, f"{kind} digits {label}", emb=emb,
                                        layout=kind, level=cfg["level"]))  # fmt: skip
            h.log.info("%s %s %s done", name, key, label)
        db = database_bytes(n, d_raw, 4)
        for r in rows:
            r["ratio"] = (r["storage_bytes"] + r.get("embedding_bytes", 0)) / db
        directions[key] = rows
    return dict(n=n, d=d_raw, level=cfg["level"], learn=learn_info,
                directions=directions)  # fmt: skip


def plan(quick: bool) -> list[tuple[str, object, dict]]:
    """(title, data loader, settings) of every data set."""
    steps = dict(k=256, p=512, steps=60, eval_every=20)
    lite = dict(levers={"invariant": LearnConfig(method="invariant", k=256, p=512),
                        "through the map": LearnConfig(method="map", **steps),
                        "InfoNCE": LearnConfig(method="infonce", **steps)},
                level=1)  # fmt: skip
    patch = dict(levers={"invariant": LearnConfig(method="invariant", k=128, p=256)},
                 level=1)  # fmt: skip
    # 769 places: k = 128 alone would be 17 % of the raw database
    aerial = dict(levers={"invariant": LearnConfig(method="invariant", k=64, p=256),
                          "PCA": LearnConfig(method="pca", k=64)},
                  map_levers=("invariant", "PCA"), level=1)  # fmt: skip
    if quick:
        return [(PATCH, partial(nordland_data, images=False), patch)]
    return [(LITE, partial(nordland_data, name="efficientnet_lite0"), lite),
            (AERIAL, aerial_data, aerial), (PATCH, nordland_data, patch)]  # fmt: skip


OPTIONS_CROSS = dict(only=(str, "comma-separated words of the data sets to run"))


def run_cross(args) -> dict:
    """Recognition under appearance change, split by place (cross_condition)."""
    t0 = time.perf_counter()
    datasets, words = {}, args.only.split(",") if args.only else None
    saved = args.out / f"{args.stem}.partial.json"
    for title, load, settings in plan(args.quick):
        if words and not any(w in title for w in words):
            continue
        datasets[title] = run_dataset(title, load(args.root, args.progress), settings)
        datasets[title]["seconds"] = time.perf_counter() - t0
        h.log.info("%s done at %.0f s", title, time.perf_counter() - t0)
        # after every data set: a run cut short still leaves the ones it finished
        args.out.mkdir(parents=True, exist_ok=True)
        saved.write_text(json.dumps(dict(datasets=datasets), default=float))
    report = dict(datasets=datasets, wall_seconds=time.perf_counter() - t0)
    report["targets"] = cross_targets(report)
    draw(report, args.out / f"{args.stem}.png")
    saved.unlink(missing_ok=True)
    return report


def refresh(report: dict, args) -> None:
    """Targets and figure again, for ``--render``."""
    report["targets"] = cross_targets(report)
    draw(report, args.render.with_suffix(".png"))


def within(rows, key, budget=None, where=lambda r: "layout" in r) -> list[dict]:
    """The ``where`` rows (default: the map's) that have ``key``, within ``budget``."""
    return [r for r in rows if where(r) and key in r
            and (budget is None or r["ratio"] <= budget + 1e-12)]  # fmt: skip


def chosen(rows, key, budget=None) -> dict | None:
    """The row chosen before scoring within ``budget``; else the best map row."""
    picks = within(rows, key, budget, lambda r: r.get("chosen"))
    best = max(within(rows, key, budget), key=lambda r: r[key], default=None)
    return picks[0] if picks else best


def _row(rows, name) -> dict | None:
    return next((r for r in rows if r["method"] == name), None)


def _check(row, key, goal, share=True) -> str:
    """The verdict of ``row[key]`` against ``goal``, naming the row (and its share)."""
    if row is None:
        return "no map row fits 15 %"
    v, tail = row[key], f", {100 * row['ratio']:.1f} %" if share else ""
    word = "met" if v >= goal else "NOT met"
    return f"{word} ({v:.3f} vs {goal:.3f}, {v - goal:+.3f}): {row['method']}{tail}"


def cross_targets(report: dict) -> list[tuple[str, str]]:
    """(target, verdict with figures) of every target the report can judge."""
    sets, out = report["datasets"], []
    if LITE in sets:
        rows = next(iter(sets[LITE]["directions"].values()))
        brute, seq = _row(rows, "brute force raw"), _row(rows, "SeqSLAM raw")
        lever, slow = max(sets[LITE]["learn"].items(), key=lambda kv: kv[1]["seconds"])
        out += [
            ("Lite0, summer map, winter queries: map R@1 >= raw brute force at "
             "<= 15 % of the raw database, embedding included",
             _check(chosen(rows, "r1", 0.15), "r1", brute["r1"])),
            ("Lite0: the map's L = 10 sequence >= SeqSLAM L = 10 on raw Lite0",
             _check(chosen(rows, "L10", 0.15), "L10", seq["L10"])),
            ("Learning from cached descriptors <= 5 minutes on 2 cores",
             f"{'met' if slow['seconds'] <= 300 else 'NOT met'} (slowest Lite0 "
             f"lever, {lever}: {slow['seconds']:.0f} s, under the load below)"),
        ]  # fmt: skip
    for name, what in ((PATCH, "patchnorm: map single frame"),
                       (AERIAL, "Aerial pairs: the map")):  # fmt: skip
        if name in sets:
            rows = next(iter(sets[name]["directions"].values()))
            b, half = chosen(rows, "r1"), _row(rows, "brute force raw")["r1"] / 2
            out.append((f"{what} >= half of raw brute force", _check(b, "r1", half)))
            out += [(f"{what} >= half of raw brute force, with a later lever (not the "
                     "data set's first: chosen after an earlier run, so not blind)",
                     _check(r, "r1", half))
                    for r in rows if r.get("chosen") and r is not b]  # fmt: skip
    for name, ds in sets.items():
        for key, rows in ds["directions"].items():
            raw = _row(rows, "map raw")
            emb = next((r for r in rows if r["method"].startswith("map ")
                        and r["method"] != "map raw" and "self_r1" in r
                        and "+" not in r["method"]), None)  # fmt: skip
            pick = next((r for r in rows if r.get("chosen")), None)
            for row, what in (
                (emb, f"with the embedding no lower than without ({name}, {key}, "
                 "same level)"),
                (pick, "of the chosen configuration no lower than the map without "
                 f"embedding ({name}, {key})"),
            ):  # fmt: skip
                if raw and row:
                    verdict = _check(row, "self_r1", raw["self_r1"], False)
                    out.append((f"Self-query {what}", verdict))
    return out


markdown_cross = h.markdown(
    "Recognition under appearance change (split by place)",
    "Maps on one condition of the test places, queried with the other; embeddings"
    " learned on the training places only. r1, r5: within +-1 place; L5-L20: sequences;"
    " self_r1: reference frames as queries; ratio: bytes over the raw database; chosen:"
    " the int8 hybrid the targets judge (weight learned on the training places).",
)


def draw(report: dict, path: Path) -> None:
    """R@1 (+-1) and L = 10 of every row, one panel per data set (first direction)."""
    from rhythmic_jax.eval.figures import new_figure, save_figure

    sets = report["datasets"]
    fig, axes = new_figure(len(sets), 7, 6)
    for ax, (name, ds) in zip(axes, sets.items(), strict=True):
        key, rows = next(iter(ds["directions"].items()))
        y = list(range(len(rows)))
        ax.barh([v - 0.2 for v in y], [r.get("r1", 0) for r in rows], 0.4,
                label="R@1 single frame")  # fmt: skip
        ax.barh([v + 0.2 for v in y], [r.get("L10", 0) for r in rows], 0.4,
                label="L = 10")  # fmt: skip
        ax.set_yticks(y, [f"{r['method']} ({100 * r['ratio']:.1f} %)" for r in rows])
        ax.invert_yaxis()
        ax.set_xlim(0, 1)
        ax.set_title(f"{name}, {key}", fontsize=9)
        ax.tick_params(labelsize=7)
    axes[0].legend(fontsize=7)
    save_figure(fig, path, 110)


QUICK_DIGITS = dict(levels="1")  # --quick


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


markdown_digits = h.markdown(
    "Digits that group frames that look alike (Nordland)",
    "Summer map, winter queries; one joint solve of every layout. calibrated: after a"
    " log-softmax per group; label_accuracy: per group, beside label_chance.",
)


OPTIONS_DIGITS = dict(cache=Path("/work/cache"), descriptor="efficientnet_lite0",
                      levels=("1,2,4", "storage levels (1,2,4)"))  # fmt: skip


def run_digits(args) -> dict:
    """Map layouts (digits) across seasons on Nordland (digits)."""
    test = NORDLAND_SPLIT.test
    path = str(args.cache / f"nordland_%s_{args.descriptor}.npy")  # per season
    summer, winter = (np.ascontiguousarray(np.load(path % s, mmap_mode="r")[test])
                      for s in ("summer", "winter"))  # fmt: skip
    n, d = summer.shape
    gt, maps = np.arange(n), layouts(n, [int(v) for v in args.levels.split(",")])
    y = jnp.concatenate([targets(gt, g) for _, _, g in maps], axis=1)
    h.log.info("fitting %d templates on %d x %d", y.shape[1], n, d)
    fit = summer, y, default_c(n), NewtonConfig()
    (params, _), fit_wall, _ = h.timed(newton_fit, *fit, progress=args.progress)
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
        h.log.info("%s", row)
        rows.append(row)
    bf = brute(summer, winter, gt)
    bf.update(layout="brute force", sizes="-", ratio=1.0,
              storage_bytes=database_bytes(n, d))  # fmt: skip
    rows.append(bf)
    return dict(descriptor=args.descriptor, places=f"{int(test[0])}-{int(test[-1])}",
                n=n, d=d, templates_total=int(y.shape[1]), fit_wall_s=fit_wall,
                tolerance=TOL, rows=rows)  # fmt: skip


PARTS = {
    "per-byte": h.Part(run_bytes, markdown_bytes, OPTIONS_BYTES, "recall_per_byte",
                       QUICK_BYTES),  # fmt: skip
    "cross-condition": h.Part(run_cross, markdown_cross, OPTIONS_CROSS,
                              "cross_condition", refresh=refresh),  # fmt: skip
    "digits": h.Part(run_digits, markdown_digits, OPTIONS_DIGITS, "digits",
                     QUICK_DIGITS),  # fmt: skip
}

if __name__ == "__main__":
    h.main(__doc__, PARTS)
