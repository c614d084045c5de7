"""The map's share of a fused score: chosen for a fit, learned with an embedding.

A hybrid map (``--codes``) fuses its place scores with the codes' similarities
at a weight ``w`` (:mod:`rhythmic_jax.decoding.fusion`). ``learn`` learns ``w``
on its training traversals (:func:`learn_fusion`) and saves it with the
embedding; ``fit --embedding`` takes it from there unless ``--fusion`` is given
(:func:`rhythmic_jax.map.embedding.fusion_of`).
"""

from __future__ import annotations

from typing import Any

__all__ = ["FUSION_TOLERANCE", "learn_fusion"]


FUSION_TOLERANCE = 1  # places: a match within one place counts, as in the reports


def learn_fusion(traversals, emb, codes="int8") -> dict[str, Any]:
    """The map's share ``w`` of the fused score, learned on training traversals.

    For each traversal a map of the default settings (:class:`MapConfig`) with
    ``codes`` is fitted on its embedded frames and queried with every other
    traversal; ``w`` is the weight of the best recall@1 (within
    ``FUSION_TOLERANCE`` places) averaged over those pairs, ties nearest 0.5
    (:func:`rhythmic_jax.decoding.fusion.learn_weight`). traversals: two or
    more (n, d) arrays, row i = place i. Returns ``{"weight", "codes",
    "recall", "places", "table": [[w, recall@1], ...], "seconds"}``.
    """
    import time

    import numpy as np

    from rhythmic_jax.decoding import queries
    from rhythmic_jax.decoding.fusion import learn_weight
    from rhythmic_jax.fitting.prepare import fit_frames
    from rhythmic_jax.map.config import MapConfig
    from rhythmic_jax.map.embedding import apply

    t0 = time.perf_counter()
    n = len(traversals[0])
    gt, tables = np.arange(n), []
    for a, ref in enumerate(traversals):
        m = fit_frames(ref, MapConfig(codes=codes), embedding=emb)
        for b, qry in enumerate(traversals):
            if a != b:
                sims = m.codebook.similarity(apply(emb, qry))
                _, table = learn_weight(
                    queries.scores(m, qry),
                    sims,
                    m.periods,
                    m.n,
                    gt,
                    FUSION_TOLERANCE,
                )
                tables.append(table)
    mean = {w: float(np.mean([t[w] for t in tables])) for w in tables[0]}
    best = max(mean.values())
    w = min((w for w, r in mean.items() if r == best), key=lambda w: abs(w - 0.5))
    return {
        "weight": w, "codes": codes, "recall": best, "places": n,
        "table": [[k, r] for k, r in mean.items()],
        "seconds": time.perf_counter() - t0,
    }  # fmt: skip
