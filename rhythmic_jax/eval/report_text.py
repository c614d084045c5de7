"""An evaluation in words: the plain-text table ``rhythmic-jax evaluate``
prints from :func:`rhythmic_jax.eval.report.evaluate_map`'s result, with the
line papers quote for each method and the legend of its columns.
"""

from __future__ import annotations

from typing import Any

from rhythmic_jax.eval.method_scores import KS
from rhythmic_jax.eval.metrics import recall_line
from rhythmic_jax.eval.timing import WARMUP

__all__ = ["format_evaluation", "legend"]


def _database_words(result: dict[str, Any]) -> str:
    """The database every bytes share is over, in words."""
    if "database_bytes" not in result:
        return ""
    frames = result.get("database_frames", result["n"])
    return (f" of {frames} x {result['d']} float32, {result['database_bytes']:,} "
            "B, the frames brute force searches")  # fmt: skip


def _truth_line(result: dict[str, Any]) -> str:
    g = result.get("ground_truth") or {}
    src = g.get("source", "index-aligned (query i is place i)")
    if g.get("tolerance_m") is not None:
        return f"ground truth: {src}, tolerance {g['tolerance_m']:g} m"
    if result.get("tolerance") is None:
        return f"ground truth: {src} (lists of right places)"
    return f"ground truth: {src}, tolerance ±{result['tolerance']} frames"


def _denominator_line(result: dict[str, Any]) -> str:
    """Which queries recall@K is out of, and what the other convention divides by."""
    over, n = result.get("recall_over"), result.get("recall_queries")
    if over is None or n is None:
        return ""
    total = result["n_queries"]
    matched = int((result.get("ground_truth") or {}).get("queries_in_map", total))
    if matched == total:
        return (
            f"\nrecall@K over all {total} queries, each with a right place "
            "(VPR_Tutorial's and VPR-methods-evaluation's conventions agree)"
        )
    if over == "matched":
        return (
            f"\nrecall@K over the {n} of {total} queries that have a right place "
            f"(VPR_Tutorial's convention; VPR-methods-evaluation's divides by all "
            f"{total})"
        )
    return (
        f"\nrecall@K over all {n} queries, the {total - matched} without a right "
        "place counted as misses (VPR-methods-evaluation's convention; "
        f"VPR_Tutorial's divides by the {matched} with one)"
    )


def format_evaluation(result: dict[str, Any]) -> str:
    """A plain-text table of an evaluation's result
    (:func:`rhythmic_jax.eval.report.evaluate_map`)."""
    seq = result["sequence"]
    head = (
        f"n={result['n']} d={result['d']} queries={result['n_queries']}; "
        f"compression ratio {result['compression_ratio']:.4f}"
        f"{_database_words(result)}\n"
        f"decode={result['decode']} sequence={seq if seq else 'off'}; recall@K "
        f"ranks {result.get('recall_ranks', 'single-frame scores')} "
        + (f"(peers at the same L={seq})" if seq and seq > 1 else "(single frames)")
        + "\n"
        + _truth_line(result)
        + _denominator_line(result)
    )
    cols = ["accuracy", "accuracy_tol"]
    cols += [f"recall@{k}" for k in result.get("recall_values", KS)]
    cols += ["pr_auc", "recall@100p", "storage_bytes", "latency_median_s"]
    cols += ["queries_per_s"]
    names = {"latency_median_s": "latency", "storage_bytes": "bytes"}
    names |= {"queries_per_s": "queries/s", "accuracy_tol": "acc_tol"}
    w = 13
    lines = [head, f"{'method':<12}" + "".join(f"{names.get(c, c):>{w}}" for c in cols)]
    for name, row in result["methods"].items():
        cells = []
        for c in cols:
            v = row.get(c)
            if c == "storage_bytes" and v is not None:
                v += row.get("embedding_bytes") or 0  # what a query needs
            if v is None:
                cells.append(f"{'-':>{w}}")
            elif isinstance(v, int):
                cells.append(f"{v:>{w},}")
            elif c == "latency_median_s":
                cells.append(f"{v * 1e3:>{w - 3}.3f} ms")
            else:
                cells.append(f"{v:>{w}.4f}" if v < 100 else f"{v:>{w},.0f}")
        lines.append(f"{row.get('label', name):<12}" + "".join(cells))
    for name, row in result["methods"].items():  # the line papers quote
        label = row.get("label", name)
        lines.append(f"{label}: {row.get('recall_line') or recall_line(row)}")
    return "\n".join(lines + legend(result))


def legend(result: dict[str, Any]) -> list[str]:
    """What the table's columns mean, for the result printed above them."""
    decode = result.get("decode")
    ranks = result.get("recall_ranks", "single-frame scores")
    if (result.get("methods", {}).get("map") or {}).get("codes_bits"):
        decode = "fused" if decode == "hard" else f"fused {decode}"  # no -1 there
    nomatch = " (a -1, no match, counts as wrong)" if decode == "hard" else ""
    lines = [
        f"accuracy: the {decode} decode's place{nomatch} is the right place exactly;"
        " acc_tol: within the tolerance",
        f"recall@K: a right place (within the tolerance) among the K best by the "
        f"{ranks}; they rank every place, so the map's recall@1 can exceed a "
        "hard decode's acc_tol",
    ]
    rows = result.get("methods", {}).values()
    if any(r.get("embedding_bytes") for r in rows):
        lines.append("bytes: what a query needs, the embedding included (the "
                     "compression ratio counts it too)")  # fmt: skip
    lines += result.get("peer_notes") or []
    if any("latency_median_s" in r for r in rows):
        lines.append("latency: one query alone, from its descriptor to a place (a "
                     "map's template product, a code's encoding and an embedding "
                     f"included), median of up to 200 calls after {WARMUP} warm "
                     f"ones; queries/s: all {result.get('n_queries')} queries in "
                     "one call (batched: not 1/latency)")  # fmt: skip
        if (result.get("sequence") or 1) > 1:
            lines.append("latency and queries/s time single frames (the sequence's "
                         "sums are not timed), alike for every row")  # fmt: skip
    return lines
