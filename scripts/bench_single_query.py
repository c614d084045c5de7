"""One descriptor -> place: the map's numpy lane against the jitted decode and faiss.

python scripts/bench_single_query.py [--singles 2000] [--exact 200]
"""

import time

import jax
import numpy as np
from _harness import cores, header, log, main, table
from bench_decode import random_features, random_map

from rhythmic_jax import RhythmicMap
from rhythmic_jax.decoding.host import SmallDecoder
from rhythmic_jax.decoding.queries import decode_queries as decode
from rhythmic_jax.eval.baselines import BruteForce
from rhythmic_jax.eval.metrics import time_batch
from rhythmic_jax.map.groups import Groups
from rhythmic_jax.map.periods import candidate_periods, choose_periods
from rhythmic_jax.map.pytree import Map

QUICK = dict(n=2000, singles=200, exact=20)  # --quick


def latencies(cases: dict, queries: np.ndarray, calls: dict, block: int = 100):
    """Median and p95 seconds of ``calls[name]`` calls ``fn(q)`` of each case on
    rows of ``queries`` (after 50 of warm-up), in turns of ``block`` calls."""
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


def options(ap) -> None:
    ap.add_argument("--n", type=int, default=10_000)
    ap.add_argument("--d", type=int, default=2048)
    ap.add_argument("--singles", type=int, default=2000)
    ap.add_argument("--exact", type=int, default=200, help="single faiss queries")


def run(args) -> dict:
    n, d = args.n, args.d
    cands = candidate_periods(n, 2, 1, 7)
    periods = choose_periods(cands, [0.0] * len(cands), n, 2)
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
    flat = BruteForce(n_threads=cores()).fit(refs)  # last: its OpenMP threads spin on
    one = {"faiss IndexFlatIP (1 row)": lambda q: flat.search(q[None], 1)}
    rows.update(latencies(one, queries, dict.fromkeys(one, args.exact)))
    for name, row in rows.items():
        log.info("%s: %.1f us", name, 1e6 * row["median_s"])
    batch = queries[:1000]
    throughput = {"jitted decode": time_batch(jit, batch, repeats=5),
                  "faiss IndexFlatIP": time_batch(lambda q: flat.search(q, 1), batch,
                                                 repeats=3)}  # fmt: skip
    return dict(n=n, d=d, periods=list(periods), singles=args.singles, single=rows,
                batch=throughput, same_as_batch_decode=bool(same),
                locate_same_as_batch_decode=bool(same_locate),
                padded_rows=int(rows_p))  # fmt: skip


def markdown(r: dict) -> str:
    lat = [
        [k, 1e6 * v["median_s"], 1e6 * v["p95_s"], v.get("calls", r["singles"])]
        for k, v in r["single"].items()
    ]
    thr = r["batch"]
    ratio = thr["jitted decode"]["queries_per_s"]
    ratio /= thr["faiss IndexFlatIP"]["queries_per_s"]
    locate, predict, faiss_one = (
        next(1e6 * v["median_s"] for k, v in r["single"].items() if k.startswith(s))
        for s in ("RhythmicMap.locate", "RhythmicMap.predict", "faiss")
    )
    p = sum(r["periods"])
    met = "met" if locate <= 20 else "not met"
    return "\n".join(header("One query to one place", r)) + "\n" + "\n\n".join([
        f"Map: N = {r['n']}, d = {r['d']}, periods {r['periods']}"
        f" ({p} templates, {4 * r['d'] * p / 1e6:.2f} MB of float32, stored as"
        f" {r.get('padded_rows', p)} rows).",
        table(["path", "median us", "p95 us", "calls"], lat),
        f"Batches of 1000: jitted decode {thr['jitted decode']['queries_per_s']:,.0f}"
        f" queries/s, faiss flat {thr['faiss IndexFlatIP']['queries_per_s']:,.0f}:"
        f" **{ratio:.1f}x**. The numpy path gives the batch decode's place for every"
        f" query: {r['same_as_batch_decode']} (SmallDecoder.place),"
        f" {r.get('locate_same_as_batch_decode', 'not run')} (RhythmicMap.locate).",
        f"Targets: one descriptor -> place <= 20 us median: {met} by RhythmicMap.locate"
        f" ({locate:.1f} us; predict on one row {predict:.1f} us; faiss flat on one row"
        f" {faiss_one:,.0f} us, {faiss_one / locate:,.0f}x longer); batch decoding >="
        f" 40x faiss flat: {'met' if ratio >= 40 else 'not met'} ({ratio:.1f}x). A"
        " query's cost is the templates' product with it: the rest (bias, one argmax"
        " over both periods' blocks of rows, one look-up in the table of every phase"
        " pair's place, the shape check) is a few microseconds. OpenBLAS runs that"
        " sgemv on one thread below rows x cols = 460,800 and on its thread pool from"
        " there; the map stores each period's templates in a block of equal rows (spare"
        " rows zero, bias -inf) grown to that size, which shares the product between"
        " the 2 cores (compare the first two rows). The batch decode multiplies numpy"
        " queries by numpy's BLAS where they lie and runs the rest jitted. The numpy"
        " paths are timed in turns, so the load falls on each alike; the thread pool's"
        " p95 grows with the load (the other core is busy).",
    ])  # fmt: skip


if __name__ == "__main__":
    main(__doc__, run, markdown, options, stem="single_query", quick=QUICK)
