"""Decoding by name: ``"hard"`` (the paper's), ``"soft"`` or ``"topm"``."""

from __future__ import annotations

from collections.abc import Sequence

import jax

from rhythmic_jax.decoding.group_decode import group_soft_decode, group_topm_decode
from rhythmic_jax.decoding.hard import Decoded, check_scores, hard_decode
from rhythmic_jax.decoding.soft import soft_decode, topm_decode
from rhythmic_jax.errors import InputError
from rhythmic_jax.map.config import DECODERS
from rhythmic_jax.map.groups import Groups

__all__ = ["DECODERS", "decode_scores"]


def decode_scores(
    scores: jax.Array,
    periods: Sequence[int] | Groups,
    n: int,
    method: str = "hard",
    top: int = 3,
) -> Decoded:
    """Decode (..., p) decision values with ``method`` in ``"hard" | "soft" | "topm"``.

    ``topm`` keeps the ``top`` best phases of every period (see
    :func:`rhythmic_jax.decoding.soft.topm_decode`). Every field of the result has the
    scores' leading shape. ``periods`` may be a map's
    :class:`~rhythmic_jax.map.groups.Groups`: mixed-radix and hierarchical layouts
    decode in the place domain (:mod:`rhythmic_jax.decoding.group_decode`).
    """
    if method not in DECODERS:
        raise InputError(f"unknown decode method {method!r}; choose one of {DECODERS}")
    if isinstance(periods, Groups) and periods.kind != "periods":
        if method == "soft":
            return group_soft_decode(scores, periods, n)
        if method == "topm":
            return group_topm_decode(scores, periods, n, top)
        return hard_decode(scores, periods, n)
    periods, n = check_scores(scores, getattr(periods, "sizes", periods), n)
    if method == "soft":
        return soft_decode(scores, periods, n)
    if method == "topm":
        return topm_decode(scores, periods, n, top)
    return hard_decode(scores, periods, n)
