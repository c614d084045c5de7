"""What a fitted map costs in bytes, by part.

A map stores its templates, ``size + 1`` numbers of ``k`` dims per class of each
group in its dtype (:func:`rhythmic_jax.map.quantize.template_bytes`; ``k`` the
templates' dimension: an embedding's output, else the input ``d``); with codes a
fixed part (the code transform) and a part per place (the codes); an embedding's
parameters are counted apart (they do not grow with ``n``). ``share`` sets
everything against the ``n x d`` float32 database
(:func:`rhythmic_jax.map.periods.database_bytes`).
"""

from __future__ import annotations

from typing import Any

from rhythmic_jax.map.periods import database_bytes
from rhythmic_jax.map.quantize import template_bytes

__all__ = ["map_storage"]


def map_storage(
    kind: str,
    sizes: tuple[int, ...],
    k: int,
    dtype: str,
    n: int,
    d: int,
    codes: dict[str, int] | None = None,
    embedding: int = 0,
) -> dict[str, Any]:
    """Bytes of a map of groups ``sizes`` (a layout of ``kind``) over k-dim
    templates stored as ``dtype``, for ``n`` places of d features.

    ``codes``: the code book's ``{"fixed", "per_place"}`` bytes (None without
    codes); ``embedding``: the embedding's bytes. Returns ``fixed``,
    ``per_place``, ``per_period`` (by period, or ``"group:size"`` for other
    layouts), ``embedding``, ``total`` (all but the embedding) and ``share``
    (everything over ``n * d * 4``).
    """
    codes = codes or {}
    per_period = {
        (str(t) if kind == "periods" else f"{g}:{t}"): template_bytes(t, k, dtype)
        for g, t in enumerate(sizes)
    }
    fixed, per_place = codes.get("fixed", 0), codes.get("per_place", 0)
    total = fixed + per_place + sum(per_period.values())
    return {
        "fixed": fixed,
        "per_place": per_place,
        "per_period": per_period,
        "embedding": embedding,
        "total": total,
        "share": (total + embedding) / database_bytes(n, d, 4),
    }
