"""``rhythmic-jax frontier REF QUERIES``: how few bytes a route needs, in one step.

Every representation the library has is fitted on the reference descriptors and
judged on the queries (:func:`rhythmic_jax.eval.frontier.frontier_rows`): maps at
their levels and layouts stored as float32, float16 and int8, ITQ codes, int8
per place, product quantisation (faiss), PCA codes (float32, int8), the map +
code hybrids, exact brute force and, for sequences, SeqSLAM. Every row but
SeqSLAM is timed alike, from query descriptors to a place
(:data:`rhythmic_jax.eval.frontier.LATENCY`). Each row gives bytes per place,
recall@1 (single frames and along sequences of L = 5 and 10), recall@K of the
single frames' ranking (``--recall-values``; in the table only when given),
the sequence scorer (a map's phase
domain, the diagonal sum of codes' and brute force's similarities, both fused
for a hybrid, SeqSLAM), recall at 100 % precision and the query latency; the
rows no other row beats at fewer bytes form the Pareto front, and ``--budget``
names the best representation within a byte budget.

The default grid (:data:`rhythmic_jax.app.specs.GRIDS` ``small``: three maps,
three code sizes, two product quantisers) runs in a couple of minutes on a few
thousand places; ``full`` is every map of r = 2, 3 at levels 1-4 and every code
size. faiss's k-means
warnings (product quantisers trained on fewer points than it asks for) are
gathered into one line of the result's ``notes``.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any

from rhythmic_jax.app.specs import GRIDS, FrontierJob, recall_values
from rhythmic_jax.errors import InputError

__all__ = ["frontier", "frontier_lines", "write_csv"]

DTYPES = ("float32", "float16", "int8")  # how each map's templates are stored

COLUMNS = ("name", "kind", "bytes_per_place", "storage_bytes", "share",
           "recall@1 L=1", "recall@100p", "recall@1 L=5", "recall@1 L=10",
           "sequence_scorer", "latency_s", "latency_p95_s", "queries_per_s",
           "pareto")  # fmt: skip
"""The CSV's columns: ``latency_s`` is one query alone from its descriptor to a
place (median, :data:`rhythmic_jax.eval.frontier.LATENCY`), ``queries_per_s``
the whole batch in one call."""


def _ints(text: str, what: str) -> tuple:
    """``64,128`` -> (64, 128); ``2:4,3:4`` -> ((2, 4), (3, 4))."""
    try:
        parts = [tuple(int(v) for v in p.split(":")) for p in str(text).split(",")]
    except ValueError:
        msg = f"{{opt:{what}}} {text!r}: give integers, comma-separated"
        raise InputError(msg) from None
    return tuple(p if len(p) > 1 else p[0] for p in parts)


def frontier(job: FrontierJob, progress: bool = False) -> dict[str, Any]:
    """Recall against bytes for every representation of ``job.reference``'s
    places, the rows written to ``job.csv`` and drawn in ``job.plot`` when given.

    The job's settings (:class:`rhythmic_jax.app.specs.FrontierJob`):
      reference, queries: descriptor files (.npy, hloc .h5) or image folders;
        row i of the reference is place i.
      ground_truth, tolerance_m: as ``evaluate`` reads them
        (:func:`rhythmic_jax.eval.ground_truth_files.load_ground_truth`);
        none: query i is place i within ``tolerance`` frames.
      maps, bits, pq: maps as r:level, ITQ code sizes, PQ sub-quantisers;
        None: those of ``grid`` (:data:`rhythmic_jax.app.specs.GRIDS`).
      lengths: sequence lengths (queries in route order); lengths longer than
        the queries are left out (none left: refused).
      budget: bytes per place; the result's ``choice`` is the best row within.
      recall_over: recall@1's denominator, ``"matched"`` (the queries with a
        right place) or ``"all"`` (every query: a query without one is a
        miss); recall at 100 % precision is out of the matched ones either way.
      recall_values: the K of every row's single-frame ``recall@K L=1`` (K > 1
        up to the places; recall@1 is ``recall@1 L=1``).
      input_size: the size image folders are resized to for the descriptor
        (None: its own); a descriptor file's record must agree.
      given: ``tolerance_m`` among them with a ground truth that lists the
        right places itself is refused
        (:func:`rhythmic_jax.eval.ground_truth_files.idle_tolerance`).
      select: (reference's, queries') prefixes of the image names kept from
        hloc ``.h5`` files (``""``: every row), so one file holds both.

    Returns ``{"rows", "pareto" (names), "choice", "ground_truth", "config",
    "n", "d", "n_queries", "recall_over", "recall_queries", "skipped", "notes",
    "seconds"}``; ``skipped`` holds a line per kind of representation the route
    cannot train, left out before any is fitted
    (:func:`rhythmic_jax.eval.frontier.trainable`: ITQ bits above the places or
    the dimensions, PQ that does not divide d).
    """
    from rhythmic_jax.app.native_stderr import gathered_stderr
    from rhythmic_jax.eval import frontier as fr
    from rhythmic_jax.eval.ground_truth_files import idle_tolerance
    from rhythmic_jax.frames.sources import load_sources, parse_input_size

    reference, queries, cache = job.reference, job.queries, job.cache or None
    if cache:
        check_cache(cache, [reference, queries, *(job.ground_truth or ())])
    grid = GRIDS[job.grid]
    maps = grid["maps"] if job.maps is None else _ints(job.maps, "maps")
    bits = grid["bits"] if job.bits is None else _ints(job.bits, "bits")
    pq = grid["pq"] if job.pq is None else _ints(job.pq, "pq") if job.pq else ()
    lengths = _ints(job.lengths, "lengths")

    t0 = time.perf_counter()
    ref_prefix, query_prefix = (p or None for p in job.select or ("", ""))
    reads = {"progress": progress, "input_size": parse_input_size(job.input_size)}
    ref = load_sources([reference], job.descriptor, select=ref_prefix, **reads).x
    qry = load_sources([queries], job.descriptor, select=query_prefix, **reads).x
    if ref.shape[1] != qry.shape[1]:
        raise InputError(
            f"{queries}: {qry.shape[1]}-d descriptors but {reference} has "
            f"{ref.shape[1]}-d"
        )
    truth = None
    if job.ground_truth:
        from rhythmic_jax.eval.ground_truth_files import load_ground_truth

        truth = load_ground_truth(
            job.ground_truth, n_queries=len(qry), n_places=len(ref),
            query_source=queries, reference_sources=[reference],
            tolerance_m=job.tolerance_m, fmt=job.ground_truth_format,
        )  # fmt: skip
        idle_tolerance(truth, job.given)
    elif len(qry) > len(ref):
        raise InputError(
            f"{queries}: {len(qry)} queries for {len(ref)} places; without "
            "{opt:ground_truth} query i is place i"
        )
    d = ref.shape[1]
    kept = tuple(k for k in lengths if k <= len(qry))
    if not kept:
        raise InputError(
            f"{{opt:lengths}} {','.join(map(str, lengths))}: longer than the "
            f"{len(qry)} queries"
        )
    cfg, skipped = fr.trainable(fr.FrontierConfig(
        maps=tuple(maps), bits=tuple(bits),
        lengths=kept, tolerance=int(job.tolerance),
        dtypes=DTYPES, pq=tuple(pq), scalar=True,
        recall_values=recall_values(job.recall_values),
    ), len(ref), d)  # fmt: skip
    with gathered_stderr(KMEANS_WARNING) as warned:
        rows = fr.frontier_rows(
            ref, qry, cfg, cache=cache, truth=truth, progress=progress,
            seqslam=max(cfg.lengths) > 1,
        )  # fmt: skip
    matched = len(qry) if truth is None else int(truth.in_map.sum())
    if job.recall_over == "all":  # the unmatched queries are misses: hits / b
        for row in rows:
            keys = [f"recall@1 L={k}" for k in cfg.lengths]
            keys += [f"recall@{k} L=1" for k in cfg.recall_values if k > 1]
            for key in keys:
                if row.get(key) is not None:
                    row[key] *= matched / len(qry)
    for row, front in zip(rows, fr.pareto_front(rows), strict=True):
        row["pareto"] = front
    if truth is not None:
        described = truth.describe()
    else:
        described = {"source": "index-aligned (query i is place i)",
                     "tolerance_frames": int(job.tolerance)}  # fmt: skip
    budget = job.budget
    choice = None if budget is None else fr.choose(rows, float(budget))
    result = {
        "n": len(ref),
        "d": d,
        "n_queries": len(qry),
        "recall_over": job.recall_over,
        "recall_queries": matched if job.recall_over == "matched" else len(qry),
        "ground_truth": described,
        "config": dataclasses.asdict(cfg),
        "budget_bytes_per_place": budget,
        "choice": choice["name"] if choice else None,
        "pareto": [r["name"] for r in rows if r["pareto"]],
        "rows": rows,
        "skipped": skipped,
        "notes": [kmeans_note(warned)] if warned else [],
        "seconds": time.perf_counter() - t0,
    }
    _write(job, result)
    return result


def _write(job: FrontierJob, result: dict[str, Any]) -> None:
    """``--csv``'s rows and ``--plot``'s frontier, where asked for."""
    if job.csv:
        write_csv(result["rows"], job.csv)
    if job.plot:
        from rhythmic_jax.eval.figures import plot_frontier

        plot_frontier(result["rows"], job.plot, result["config"]["lengths"],
                      title=f"recall per byte, {result['n']} places",
                      per_place=True, budget=job.budget)  # fmt: skip


def check_cache(cache: str, inputs) -> None:
    """Refuse (:class:`InputError`) a ``--cache`` that is a file, or that is one
    of ``inputs`` or lies inside one (an image folder: the cache writes its
    entries there)."""
    from pathlib import Path

    place = Path(cache).expanduser().resolve()
    if place.exists() and not place.is_dir():
        raise InputError(f"{{opt:cache}} {cache}: a file, not a folder")
    for given in inputs:
        src = Path(given).expanduser().resolve()
        if place == src or src in place.parents:
            raise InputError(
                f"{{opt:cache}} {cache}: the input {given} is there; give a folder "
                "of its own"
            )


KMEANS_WARNING = r"WARNING clustering (\d+) points to (\d+) centroids"


def kmeans_note(lines: list[str]) -> str:
    """faiss's k-means warnings (one per sub-quantiser trained) in one line."""
    import re

    found = [re.search(KMEANS_WARNING + r".*at least (\d+)", line) for line in lines]
    sizes = sorted({m.groups() for m in found if m}, key=lambda g: int(g[1]))
    what = "; ".join(f"{k} centroids from {n} points (it asks for {least})"
                     for n, k, least in sizes)  # fmt: skip
    return (f"note: faiss warned {len(lines)} times while training product "
            f"quantisers on few points: {what or lines[0]}")  # fmt: skip


def _cell(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "*" if v else ""
    if isinstance(v, float):
        return f"{v:.4f}" if v <= 1 else f"{v:,.0f}"
    return f"{v:,}" if isinstance(v, int) else str(v)


def recall_keys(rows) -> list[str]:
    """The rows' single-frame ``recall@K L=1`` keys of K > 1, K ascending."""
    keys = {k for r in rows for k in r if k.startswith("recall@") and k.endswith("L=1")}
    keys -= {"recall@1 L=1"}
    return sorted(keys, key=lambda k: int(k.split("@")[1].split()[0]))


def frontier_lines(result: dict[str, Any], recall_at: bool = False) -> str:
    """The table, fewest bytes first, Pareto rows marked ``*``, and the choice;
    ``recall_at``: with a column per ``recall@K L=1`` (K > 1) beside R@1."""
    g = result["ground_truth"]
    if g.get("tolerance_m") is not None:
        tol = f"tolerance {g['tolerance_m']:g} m"
    elif g.get("tolerance_frames") is not None:
        tol = f"tolerance ±{g['tolerance_frames']} frames"
    else:  # a file listing each query's right places (VPR-Bench, .npy lists)
        mean = g.get("positives_per_query_mean")
        each = "" if mean is None else f", {mean:.1f} per query on average"
        tol = f"the right places it lists{each}"
    lengths = result["config"]["lengths"]
    at = recall_keys(result["rows"]) if recall_at else []
    keys = ["recall@1 L=1", *at, "recall@100p"]
    keys += [f"recall@1 L={k}" for k in lengths[1:]]
    heads = ["", "representation", "B/place", "share %", "R@1"]
    heads += [k.replace("recall", "R").replace(" L=1", "") for k in at] + ["R@100P"]
    heads += [f"R@1 L={k}" for k in lengths[1:]] + ["ms/query", "q/s batch"]
    heads += ["sequence scorer"] * bool(lengths[1:])
    body = []
    for r in sorted(result["rows"], key=lambda r: (r["storage_bytes"], r["name"])):
        lat, qps = r.get("latency_s"), r.get("queries_per_s")
        scorer = [_cell(r.get("sequence_scorer"))] if lengths[1:] else []
        body.append(["*" if r["pareto"] else "", r["name"],
                     f"{r['bytes_per_place']:,.0f}", f"{100 * r['share']:.2f}",
                     *(_cell(r.get(k)) for k in keys),
                     "-" if lat is None else f"{1e3 * lat:.3f}",
                     "-" if qps is None else f"{qps:,.0f}", *scorer])  # fmt: skip
    widths = [max(len(str(x)) for x in col) for col in zip(heads, *body, strict=True)]
    text = {0, 1, len(heads) - 1} if lengths[1:] else {0, 1}  # left-aligned
    fmt = [f"{{:<{w}}}" if i in text else f"{{:>{w}}}" for i, w in enumerate(widths)]
    lines = [
        f"{result['n']} places of {result['d']}-d, {result['n_queries']} queries; "
        f"ground truth: {g['source']}, {tol}; {_over_line(result)}; "
        f"{result['seconds']:.0f} s",
        "  ".join(f.format(h) for f, h in zip(fmt, heads, strict=True)).rstrip(),
    ]
    lines += ["  ".join(f.format(c) for f, c in zip(fmt, row, strict=True)).rstrip()
              for row in body]  # fmt: skip
    lines.append("* Pareto front: no other row has at least its recall@1 (L=1) in "
                 "fewer bytes")  # fmt: skip
    lines.append(f"ms/query: {fr_latency()}")
    lines += result.get("skipped", [])
    if result["budget_bytes_per_place"] is not None:
        b = result["budget_bytes_per_place"]
        pick = result["choice"] or f"nothing fits in {b:g} bytes per place"
        lines.append(f"within {b:g} bytes per place: {pick}")
    return "\n".join(lines + list(result.get("notes", ())))


def fr_latency() -> str:
    """:data:`rhythmic_jax.eval.frontier.LATENCY` (imported when printed)."""
    from rhythmic_jax.eval.frontier import LATENCY

    return LATENCY


def _over_line(result: dict[str, Any]) -> str:
    """Which queries recall@1 is out of."""
    n, total = result.get("recall_queries", result["n_queries"]), result["n_queries"]
    if result.get("recall_over") == "all":
        return f"recall@1 over all {n} queries (one without a right place: a miss)"
    return f"recall@1 over the {n} of {total} queries that have a right place"


def write_csv(rows, path: str | Path) -> None:
    """One line per representation, the columns of :data:`COLUMNS` with the
    rows' ``recall@K L=1`` after ``recall@1 L=1`` (names inert,
    :mod:`rhythmic_jax.io.csv_cells`)."""
    from rhythmic_jax.io.atomic import atomic_path
    from rhythmic_jax.io.csv_cells import csv_text

    at = COLUMNS.index("recall@1 L=1") + 1
    columns = (*COLUMNS[:at], *recall_keys(rows), *COLUMNS[at:])
    text = csv_text(columns, ([r.get(c) for c in columns] for r in rows))
    with atomic_path(Path(path)) as tmp, open(tmp, "w", newline="") as f:
        f.write(text)
