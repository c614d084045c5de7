"""What the command line prints: the text form of each job's result.

Each function takes what a job of :mod:`rhythmic_jax.app.jobs` returns (a map's
or an embedding's info dict, predictions, an evaluation) and returns the lines,
without printing them; ``--json`` prints the dicts themselves instead.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from rhythmic_jax.jit_options import describe as compile_options

if TYPE_CHECKING:
    import numpy as np

__all__ = [
    "evaluate_summary", "fit_summary", "fusion_words", "info_lines", "learn_summary",
    "query_summary",
]  # fmt: skip

W = 18  # width of the names in info's lines


def _fusion_learned(fusion: dict[str, Any]) -> str:
    """A fusion weight an embedding learned, in words (its R@1 and codes)."""
    return (
        f"{fusion['weight']:g} for {fusion['codes']} codes (R@1 "
        f"{fusion['recall']:.3f} on the training places it learned from, "
        f"{fusion['places']}, in-sample"
    )


def held_out_words(held: dict[str, Any]) -> str:
    """The embedding's recall on the places held out of learning, named so."""
    return (
        f"R@1 {held['embedded']:.3f} on {held['places']} held-out places of the "
        f"training route (not used to learn; {held['codes']} codes, within "
        f"{held['tolerance']} place; raw descriptors' codes {held['raw']:.3f})"
    )


def learn_summary(out: str, emb, info: dict[str, Any]) -> str:
    """Lines about a saved embedding: its shape and the places it learned from,
    its recall on the held-out places, the fusion weight learned with it."""
    line = (
        f"embedding {out}: {emb.kind} {emb.d} -> {emb.k} dims, "
        f"{info['seconds']:.1f} s on {info.get('learn_places', info['places'])} "
        f"places x {info['traversals']} traversals"
    )
    held = info.get("held_out")
    if held:
        line += f"\n  {held_out_words(held)}"
    fusion = info.get("fusion")
    if fusion:
        line += f"\n  fusion {_fusion_learned(fusion)}, {fusion['seconds']:.1f} s)"
    return line


def fit_summary(out: str, info: dict[str, Any]) -> str:
    """One line about a saved map: size, periods, storage and compression."""
    codes = ""
    if info.get("codes_bits"):
        kind = info.get("codes_kind") or "itq"
        bits = f"{info['codes_bits']}-bit"
        codes = f" with {'int8' if kind == 'int8' else bits} codes"
    emb = info.get("embedding_bytes") or 0
    counted = ", the embedding counted" if emb else ""
    return (
        f"map {out}: n={info['n']} d={info['d']} {info['layout']}"
        f"{codes} storage={info['storage_bytes']:,} B"
        + (f" + embedding {emb:,} B" if emb else "")
        + f" (ratio {info['compression_ratio']:.4f} of {info['database_bytes']:,} B"
        f"{counted})"
    )


def fusion_words(weight: float) -> str:
    """A fusion weight and what it leaves deciding: 0, the codes alone; 1, the
    map's templates alone; else both."""
    alone = {0.0: " (the codes alone)", 1.0: " (the map's templates alone)"}
    return f"{weight:g}{alone.get(float(weight), '')}"


def query_summary(pred: np.ndarray, out: str | None, csv: str | None = None) -> str:
    """One line about predictions written to ``out`` (and results to ``csv``)."""
    where = " and ".join(x for x in (out, csv and f"{csv} (per query)") if x)
    return f"{len(pred)} predictions ({int((pred < 0).sum())} no match) -> {where}"


def describe_summary(job, x: np.ndarray) -> str:
    """One line about descriptors written by ``describe``: rows, dimension, source."""
    name = job.reading.descriptor or "patchnorm"
    return (
        f"{job.out}: {x.shape[0]} frames of {job.source} described with {name}, "
        f"{x.shape[1]}-d float32 ({x.nbytes:,} B)"
    )


def _rows(rows: list[tuple[str, Any]]) -> str:
    """``name: value`` lines, the names right-aligned in :data:`W` columns."""
    return "\n".join(f"{name:>{W}}: {value}" for name, value in rows)


def info_lines(info: dict[str, Any]) -> str:
    """The text form of :func:`rhythmic_jax.app.jobs.info`, one setting a line.

    An embedding: its shape and method, its descriptor and the fusion weight it
    learned. A map: its settings, where its embedding, descriptor and fusion
    weight came from (the fusion line only with codes; maps saved before say
    only what they hold), its storage, each candidate period's training error
    and the compile options.
    """
    fusion = info.get("fusion")
    if info.get("kind") == "embedding":
        learned = info.get("learn") or {}
        method = (learned.get("config") or {}).get("method")
        places = learned.get("learn_places", learned.get("places"))
        how = f", {method} on {places} places" if method else ""
        uses = (
            "(descriptor files: fit --embedding takes .npy)"
            if info["descriptor"] == "features"
            else "(fit --embedding describes images with it)"
        )
        weight = (
            f"{_fusion_learned(fusion)}; fit --embedding --codes {fusion['codes']} "
            "uses it)"
            if fusion
            else "none learned (saved before learn kept one): maps fuse at 0.5"
        )
        held = learned.get("held_out")
        return _rows([
            ("embedding", f"{info['head']} {info['d']} -> {info['k']} dims{how}"),
            ("descriptor", f"{info['descriptor']} {uses}"),
            ("fusion", weight),
            *([("held out", held_out_words(held))] if held else []),
        ])  # fmt: skip
    rows = [(key, info[key]) for key in ("n", "d", "layout")]
    rows += [
        ("storage_bytes", f"{info['storage_bytes']:,}"),
        ("embedding_bytes", f"{info['embedding_bytes']:,}"),
        ("embedding", info["embedding"]),
        ("compression_ratio", f"{info['compression_ratio']:.4f} of "
                              f"{info['database_bytes']:,} B ({info['n']} x "
                              f"{info['d']} float32, one frame a place)"),
        ("C", _penalty(info)),
    ]  # fmt: skip
    if info.get("descriptor"):
        rows.insert(3, ("descriptor", info["descriptor"]))
    ref, st = info.get("reference") or {}, info["storage"]
    if ref.get("embedding"):
        taken = ref.get("descriptor_from_embedding")
        taken = f"; descriptor {info['descriptor']} taken from it" if taken else ""
        rows.append(("embedding from", f"{ref['embedding']}{taken}"))
    if info.get("codes_bits"):
        w, fusion = (info.get("config") or {}).get("fusion"), ref.get("fusion")
        how = f" ({fusion['from']}: {fusion['note']})" if fusion else ""
        rows.append(("fusion", f"{fusion_words(w)}{how}"))
    rows += [
        ("storage fixed", f"{st['fixed']:,} B (code transform)"),
        ("per place", _per_place(info)),
        *_period_rows(info),
        ("share", f"{st['share']:.4f} of the float32 database"),
    ]
    if info.get("checksums"):
        rows.append(("checksums", info["checksums"]))
    return _rows(rows + [("compile options", _compile_options())])


def _penalty(info: dict[str, Any]) -> str:
    """The SVM penalty C, and whether it is the default C = log N."""
    import math

    c, n = float(info["c"]), int(info["n"])
    if (info.get("config") or {}).get("c") is None and math.isclose(c, math.log(n)):
        return f"{c:.4f} (SVM penalty C = log N, N = {n})"
    return f"{c:.4f} (SVM penalty C, set by the fit; log N = {math.log(n):.4f})"


def _per_place(info: dict[str, Any]) -> str:
    """The codes' bytes of one place (and of all of them)."""
    total, n = int(info["storage"]["per_place"]), int(info["n"])
    if not total:
        return "0 B (no codes)"
    return f"{total / n:,.0f} B (codes; {total:,} B for {n} places)"


def _period_rows(info: dict[str, Any]) -> list[tuple[str, str]]:
    """One line per candidate period: its templates' bytes when the map keeps
    it, and its training error; other layouts' groups a line each."""
    per = info["storage"]["per_period"]
    rows = []
    for t, e in zip(info["candidates"], info["candidate_errors"], strict=True):
        kept = per.get(str(t))
        bytes_ = f"{kept:,} B (templates), " if kept is not None else "not kept, "
        rows.append((f"period {t}", f"{bytes_}training error {e:.4f}"))
    named = {str(t) for t in info["candidates"]}
    rows += [(f"group {g}", f"{b:,} B (templates)")
             for g, b in per.items() if g not in named]  # fmt: skip
    return rows


def _compile_options() -> str:
    """The compile options of the backend JAX would use here, told without
    starting JAX when the environment or the installed plugins say which."""
    import importlib.util
    import os

    chosen = os.environ.get("JAX_PLATFORMS", "").split(",")[0].strip().lower()
    if not chosen:
        plugins = ("jax_cuda12_plugin", "jax_cuda13_plugin", "jax_rocm60_plugin")
        if any(importlib.util.find_spec(p) for p in plugins):
            import jax

            chosen = jax.default_backend()
        else:
            chosen = "cpu"
    return compile_options("gpu" if chosen in ("cuda", "rocm") else chosen)


def evaluate_summary(result: dict[str, Any]) -> str:
    """The text form of :func:`rhythmic_jax.app.jobs.evaluate`: the table, then
    the reference note (and where the plot went)."""
    from rhythmic_jax.eval.report import format_evaluation

    lines = format_evaluation(result) + "\n" + result["reference_note"]
    if result.get("plot"):
        lines += f"\nPR curves, recall@N and the route -> {result['plot']}"
    if result.get("matches"):
        lines += (
            f"\nqueries beside the places chosen and the right ones -> "
            f"{result['matches']}"
        )
    return lines
