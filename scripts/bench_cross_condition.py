"""Recognition under appearance change, on a split by place: maps, hybrids and
baselines fitted on one condition of the test places, queried with the other
(Nordland summer/winter, aerial A/B; docs/appearance.md).

    python scripts/bench_cross_condition.py --no-progress   # reports/cross_condition.*
    python scripts/bench_cross_condition.py --quick         # patchnorm, closed form
"""

import copy
import json
import math
import time
from dataclasses import asdict, replace
from functools import partial
from pathlib import Path

import _harness as h
import numpy as np

from rhythmic_jax.decoding.fusion import learn_weight
from rhythmic_jax.decoding.group_decode import place_scores as group_place_scores
from rhythmic_jax.eval.seqslam import seqslam_decode
from rhythmic_jax.eval.split import NORDLAND_SPLIT
from rhythmic_jax.fitting.learn import LearnConfig, learn_embedding
from rhythmic_jax.frames.cache_files import default_cache_dir
from rhythmic_jax.frames.features import describe, get_descriptor
from rhythmic_jax.map import embedding as emb_files
from rhythmic_jax.map.codes import fit_codebook
from rhythmic_jax.map.embedding import apply, embedding_bytes
from rhythmic_jax.map.periods import database_bytes
from rhythmic_jax.map.scalar_codes import scalar_code_bytes
from rhythmic_jax.rhythmic_map import RhythmicMap

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
    pred = np.asarray(pred)
    return float(np.mean(np.abs(pred - np.arange(len(pred))) <= tol))


def _recall(scores, k: int) -> float:
    scores = np.asarray(scores)
    gt, top = np.arange(len(scores)), np.argpartition(-scores, k, axis=1)[:, :k]
    return float(np.mean(np.any(np.abs(top - gt[:, None]) <= TOL, axis=1)))


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
    """A fitted map plus ``codes`` of its (embedded) reference frames: what
    ``RhythmicMap(..., codes=codes, fusion=fusion).fit`` stores, with no new solve."""
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
    """The largest pair (t, t + 1), t <= ``MAX_LEVEL`` ceil(sqrt n), whose k-dim map
    plus ``fixed`` and ``per_place`` bytes fits ``budget`` of the raw database."""
    room = budget * database_bytes(n, d_raw, 4) - fixed - n * per_place
    cap = MAX_LEVEL * (math.isqrt(n - 1) + 1)
    t = min(int((room / (4 * (k + 1)) - 1) // 2), cap, n - 1)
    return (t, t + 1) if t >= 2 and t * (t + 1) >= n else None


def budget_rows(ref, qry, label, emb, n, d_raw, train) -> list[dict]:
    """The map of the largest periods within 15 % and its hybrids with ITQ codes and
    with 8-bit codes (weight learned on ``train``), every byte counted."""
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


def options(ap) -> None:
    ap.add_argument("--only", help="comma-separated words of the data sets to run")


def run(args) -> dict:
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
    report["targets"] = targets(report)
    draw(report, args.out / f"{args.stem}.png")
    saved.unlink(missing_ok=True)
    return report


def refresh(report: dict, args) -> None:
    """Targets and figure again, for ``--render``."""
    report["targets"] = targets(report)
    draw(report, args.render.with_suffix(".png"))


COLS = ("r1", "r1_exact", "r5", "L5", "L10", "L20", "self_r1")
HEADS = ["method", "R@1", "exact", "R@5", "L=5", "L=10", "L=20", "self",
         "storage B", "embedding B", "ratio", "sizes", "fit s"]  # fmt: skip


def within(rows, key, budget=None, where=lambda r: "layout" in r) -> list[dict]:
    """The ``where`` rows (default: the map's) that have ``key``, within ``budget``."""
    return [r for r in rows if where(r) and key in r
            and (budget is None or r["ratio"] <= budget + 1e-12)]  # fmt: skip


def chosen(rows, key, budget=None) -> dict | None:
    """The configuration fixed before scoring (the 8-bit hybrid on the first lever)
    within ``budget``; else the best map row (older reports)."""
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


def targets(report: dict) -> list[tuple[str, str]]:
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


def _fmt(v):
    return round(v, 4) if isinstance(v, float) else v


def markdown(report: dict) -> str:
    lines = h.header("Recognition under appearance change (split by place)", report)
    wall = f"Wall time of the whole run: {report.get('wall_seconds', 0) / 60:.1f} min"
    if walls := report.get("wall_seconds_by_process"):
        wall = "Data sets run in parallel processes (the commands above, joined by "
        wall += "';'); wall time of each: "
        wall += ", ".join(f"{k} {v / 60:.1f} min" for k, v in walls.items())
    lines += [wall + ".", "",
              "Maps are fitted on one condition of the test places and queried with the"
              " other; every embedding was learned on the training places only"
              " (Nordland 0-1199, test 1220-3575; aerial: DSIFN pairs train, LEVIR"
              " pairs test). R@1 and R@5 within +-1 place; `exact` without tolerance; L"
              " = phase-domain sequence of the map's place scores, or SeqSLAM on the"
              " raw descriptor; `self` = reference frames as queries (exact). storage"
              " B: templates (with codes, the codes and their transform; brute force:"
              " the database in float32); embedding B: its parameters, stored once, not"
              " growing with N; ratio = both over the raw float32 database. `hybrid`:"
              " the map's place scores and the ITQ code similarities, each z-scored per"
              " query, summed (codes fitted on the embedded reference frames); `+ int8"
              " codes`: the same with a byte per dimension of the embedded frame, fused"
              " with the map's share w learned on the training places (the `chosen`"
              " configuration the targets judge, fixed before any test place was"
              " scored); `int8 codes alone`: those codes' own search, which shows what"
              " the templates add. Budget rows take the largest pair of periods (t, t +"
              " 1) that fits; their t/N says how far from sub-linear they are.",
              "", "## Targets", ""]  # fmt: skip
    lines += [f"- {t}: **{v}**" for t, v in targets(report)] + [""]
    for name, ds in report["datasets"].items():
        lines += [f"## {name} (N = {ds['n']}, d = {ds['d']}, level {ds['level']})", ""]
        learn = "; ".join(
            f"{k}: {v['seconds']:.1f} s learning, k = {v['config']['k']}, "
            f"{v['bytes']:,} B, kept step {v.get('kept_step', 0)} of "
            f"{v.get('steps', 0)}{' (read from the cache)' if v.get('cached') else ''}"
            for k, v in ds["learn"].items()
        )
        lines += [f"Embeddings: {learn}.", ""]
        for key, rows in ds["directions"].items():
            body = [[r["method"], *(_fmt(r.get(c, "")) for c in COLS),
                     r.get("storage_bytes", ""), r.get("embedding_bytes", 0),
                     _fmt(r["ratio"]), str(tuple(r.get("sizes", ()))),
                     _fmt(r.get("fit_seconds", ""))] for r in rows]  # fmt: skip
            lines += [f"### {key}", "", h.table(HEADS, body), ""]
    return "\n".join(lines)


def draw(report: dict, path: Path) -> None:
    """R@1 (+-1) and L = 10 of every row, one panel per data set (first direction)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sets = report["datasets"]
    fig, axes = plt.subplots(1, len(sets), figsize=(7 * len(sets), 6), squeeze=False)
    for ax, (name, ds) in zip(axes[0], sets.items(), strict=True):
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
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    h.main(__doc__, run, markdown, options, stem="cross_condition", refresh=refresh)
