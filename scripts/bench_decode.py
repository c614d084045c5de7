"""Decoding, by part: batch and single queries against exact search, the decoders
beyond the paper, and one descriptor to its place.

python scripts/bench_decode.py batch            # reports/decode.{json,md}
python scripts/bench_decode.py batch --quick    # 1 timed batch, 30 single queries
python scripts/bench_decode.py decoders         # reports/decoding.{json,md}
python scripts/bench_decode.py decoders --quick # 500 frames, patchnorm, level 1
python scripts/bench_decode.py single-query [--singles 2000] [--exact 200]
python scripts/bench_decode.py batch --render reports/decode.json  # Markdown again
"""

import functools
import itertools
import time
from pathlib import Path

import _harness as h
import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax import RhythmicMap
from rhythmic_jax.decoding.batch import decode_queries as decode
from rhythmic_jax.decoding.dispatch import decode_scores
from rhythmic_jax.decoding.host import SmallDecoder
from rhythmic_jax.decoding.sequence import SPEEDS, sequence_decode, sequence_scores
from rhythmic_jax.decoding.soft import calibrate
from rhythmic_jax.eval import metrics
from rhythmic_jax.eval import outliers as ol
from rhythmic_jax.eval import seqslam as sq
from rhythmic_jax.eval.baselines import BruteForce
from rhythmic_jax.frames.features import get_descriptor
from rhythmic_jax.map import periods as rp
from rhythmic_jax.map.groups import Groups
from rhythmic_jax.map.pytree import Map
from rhythmic_jax.solvers.objective import Templates

BATCH = 1000
LARGE = 20_000  # rows of the device-resident batch (fewer where d is large)
LARGE_BYTES = 2**28  # the large batch's float32 bytes at most
NOISE = 0.5  # query noise relative to a unit reference
QUICK_BATCH = dict(repeats=1, singles=30)  # --quick


def random_features(n: int, d: int, b: int, seed: int):
    """(references (n, d), queries (b, d), source index of each query (b,))."""
    rng = np.random.default_rng(seed)
    refs = h.unit_rows(rng.standard_normal((n, d), dtype=np.float32))
    src = rng.choice(n, size=b, replace=False)
    noise = rng.standard_normal((b, d), dtype=np.float32) * np.float32(NOISE)
    return refs, h.unit_rows(refs[src] + noise / np.sqrt(d, dtype=np.float32)), src


def random_map(d: int, periods: tuple[int, ...], seed: int) -> Templates:
    """Templates with random weights (d, p) and biases (p,)."""
    rng, p = np.random.default_rng(seed), sum(periods)
    w = rng.standard_normal((d, p), dtype=np.float32) / np.float32(np.sqrt(d))
    b = rng.standard_normal(p, dtype=np.float32) * np.float32(0.01)
    return Templates(jnp.asarray(w), jnp.asarray(b))


def bench_case(name, refs, queries, src, periods, repeats: int, singles: int) -> dict:
    """Throughput and latency of both decoders on the same features."""
    (n, d), p = refs.shape, sum(periods)
    h.log.info("%s: N=%d d=%d periods %s (p=%d)", name, n, d, periods, p)
    params = random_map(d, periods, seed=1)
    flat = BruteForce(n_threads=h.cores()).fit(refs)
    fns = dict(rhythmic=lambda q: decode(params, q, periods, n),
               faiss=lambda q: flat.search(q, 1))  # fmt: skip
    load, out = h.load_average(), {}
    for label, fn in fns.items():
        batch = metrics.time_batch(fn, queries, repeats=repeats)
        single = metrics.time_single_queries(fn, queries[:singles], warmup=10)
        out[label] = dict(batch=batch, single=single)
        h.log.info("  %s: %.0f queries/s, single median %.3f ms", label,
                   batch["queries_per_s"], 1e3 * single["median_s"])  # fmt: skip
    # device-resident batches, uploaded once outside the timing: the jitted
    # decode (in chunks of buckets.CHUNK rows above that size)
    rows = min(LARGE, LARGE_BYTES // (4 * d))
    big = np.resize(queries, (rows, d))
    for label, batch in (("rhythmic_device", queries), ("rhythmic_device_large", big)):
        dev = jax.device_put(batch)
        out[label] = dict(batch=metrics.time_batch(
            lambda _, dev=dev: decode(params, dev, periods, n), batch, repeats=repeats
        ))  # fmt: skip
        del dev
        h.log.info("  %s: %.0f queries/s (batch %d)", label,
                   out[label]["batch"]["queries_per_s"], len(batch))  # fmt: skip
    top = fns["faiss"](queries)[1]
    r, f = out["rhythmic"], out["faiss"]
    return dict(
        name=name, n=n, d=d, periods=list(periods), p=p, batch_size=len(queries),
        single_queries=singles, load_average_start=load,
        threads=dict(xla=h.cores(), faiss=flat.n_threads),
        map_bytes=rp.storage_bytes(periods, d), database_bytes=rp.database_bytes(n, d),
        flop_ratio=n / p, faiss_top1_is_source=float(np.mean(top[:, 0] == src)),
        rhythmic=r, faiss=f, rhythmic_device=out["rhythmic_device"],
        rhythmic_device_large=out["rhythmic_device_large"],
        batch_speedup=r["batch"]["queries_per_s"] / f["batch"]["queries_per_s"],
        single_speedup_median=f["single"]["median_s"] / r["single"]["median_s"],
        single_speedup_p95=f["single"]["p95_s"] / r["single"]["p95_s"],
    )  # fmt: skip


markdown_batch = h.markdown(
    "Decoding: rhythmic map against exact search (faiss IndexFlatIP)",
    "Random templates; both decoders see the same queries. A device batch is uploaded"
    " once, outside the timing.",
)


OPTIONS_BATCH = dict(repeats=(5, "timed batch calls"),
                     singles=(300, "timed single queries"))  # fmt: skip


def run_batch(args) -> dict:
    """Batch and single-query decoding against exact search (decode)."""
    kw = dict(repeats=args.repeats, singles=args.singles)
    refs, qry, src = random_features(10713, 4096, BATCH, seed=0)
    cases = [
        bench_case("random, Nordland spring size", refs, qry, src, (105, 106), **kw)
    ]
    del refs, qry
    periods = rp.nominal_periods(3576, 2, 1, 7)
    if (args.root / "nordland_64x32").is_dir():
        name = "Nordland summer map, winter queries, patchnorm"
        refs, qry = h.nordland_features(args.root, progress=args.progress)
        qry, src = qry[:BATCH], np.arange(BATCH)
    else:
        h.log.warning("no Nordland data under %s: random features", args.root)
        name = "random, Nordland 64x32 size"
        refs, qry, src = random_features(3576, 2048, BATCH, seed=0)
    cases.append(bench_case(name, refs, qry, src, periods, **kw))
    return dict(jax_backend=jax.default_backend(), cases=cases)


TOLERANCE = 1
LENGTHS = (5, 10, 20)
GRID_LENGTH = 10  # the length also run over the 5-speed grid
M = 3
EXCLUDE = 5  # rivals of a confidence margin lie more than this many places away
HOLDOUT = dict(fraction=0.2, block=50, seed=0)
CONTRAST_WINDOW = 10
CENTRE_WINDOW = 100  # query frames in a template's running mean
DESCRIPTORS = ("patchnorm", "efficientnet_lite0")
QUICK_DECODERS = dict(frames=500, levels=[1], descriptors=["patchnorm"])  # --quick
GRIDS = [(length, (1.0,)) for length in LENGTHS] + [(GRID_LENGTH, SPEEDS)]


def fitted_map(x: np.ndarray, level: int, descriptor: str, progress: bool):
    """``RhythmicMap(r=2, level=level).fit(x)``, cached on disk (minutes a fit)."""
    settings = get_descriptor(descriptor).settings()
    model = RhythmicMap(r=2, level=level, descriptor=descriptor,
                        descriptor_settings=settings)  # fmt: skip
    return h.cached_fit(model, x, progress=progress)[0]


def _row(method, out, gt, seconds, storage, **extra) -> dict:
    """``out``: a decode's indices, or a tuple that starts with them."""
    pred, inmap = np.asarray(out[0] if isinstance(out, tuple) else out), gt >= 0
    pred, gt_in = pred[inmap], gt[inmap]
    return dict(
        method=method, **extra, recall_at_1=metrics.accuracy(pred, gt_in, TOLERANCE),
        recall_at_1_exact=metrics.accuracy(pred, gt_in, 0),
        queries_per_s=len(pred) / max(seconds, 1e-12), storage_bytes=int(storage),
    )  # fmt: skip


def per_period(fn):
    """(T, p) -> (T, p): ``fn`` on each period's block of scores, jitted."""

    @functools.partial(jax.jit, static_argnames=("periods",))
    def apply(scores: jax.Array, periods: tuple[int, ...]) -> jax.Array:
        blocks = jnp.split(scores, np.cumsum(periods)[:-1].tolist(), axis=-1)
        return jnp.concatenate([fn(b) for b in blocks], axis=-1)

    return apply


def _standardise(b: jax.Array) -> jax.Array:
    """A period's scores to zero mean, unit std."""
    mu, sd = jnp.mean(b, axis=-1, keepdims=True), jnp.std(b, axis=-1, keepdims=True)
    return (b - mu) / jnp.maximum(sd, 1e-6)


def _spread(b: jax.Array) -> jax.Array:
    """Circular max over phases j-1, j, j+1 of a period."""
    rolled = jnp.maximum(jnp.roll(b, 1, axis=-1), jnp.roll(b, -1, axis=-1))
    return jnp.maximum(b, rolled)


@functools.partial(jax.jit, static_argnames=("periods", "window"))
def centre_templates(scores: jax.Array, periods=(), window=CENTRE_WINDOW) -> jax.Array:
    """Each template's score minus its causal mean over the last ``window`` frames."""
    zero = jnp.zeros((1, scores.shape[1]), scores.dtype)
    c = jnp.concatenate([zero, jnp.cumsum(scores, axis=0)])
    t = jnp.arange(1, scores.shape[0] + 1)
    lo = jnp.maximum(t - window, 0)
    return scores - (c[t] - c[lo]) / (t - lo).astype(scores.dtype)[:, None]


TRANSFORMS = {
    # log-softmax subtracts one constant per frame and period: the same for every
    # place, so the argmax (and the speed chosen) cannot change; shown as a check
    "calibrated": calibrate,
    "standardised": per_period(_standardise),
    "spread ±1": per_period(_spread),
    f"centred (last {CENTRE_WINDOW} frames)": centre_templates,
}


@functools.partial(jax.jit, static_argnums=(1, 2, 3, 4))
def place_sequence_decode(scores, periods, n, length, window) -> jax.Array:
    """SeqSLAM's recipe on the map's place scores at speed 1: index (T,)."""
    i, offsets = np.arange(n), rp.period_offsets(periods)
    cols = np.stack([o + i % t for o, t in zip(offsets, periods, strict=True)])
    sim = sq.enhance_contrast(jnp.sum(scores[:, cols], axis=1), window)  # (T, n)
    return jnp.argmax(sq.sequence_similarity(sim, length, 1.0), axis=1)


def map_rows(model: RhythmicMap, qry: np.ndarray, gt: np.ndarray, repeats: int):
    """Every decode of one map over the whole query sequence."""
    storage, per, n = model.storage_bytes, model.periods, model.n
    q = jnp.asarray(qry)
    s, score_s = h.fastest(lambda: model.scores(q), repeats)
    rows = []

    def add(label, fn, length=None, speeds=None):
        out, sec = h.fastest(fn, repeats)
        dq = len(gt) / max(sec, 1e-12)
        speeds = None if speeds is None else list(speeds)
        rows.append(_row(label, out, gt, score_s + sec, storage, L=length,
                         speeds=speeds, decode_queries_per_s=dq))  # fmt: skip

    for method in ("hard", "soft", "topm"):
        label = f"{method} (m={M})" if method == "topm" else method
        add(label, lambda method=method: decode_scores(s, per, n, method, M).index)
    for length, v in GRIDS:
        fn = lambda L=length, v=v: sequence_decode(s, per, n, L, v)  # noqa: E731
        add(f"sequence soft L={length} {_speeds(v)}", fn, length, v)
    for name, transform in TRANSFORMS.items():
        for length, v in GRIDS[1:]:
            if name == "calibrated" and len(v) > 1:
                continue
            fn = lambda length=length, v=v, t=transform: sequence_decode(  # noqa: E731
                t(s, per), per, n, length, v
            )
            add(f"sequence soft L={length} {_speeds(v)}, {name}", fn, length, v)
    w = CONTRAST_WINDOW
    for length in LENGTHS[1:]:
        fn = lambda L=length: place_sequence_decode(s, per, n, L, w)  # noqa: E731
        add(f"place-domain L={length} v=1, contrast w={w}", fn, length, [1.0])
    return rows


def _speeds(speeds) -> str:
    return "v=1" if tuple(speeds) == (1.0,) else f"{len(speeds)} speeds"


def reference_rows(ref: np.ndarray, qry: np.ndarray, gt: np.ndarray, repeats: int):
    """Single-frame brute force and SeqSLAM-style sequences on full descriptors."""
    storage, flat = ref.size * 4, BruteForce(n_threads=h.cores()).fit(ref)
    pred, sec = h.fastest(lambda: flat.search(qry, 1)[1][:, 0], repeats)
    rows = [_row("brute force", pred, gt, sec, storage)]
    for window in (None, CONTRAST_WINDOW):
        for length, speeds in GRIDS:
            label = f"SeqSLAM L={length} {_speeds(speeds)}"
            if window:
                label += f", contrast w={window}"
            fn = lambda L=length, v=speeds, w=window: sq.seqslam_decode(  # noqa: E731
                qry, ref, L, v, contrast_window=w, progress=False
            )
            out, sec = h.fastest(fn, max(1, repeats // 3))
            rows.append(_row(label, out, gt, sec, storage, L=length, speeds=[*speeds]))
    return rows


def _threshold_metrics(pred, conf, gt, first: np.ndarray) -> dict:
    """Threshold-free metrics on the second half, and a first-half threshold."""
    second = ~first
    p2, c2, g2 = pred[second], conf[second], gt[second]
    thr = ol.choose_threshold(pred[first], conf[first], gt[first], tolerance=TOLERANCE)
    kept = ol.reject(p2, c2, thr)
    ok = (kept >= 0) & (g2 >= 0) & (np.abs(kept - g2) <= TOLERANCE)
    return dict(
        pr_auc=metrics.pr_auc(p2, c2, g2, TOLERANCE),
        recall_at_100_precision=metrics.recall_at_100_precision(p2, c2, g2, TOLERANCE),
        threshold=thr,
        precision_at_threshold=float(ok.sum() / max((kept >= 0).sum(), 1)),
        recall_at_threshold=float(ok.sum() / (g2 >= 0).sum()),
        outliers_rejected=float((kept[g2 < 0] == -1).mean()),
        retrieved=int((kept >= 0).sum()),
    )


def outlier_rows(ref, qry, level: int, descriptor: str, progress: bool):
    """Hold 20 % of the route out of the map; query every winter frame."""
    hold = ol.holdout_split(len(ref), **HOLDOUT)
    gt, first = hold.gt(), np.arange(len(qry)) < len(qry) // 2
    kept = ref[hold.fit]
    model = fitted_map(kept, level, descriptor, progress)
    per, n = model.periods, model.n
    scores = model.scores(qry)
    label, centred = f"sequence soft L={GRID_LENGTH}", centre_templates(scores)
    seq = {label: sequence_scores(scores, per, GRID_LENGTH),
           f"{label}, centred": sequence_scores(centred, per, GRID_LENGTH)}  # fmt: skip
    cases = {}
    for kind in ("margin", "likelihood"):
        ex = EXCLUDE if kind == "margin" else 0
        cases[f"hard, {kind}"] = ol.decode_confidence(scores, per, n, "hard", kind=kind)
        for label, acc in {"soft": scores, **seq}.items():
            cases[f"{label}, {kind}"] = ol.decode_confidence(
                acc, per, n, "soft", kind=kind, exclude=ex
            )
    sim, top = BruteForce(n_threads=h.cores()).fit(kept).search(qry, 1)
    cases["brute force, cosine"] = (top[:, 0], ol.finite_confidence(sim[:, 0]))
    for w in (None, CONTRAST_WINDOW):
        idx, score = sq.seqslam_decode(qry, kept, GRID_LENGTH, contrast_window=w)
        label = f"SeqSLAM L={GRID_LENGTH}" + (f", contrast w={w}" if w else "")
        cases[label + ", score"] = (np.asarray(idx), ol.finite_confidence(score))
    rows = []
    for label, (pred, conf) in cases.items():
        pred = np.asarray(pred).astype(np.int64)
        rows.append(dict(method=label, **_threshold_metrics(pred, conf, gt, first)))
    return dict(descriptor=descriptor, level=level, periods=list(per), n_map=int(n),
                n_held=len(hold.held), n_queries=len(qry), rows=rows)  # fmt: skip


def decoding_targets(report: dict) -> list:
    """Nordland, level 4, L = 10 and 20: the plain and the best map decode against
    SeqSLAM: within 5 points, >= 10x its speed, <= 14 % of its storage."""
    rows = []
    for b in report["decoding"]:
        if b["dataset"] != "nordland" or b["level"] != 4:
            continue
        refs = {r["method"]: r for r in b["references"]}
        for length in (GRID_LENGTH, 20):
            ours = [r for r in b["rows"] if r.get("L") == length]
            plain = next(r for r in ours if r["method"].endswith(f"L={length} v=1"))
            best = max(ours, key=lambda r: r["recall_at_1"])
            for r, w in itertools.product({id(plain): plain, id(best): best}.values(),
                                          ("", f", contrast w={CONTRAST_WINDOW}")):
                ref = refs[f"SeqSLAM L={length} v=1{w}"]
                what = f"{b['descriptor']}, {r['method']} against SeqSLAM{w}:"
                gap = 100 * (r["recall_at_1"] - ref["recall_at_1"])
                speed = r["queries_per_s"] / ref["queries_per_s"]
                share = 100 * r["storage_bytes"] / ref["storage_bytes"]
                rows += [
                    h.target(f"{what} R@1 points", gap, -5, fmt="{:+.1f}"),
                    h.target(f"{what} speed", speed, 10, fmt="{:.1f}x"),
                    h.target(f"{what} storage %", share, 14, False, "{:.1f}"),
                ]
    return h.targets(rows)


markdown_decoders = h.markdown(
    "Decoders beyond the paper",
    f"Recall@1 within ±{TOLERANCE} (also exact); queries/s after a compiling call."
    " Outliers: frames held out of the map; PR AUC and recall at 100 % precision on"
    " the route's second half, the threshold chosen on its first.",
    decoding_targets,
)


def run_decoders(args) -> dict:
    """Decoders beyond the paper: soft, top-m, sequences, outliers (decoding)."""
    blocks, outliers = [], []
    repeats = 3 if args.quick else 5
    kw = dict(cache_dir=args.cache_dir, progress=args.progress)
    for name in args.descriptors:
        try:
            get_descriptor(name).settings()
        except Exception as err:  # noqa: BLE001 - weights missing, import failure
            h.log.warning("skipping descriptor %s: %s", name, err)
            continue
        datasets = {
            "nordland": h.nordland_features(args.root, name, **kw),
            "aerial LEVIR": h.aerial_features(args.root, name, **kw)[:2],
        }
        if args.frames:
            f = args.frames
            datasets = {k: (r[:f], q[:f]) for k, (r, q) in datasets.items()}
        for dataset, (ref, qry) in datasets.items():
            gt = np.arange(len(qry))
            h.log.info("%s %s: references", dataset, name)
            refs = reference_rows(ref, qry, gt, repeats)
            for level in args.levels:
                model = fitted_map(ref, level, name, args.progress)
                h.log.info("%s %s level %d, periods %s", dataset, name, level,
                           model.periods)  # fmt: skip
                blocks.append(dict(dataset=dataset, descriptor=name,
                                   settings=get_descriptor(name).settings(),
                                   level=level, n=int(model.n), d=int(model.d),
                                   n_queries=len(qry), periods=list(model.periods),
                                   compression_ratio=model.compression_ratio,
                                   database_bytes=int(ref.size * 4),
                                   rows=map_rows(model, qry, gt, repeats),
                                   references=refs))  # fmt: skip
        ref, qry = datasets["nordland"]
        for level in args.levels:
            h.log.info("outlier protocol, %s level %d", name, level)
            outliers.append(outlier_rows(ref, qry, level, name, args.progress))
    return dict(tolerance=TOLERANCE, lengths=list(LENGTHS), speeds_grid=list(SPEEDS),
                m=M, exclude=EXCLUDE, holdout=HOLDOUT, decoding=blocks,
                outliers=outliers)  # fmt: skip


OPTIONS_DECODERS = dict(cache_dir=(Path, "descriptor cache"),
                        descriptors=list(DESCRIPTORS), levels=[1, 4],
                        frames=(int, "first frames only"))  # fmt: skip


QUICK_SINGLE = dict(n=2000, singles=200, exact=20)  # --quick


def latencies(cases: dict, queries: np.ndarray, calls: dict, block: int = 100):
    """Median and p95 s of each case's calls on single queries, in turns."""
    for fn in cases.values():
        for q in queries[:50]:
            fn(q)
    ts, done = {name: [] for name in cases}, 0
    while any(len(ts[k]) < calls[k] for k in cases):
        for name, fn in cases.items():
            for q in queries[done : done + block][: calls[name] - len(ts[name])]:
                t = time.perf_counter()
                fn(q)
                ts[name].append(time.perf_counter() - t)
        done = (done + block) % len(queries)
    return {name: dict(median_s=float(np.median(v)), p95_s=float(np.percentile(v, 95)),
                       calls=len(v)) for name, v in ts.items()}  # fmt: skip


OPTIONS_SINGLE = dict(n=10_000, d=2048, singles=2000,
                      exact=(200, "single faiss queries"))  # fmt: skip


def run_single(args) -> dict:
    """One descriptor to its place: numpy lane, jitted decode, faiss (single_query)."""
    n, d = args.n, args.d
    cands = rp.candidate_periods(n, 2, 1, 7)
    periods = rp.choose_periods(cands, [0.0] * len(cands), n, 2)
    refs, queries, _ = random_features(n, d, args.singles, seed=0)
    params, p = random_map(d, periods, seed=1), sum(periods)
    model = RhythmicMap(r=2)
    groups = Groups("periods", periods)
    model.map = Map(*params, stored=dict(params._asdict()), config=model.config,
                    groups=groups, periods=periods, n=n, d=d)  # fmt: skip
    small = SmallDecoder.build(params, periods, n)
    batch_idx = np.asarray(decode(params, queries, periods, n).index)
    same = [small.place(q) for q in queries] == batch_idx.tolist()
    model.predict(queries[:1])  # builds the map's numpy lane
    same_locate = [model.locate(q) for q in queries] == batch_idx.tolist()
    wt, rows_p = small.wt, small.wt.shape[0]
    unpadded, alone = np.ascontiguousarray(wt[:p]), "templates x query alone, "
    cases = {
        alone + f"{p} rows (one-thread sgemv)": lambda q: unpadded @ q,
        alone + f"padded to {rows_p} rows (the map's)": lambda q: wt @ q,
        "RhythmicMap.locate (1 descriptor)": model.locate,
        "RhythmicMap.predict (1 row)": lambda q: model.predict(q[None]),
        "numpy index (SmallDecoder.place)": small.place,
    }
    rows = latencies(cases, queries, dict.fromkeys(cases, args.singles))

    def jit(q):  # timed after the numpy paths: XLA's threads spin on after a call
        return jax.block_until_ready(decode(params, q, periods, n).index)

    one = {"jitted decode (1 row)": lambda q: jit(q[None])}
    rows.update(latencies(one, queries, dict.fromkeys(one, args.singles)))
    flat = BruteForce(n_threads=h.cores()).fit(refs)  # last: its OpenMP threads spin on
    one = {"faiss IndexFlatIP (1 row)": lambda q: flat.search(q[None], 1)}
    rows.update(latencies(one, queries, dict.fromkeys(one, args.exact)))
    for name, row in rows.items():
        h.log.info("%s: %.1f us", name, 1e6 * row["median_s"])
    batch = queries[:1000]
    throughput = {
        "jitted decode": metrics.time_batch(jit, batch, repeats=5),
        "faiss IndexFlatIP": metrics.time_batch(lambda q: flat.search(q, 1), batch, 3),
    }
    return dict(n=n, d=d, periods=list(periods), singles=args.singles, single=rows,
                batch=throughput, same_as_batch_decode=bool(same),
                locate_same_as_batch_decode=bool(same_locate),
                padded_rows=int(rows_p))  # fmt: skip


def single_targets(r: dict) -> list:
    """One descriptor to its place <= 20 us (median); batches >= 40x faiss flat."""
    locate = next(v["median_s"] for k, v in r["single"].items() if "locate" in k)
    thr = [v["queries_per_s"] for v in r["batch"].values()]
    return h.targets([
        h.target("RhythmicMap.locate, median us", 1e6 * locate, 20, False, "{:.1f}"),
        h.target("batches: decode / faiss flat", thr[0] / thr[1], 40, fmt="{:.1f}x"),
    ])  # fmt: skip


markdown_single = h.markdown(
    "One query to one place",
    "Seconds per call on one descriptor, in turns; batches of 1000 queries. Each"
    " period's templates fill a block of equal rows so OpenBLAS shares the product.",
    single_targets,
)


PARTS = {
    "batch": h.Part(run_batch, markdown_batch, OPTIONS_BATCH, "decode", QUICK_BATCH),
    "decoders": h.Part(run_decoders, markdown_decoders, OPTIONS_DECODERS, "decoding",
                       QUICK_DECODERS),  # fmt: skip
    "single-query": h.Part(run_single, markdown_single, OPTIONS_SINGLE,
                           "single_query", QUICK_SINGLE),  # fmt: skip
}

if __name__ == "__main__":
    h.main(__doc__, PARTS)
