"""Batch and single-query decoding against exact search, on the same features.

python scripts/bench_decode.py           # writes reports/decode.{json,md}
python scripts/bench_decode.py --quick   # 1 timed batch, 30 single queries
python scripts/bench_decode.py --render reports/decode.json  # Markdown again
"""

import _harness as h
import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax.decoding.queries import decode_queries as decode
from rhythmic_jax.eval.baselines import BruteForce
from rhythmic_jax.eval.metrics import time_batch, time_single_queries
from rhythmic_jax.map.periods import database_bytes, nominal_periods, storage_bytes
from rhythmic_jax.solvers.objective import Templates

BATCH = 1000
LARGE = 20_000  # rows of the device-resident batch (fewer where d is large)
LARGE_BYTES = 2**28  # the large batch's float32 bytes at most
NOISE = 0.5  # query noise relative to a unit reference
QUICK = dict(repeats=1, singles=30)  # --quick


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
        batch = time_batch(fn, queries, repeats=repeats)
        single = time_single_queries(fn, queries[:singles], warmup=10)
        out[label] = dict(batch=batch, single=single)
        h.log.info("  %s: %.0f queries/s, single median %.3f ms", label,
                   batch["queries_per_s"], 1e3 * single["median_s"])  # fmt: skip
    # device-resident batches, uploaded once outside the timing: the jitted
    # decode (in chunks of buckets.CHUNK rows above that size)
    rows = min(LARGE, LARGE_BYTES // (4 * d))
    big = np.resize(queries, (rows, d))
    for label, batch in (("rhythmic_device", queries), ("rhythmic_device_large", big)):
        dev = jax.device_put(batch)
        out[label] = dict(batch=time_batch(
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
        map_bytes=storage_bytes(periods, d), database_bytes=database_bytes(n, d),
        flop_ratio=n / p, faiss_top1_is_source=float(np.mean(top[:, 0] == src)),
        rhythmic=r, faiss=f, rhythmic_device=out["rhythmic_device"],
        rhythmic_device_large=out["rhythmic_device_large"],
        batch_speedup=r["batch"]["queries_per_s"] / f["batch"]["queries_per_s"],
        single_speedup_median=f["single"]["median_s"] / r["single"]["median_s"],
        single_speedup_p95=f["single"]["p95_s"] / r["single"]["p95_s"],
    )  # fmt: skip


def case_markdown(c: dict) -> str:
    r, f = c["rhythmic"], c["faiss"]
    cases = ((f"rhythmic decode ({c['p']} templates)", r),
             (f"faiss IndexFlatIP ({c['n']} references)", f))  # fmt: skip
    rows = [[label, s["batch"]["queries_per_s"], 1e3 * s["single"]["median_s"],
             1e3 * s["single"]["p95_s"]] for label, s in cases]  # fmt: skip
    head = ["method", f"queries/s (batch {c['batch_size']})", "single ms median"]
    dev = [(f"rhythmic decode, device batch of {s['batch']['batch_size']}",
            s["batch"]["queries_per_s"]) for s in
           (c.get("rhythmic_device"), c.get("rhythmic_device_large")) if s]  # fmt: skip
    return "\n\n".join([
        f"## {c['name']}: N = {c['n']}, d = {c['d']}, periods {c['periods']}",
        h.table([*head, "single ms p95"], rows),
        *([h.table(["batch uploaded once", "queries/s"], dev)] if dev else []),
        f"Rhythmic / faiss: **{c['batch_speedup']:.1f}x** batch throughput,"
        f" **{c['single_speedup_median']:.1f}x** single-query median latency"
        f" ({c['single_speedup_p95']:.1f}x at p95); FLOP ratio N / p = {c['n']} /"
        f" {c['p']} = **{c['flop_ratio']:.1f}**. Bytes read per single query: map"
        f" {c['map_bytes'] / 2**20:.1f} MiB, database {c['database_bytes'] / 2**20:.1f}"
        f" MiB. Threads: XLA {c['threads']['xla']}, faiss {c['threads']['faiss']}. Load"
        f" average at the start of the case {c['load_average_start']}. Single queries"
        f" timed: {c['single_queries']}; batch calls timed: {r['batch']['repeats']}"
        " each. faiss top-1 = the query's own reference (same index) for"
        f" {100 * c['faiss_top1_is_source']:.1f} % of queries.",
    ]) + "\n"  # fmt: skip


def markdown(report: dict) -> str:
    title = "Decoding: rhythmic map against exact search (faiss IndexFlatIP)"
    parts = h.header(title, report) + [
        "The map's templates are random (decoding cost does not depend on their"
        " values); both decoders see the same references and queries.",
        "",
    ]
    return "\n".join(parts + [case_markdown(c) for c in report["cases"]])


def options(ap) -> None:
    ap.add_argument("--repeats", type=int, default=5, help="timed batch calls")
    ap.add_argument("--singles", type=int, default=300, help="timed single queries")


def run(args) -> dict:
    kw = dict(repeats=args.repeats, singles=args.singles)
    refs, qry, src = random_features(10713, 4096, BATCH, seed=0)
    cases = [
        bench_case("random, Nordland spring size", refs, qry, src, (105, 106), **kw)
    ]
    del refs, qry
    periods = nominal_periods(3576, 2, 1, 7)
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


if __name__ == "__main__":
    h.main(__doc__, run, markdown, options, stem="decode", quick=QUICK)
