"""Recall per byte of a map with codes: its templates alone, its codes alone,
both fused and brute force, each at its bytes (``evaluate``'s frontier rows).
"""

from __future__ import annotations

import numpy as np

from rhythmic_jax.map.periods import database_bytes

__all__ = ["code_similarity", "codes_name", "model_frontier"]


def code_similarity(model, queries) -> np.ndarray:
    """The codes' similarities (b, n) of raw queries (b, d): embedded first where
    the map has an embedding, as its own decode does (its codes live there)."""
    from rhythmic_jax.decoding.queries import queries as map_queries

    return model.codebook.similarity(map_queries(model.value, queries))


def codes_name(book) -> str:
    """A code book as the figures name it: "int8 per place" or "ITQ B bits"."""
    if getattr(book, "kind", None) == "int8":
        return "int8 per place"
    return f"ITQ {book.bits} bits"


def model_frontier(model, queries, pred, truth, sequence=None, brute=None, db=None):
    """Recall@1 against bytes for a fitted map with codes, as ``evaluate`` reports it.

    Rows as :func:`rhythmic_jax.eval.frontier.frontier_rows` gives them, for one
    length L = ``sequence`` or 1: the map's templates alone (soft decode), its
    codes alone (similarities summed along the diagonal for sequences), the
    hybrid (``pred``, the map's own decode) and, for single frames, brute force
    (``brute``: its predictions). ``db``: the bytes every share is over (the
    frames brute force searches; default one float32 frame a place).
    ``truth`` is a :class:`~rhythmic_jax.eval.ground_truth.GroundTruth`.
    """
    from rhythmic_jax.decoding.fusion import code_sequence_scores
    from rhythmic_jax.decoding.sequence import sequence_decode
    from rhythmic_jax.decoding.soft import soft_decode
    from rhythmic_jax.eval.ground_truth import gt_accuracy
    length = int(sequence) if sequence else 1
    key, n, d = f"recall@1 L={length}", model.n, model.d
    emb = model.embedding_bytes  # every part but brute force embeds its queries
    plus = " + embedding" if emb else ""
    s = model.scores(queries)
    sims = code_similarity(model, queries)
    if length > 1:
        alone = sequence_decode(s, model.periods, n, length, (1.0,), "soft")[0]
        coded = code_sequence_scores(sims, length)
    else:
        alone, coded = soft_decode(s, model.periods, n).index, sims
    st = model.storage()
    db = database_bytes(n, d, 4) if db is None else int(db)
    w = float(model.config.fusion)
    fused = "codes alone (fusion 0)" if w == 0 else f"map + codes (fused, w={w:g})"
    parts = [
        ("map", "templates alone" + plus, sum(st["per_period"].values()) + emb, alone),
        ("codes", codes_name(model.codebook) + " alone" + plus,
         model.codebook.storage()["total"] + emb,
         np.argmax(coded, axis=1)),
        ("hybrid", fused + plus, model.storage_bytes + emb, pred),
    ]  # fmt: skip
    if brute is not None and length == 1:
        parts.append(("brute force", "brute force", db, brute))
    return [
        {"kind": kind, "name": name, "storage_bytes": int(size),
         "share": size / db, key: gt_accuracy(np.asarray(p), truth)}
        for kind, name, size, p in parts
    ]  # fmt: skip
