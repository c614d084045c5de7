"""What an embedding does on places it never saw: the held-out end of the route.

:func:`split_places` keeps the last ``share`` of a training route's places out
of learning, after a gap. A contiguous block, not an interleave: frames next to
each other along a route are near-duplicates (Nordland's frames are seconds
apart), so every held-out place of an interleave would have its neighbours in
the learning set and the figure would read as in-sample; a block at the route's
end is new ground, as a map's test segment is (``reports/cross_condition.md``
splits by place the same way). The gap keeps the block's first places from
being near-duplicates of the learning set's last.

:func:`held_out_recall` measures, on those places, the codes a hybrid map would
store: the embedded frames' and the raw descriptors' (the same kind, e.g. int8),
each traversal as the reference and every other as the queries, and
:func:`held_out_notes` says in one line each when the embedding made them
worse or learned from few places per dimension.

Shapes: n places, d input features, k embedded dimensions, h held-out places.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = [
    "PLACES_PER_DIMENSION",
    "TOLERANCE",
    "held_out_notes",
    "held_out_recall",
    "split_places",
]

TOLERANCE = 1  # places: a match within one place counts, as in the reports
# Learning places per embedded dimension below which the closed form's scatter
# is estimated from too few places: on Nordland (Lite0, k = 256) 280 places
# (1.1 a dimension) made held-out R@1 0.16-0.18 where raw codes reach 0.654,
# and 1,200 (4.7 a dimension) 0.730 above them.
PLACES_PER_DIMENSION = 4.0


def split_places(n: int, share: float) -> tuple[int, int]:
    """``(learn, start)``: places ``[0, learn)`` learn, ``[start, n)`` are held
    out (``share`` of n, rounded; 0: none, ``start == n``), a gap of
    ``min(20, n // 20)`` places between them."""
    held = int(round(share * n))
    if held == 0:
        return n, n
    gap = min(20, n // 20)
    return n - held - gap, n - held


def _codes(x: np.ndarray, codes):
    """A code book of the rows x (h, d) of the kind ``codes`` names (int8 or a
    number of ITQ bits)."""
    if codes == "int8":
        from rhythmic_jax.map.scalar_codes import ScalarCodeBook

        return ScalarCodeBook.fit(x)
    from rhythmic_jax.map.codes import CodeBook

    return CodeBook.fit(x, min(int(codes), x.shape[1]))


def _recall(refs: list[np.ndarray], codes) -> float:
    """Mean over ordered pairs (reference a, queries b != a) of the share of
    queries whose most similar code is within :data:`TOLERANCE` of their place."""
    hits = []
    for a, ref in enumerate(refs):
        book = _codes(ref, codes)
        for b, qry in enumerate(refs):
            if a != b:
                best = np.argmax(np.asarray(book.similarity(qry)), axis=1)
                hits.append(np.abs(best - np.arange(len(qry))) <= TOLERANCE)
    return float(np.mean(np.concatenate(hits)))


def held_out_recall(emb, held: list[np.ndarray], codes="int8") -> dict[str, Any]:
    """Recall@1 (within :data:`TOLERANCE` places) of ``codes`` on the held-out
    places ``held`` (one (h, d) array per traversal, row i = place i): of the
    embedded frames and of the raw descriptors. Returns ``{"places", "codes",
    "tolerance", "embedded", "raw"}``."""
    from rhythmic_jax.map.embedding import apply

    return {
        "places": int(len(held[0])),
        "codes": codes,
        "tolerance": TOLERANCE,
        "embedded": _recall([apply(emb, x) for x in held], codes),
        "raw": _recall([np.asarray(x, np.float32) for x in held], codes),
    }


def held_out_notes(info: dict[str, Any], k: int) -> list[str]:
    """One line each: the embedded codes below the raw ones on the held-out
    places; fewer than :data:`PLACES_PER_DIMENSION` learning places a dimension."""
    notes = []
    held = info.get("held_out")
    if held and held["embedded"] < held["raw"]:
        notes.append(
            f"the embedding makes {held['codes']} codes worse on {held['places']} "
            f"held-out places (R@1 {held['embedded']:.3f} embedded against "
            f"{held['raw']:.3f} on the raw descriptors): learn from more places, or "
            "fit maps on the raw descriptors"
        )
    per = info["learn_places"] / k
    if per < PLACES_PER_DIMENSION:
        notes.append(
            f"{info['learn_places']} learning places for {k} embedded dimensions "
            f"({per:.1f} a dimension, fewer than {PLACES_PER_DIMENSION:g}): the "
            "embedding may not generalise; learn from more places or a smaller "
            "{opt:k}"
        )
    return notes
