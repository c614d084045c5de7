"""Batch and single-query decoding against exact search, on the same features.

A rhythmic map answers a query with one ``(b, d) x (d, p)`` product, an argmax per
period and a Chinese-remainder look-up (:func:`rhythmic_jax.decoding.hard.decode`,
jitted); exact search scores the query against all N references (faiss
``IndexFlatIP`` through :class:`rhythmic_jax.eval.baselines.BruteForce`). Per query the
products cost ``p d`` against ``N d`` multiply-adds, so ``N / p`` is the FLOP
ratio the measured speed-up is set beside.

Cases, both decoders on the same references and queries in the same run:

- N = 10713, d = 4096 (the paper's Nordland spring size), periods (105, 106):
  random L2-normalised references; queries are 1000 references with Gaussian
  noise, re-normalised.
- N = 3576, d = 2048 with the level-1 periods of that size (the pair of
  ``candidate_periods(3576)`` with the smallest storage): Nordland summer
  patch-normalised 64x32 descriptors as references and winter as queries when
  the data is present, random ones otherwise.

The map's templates are random: decoding costs the same whatever their values.
Throughput: ``time_batch`` over batches of 1000 (median of the timed calls after
one untimed call). Latency: ``time_single_queries`` (10 warm-up calls, then one
call per query; JAX results waited for with ``block_until_ready``). faiss runs
on as many OpenMP threads as XLA has CPU threads (one per core).

    python scripts/bench_decode.py           # writes reports/decode.{json,md}
    python scripts/bench_decode.py --quick   # 1 timed batch, 30 single queries
    python scripts/bench_decode.py --render reports/decode.json  # Markdown again
"""

from __future__ import annotations

import logging
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from _bench_common import (
    begin,
    cores,
    header,
    load_average,
    parser,
    rerender,
    run_record,
    table,
    write_report,
)

from rhythmic_jax.decoding.hard import decode
from rhythmic_jax.eval.baselines import BruteForce
from rhythmic_jax.eval.metrics import time_batch, time_single_queries
from rhythmic_jax.frames.features import cached_describe, get_descriptor
from rhythmic_jax.io.images import nordland
from rhythmic_jax.objective import Templates
from rhythmic_jax.periods import (
    database_bytes,
    nominal_periods,
    storage_bytes,
)

log = logging.getLogger("bench_decode")

BATCH = 1000
NOISE = 0.5  # query noise relative to a unit reference


def unit_rows(a: np.ndarray) -> np.ndarray:
    """Rows scaled to unit L2 norm, float32."""
    return (a / np.linalg.norm(a, axis=1, keepdims=True)).astype(np.float32)


def random_features(n: int, d: int, b: int, seed: int):
    """(references (n, d), queries (b, d), source index of each query (b,))."""
    rng = np.random.default_rng(seed)
    refs = unit_rows(rng.standard_normal((n, d), dtype=np.float32))
    src = rng.choice(n, size=b, replace=False)
    noise = rng.standard_normal((b, d), dtype=np.float32) * np.float32(NOISE)
    return refs, unit_rows(refs[src] + noise / np.sqrt(d, dtype=np.float32)), src


def nordland_features(root: Path, b: int, progress: bool):
    """Nordland summer (3576, 2048) references and the first ``b`` winter
    queries (same index = same place), patch-normalised 64x32, cached."""
    summer, winter = nordland(root / "nordland_64x32", progress=progress)
    desc = get_descriptor("patchnorm")
    key = "nordland64x32-"
    refs = cached_describe(summer.images, desc, key + "summer", progress=progress)
    qry = cached_describe(winter.images, desc, key + "winter", progress=progress)
    return refs, qry[:b], np.arange(b)


def random_map(d: int, periods: tuple[int, ...], seed: int) -> Templates:
    """Templates with random weights (d, p) and biases (p,)."""
    rng = np.random.default_rng(seed)
    p = sum(periods)
    w = rng.standard_normal((d, p), dtype=np.float32) / np.float32(np.sqrt(d))
    b = rng.standard_normal(p, dtype=np.float32) * np.float32(0.01)
    return Templates(jnp.asarray(w), jnp.asarray(b))


def bench_case(
    name: str,
    refs: np.ndarray,
    queries: np.ndarray,
    src: np.ndarray,
    periods: tuple[int, ...],
    repeats: int,
    singles: int,
) -> dict:
    """Throughput and latency of both decoders on the same features."""
    n, d = refs.shape
    p = sum(periods)
    log.info("%s: N=%d d=%d periods %s (p=%d)", name, n, d, periods, p)
    params = random_map(d, periods, seed=1)
    flat = BruteForce(n_threads=cores()).fit(refs)

    def rhythmic(q):
        return decode(params, q, periods, n)

    def exact(q):
        return flat.search(q, 1)

    load = load_average()
    out = {}
    for label, fn in (("rhythmic", rhythmic), ("faiss", exact)):
        batch = time_batch(fn, queries, repeats=repeats)
        single = time_single_queries(fn, queries[:singles], warmup=10)
        out[label] = dict(batch=batch, single=single)
        log.info(
            "  %s: %.0f queries/s in batches of %d, single median %.3f ms",
            label,
            batch["queries_per_s"],
            len(queries),
            1e3 * single["median_s"],
        )
    _, top = exact(queries)
    r, f = out["rhythmic"], out["faiss"]
    return dict(
        name=name,
        n=n,
        d=d,
        periods=list(periods),
        p=p,
        batch_size=len(queries),
        single_queries=singles,
        load_average_start=load,
        threads=dict(xla=cores(), faiss=flat.n_threads),
        map_bytes=storage_bytes(periods, d),
        database_bytes=database_bytes(n, d),
        flop_ratio=n / p,
        faiss_top1_is_source=float(np.mean(top[:, 0] == src)),
        rhythmic=r,
        faiss=f,
        batch_speedup=r["batch"]["queries_per_s"] / f["batch"]["queries_per_s"],
        single_speedup_median=f["single"]["median_s"] / r["single"]["median_s"],
        single_speedup_p95=f["single"]["p95_s"] / r["single"]["p95_s"],
    )


def case_markdown(c: dict) -> str:
    r, f = c["rhythmic"], c["faiss"]
    rows = [
        [
            f"rhythmic decode ({c['p']} templates)",
            r["batch"]["queries_per_s"],
            1e3 * r["single"]["median_s"],
            1e3 * r["single"]["p95_s"],
        ],
        [
            f"faiss IndexFlatIP ({c['n']} references)",
            f["batch"]["queries_per_s"],
            1e3 * f["single"]["median_s"],
            1e3 * f["single"]["p95_s"],
        ],
    ]
    head = ["method", f"queries/s (batch {c['batch_size']})", "single ms median"]
    return "\n".join(
        [
            f"## {c['name']}: N = {c['n']}, d = {c['d']}, periods {c['periods']}",
            "",
            table([*head, "single ms p95"], rows),
            "",
            f"Rhythmic / faiss: **{c['batch_speedup']:.1f}x** batch throughput,"
            f" **{c['single_speedup_median']:.1f}x** single-query median latency"
            f" ({c['single_speedup_p95']:.1f}x at p95); FLOP ratio N / p ="
            f" {c['n']} / {c['p']} = **{c['flop_ratio']:.1f}**. Bytes read per"
            f" single query: map {c['map_bytes'] / 2**20:.1f} MiB, database"
            f" {c['database_bytes'] / 2**20:.1f} MiB. Threads: XLA"
            f" {c['threads']['xla']}, faiss {c['threads']['faiss']}. Load average"
            f" at the start of the case {c['load_average_start']}. Single queries"
            f" timed: {c['single_queries']}; batch calls timed:"
            f" {r['batch']['repeats']} each. faiss top-1 = the query's own"
            f" reference (same index) for {100 * c['faiss_top1_is_source']:.1f} %"
            " of queries.",
            "",
        ]
    )


def markdown(report: dict) -> str:
    title = "Decoding: rhythmic map against exact search (faiss IndexFlatIP)"
    parts = header(title, report) + [
        "The map's templates are random (decoding cost does not depend on their"
        " values); both decoders see the same references and queries.",
        "",
    ]
    parts += [case_markdown(c) for c in report["cases"]]
    return "\n".join(parts)


def main(argv: list[str] | None = None) -> dict:
    ap = parser(__doc__)
    ap.add_argument("--repeats", type=int, default=None, help="timed batch calls")
    ap.add_argument("--singles", type=int, default=None, help="timed single queries")
    ap.add_argument("--quick", action="store_true", help="1 batch, 30 singles")
    args = ap.parse_args(argv)
    if args.render:
        return rerender(args.render, markdown)
    repeats = args.repeats or (1 if args.quick else 5)
    singles = args.singles or (30 if args.quick else 300)

    env, load_start = begin(log)
    kw = dict(repeats=repeats, singles=singles)
    refs, qry, src = random_features(10713, 4096, BATCH, seed=0)
    cases = [
        bench_case("random, Nordland spring size", refs, qry, src, (105, 106), **kw)
    ]
    del refs, qry
    n = 3576
    periods = nominal_periods(n, 2, 1, 7)
    if (args.root / "nordland_64x32").is_dir():
        name = "Nordland summer map, winter queries, patchnorm"
        refs, qry, src = nordland_features(args.root, BATCH, args.progress)
    else:
        log.warning("no Nordland data under %s: random features", args.root)
        name = "random, Nordland 64x32 size"
        refs, qry, src = random_features(n, 2048, BATCH, seed=0)
    cases.append(bench_case(name, refs, qry, src, periods, **kw))
    report = dict(
        **run_record("bench_decode.py", argv, env, load_start),
        jax_backend=jax.default_backend(),
        cases=cases,
    )
    stem = "decode_quick" if args.quick else "decode"
    write_report(args.out, stem, report, markdown(report))
    return report


if __name__ == "__main__":
    main()
