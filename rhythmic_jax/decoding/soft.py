"""Soft and top-m decoding: score every place by its summed phase scores.

The paper localises a query by the argmax phase of every period and the Chinese
remainder intersection of those phases (Sec. III-B, Eq. 5); one wrong argmax in any
period gives a wrong place. Soft decoding keeps every phase score and scores place
``i < n`` by

    S(i) = sum_g s_g[i mod tau_g],

returning ``argmax_i S(i)``: ``r * n`` gathers per query and no descriptor access.
After :func:`calibrate` (a log-softmax over the phases of each period) ``S(i)`` is
a sum of per-period log-likelihoods, so periods with flat scores weigh less.
``S`` is separable over periods, so when every phase combination is a place
(``n = prod(tau)``) its argmax is the per-period argmax: the soft index then equals
the hard one. It differs, and rescues queries, when the hard combination falls at
or beyond ``n`` (a "no match" of the paper), and it gives a runner-up score.

Top-m decoding scores only the places whose phase is among the ``top`` best of every
period: the ``prod_g min(top, tau_g)`` Chinese-remainder combinations (index
``(sum_g T_g[j_g]) mod M`` with the tables of
:func:`rhythmic_jax.map.periods.crt_tables`),
combinations with index ``>= n`` dropped. ``top = 1`` is the paper's hard decode
(no match when the argmax combination is ``>= n``); ``top >= max(tau)`` is exactly the
soft decode (same sums in the same order, ties to the smaller index).

Both return the best score and the runner-up: the best score among the other places
(with ``exclude = e``, among places more than ``e`` frames from the best one, so that
neighbours of the match, which look alike along a route, do not count as rivals).
Top-m seeks the runner-up among the combinations of the ``max(top, 2)`` best
phases, so that ``top = 1`` (one candidate) still measures its answer against
the combinations one phase away (places or not, as the hard decode: its
confidence is the weakest phase margin). ``confidence = best - runner_up``
(:func:`rhythmic_jax.decoding.hard.confidence`: finite; ``0`` for no match and
for an answer without a rival). A query whose scores are not finite is no match.

Shapes: ``b`` queries, ``p = sum(periods)`` scores per query, ``n`` places.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax.decoding.hard import Decoded, check_scores
from rhythmic_jax.errors import InputError
from rhythmic_jax.jit_options import jit
from rhythmic_jax.map.groups import Groups
from rhythmic_jax.map.periods import crt_tables, period_offsets, place_columns
from rhythmic_jax.validate import check_int

__all__ = ["calibrate", "chosen", "soft_decode", "topm_combinations", "topm_decode"]

_INT32_SAFE = 2**30  # running CRT sums stay below 2 M < 2**31


def calibrate(scores: jax.Array, periods: Sequence[int] | Groups) -> jax.Array:
    """Per-period log-softmax over phases: (..., p) -> (..., p).

    ``c_g[j] = s_g[j] - log sum_j' exp(s_g[j'])``, so ``sum_g c_g[i mod tau_g]`` is a
    sum of log-probabilities. Argmaxes (the hard decode) are unchanged. With a
    :class:`~rhythmic_jax.map.groups.Groups` the softmax runs over every group's
    classes.
    """
    if isinstance(periods, Groups) and periods.kind != "periods":
        per = periods.sizes
        if getattr(scores, "shape", (0,))[-1:] != (periods.p,):
            raise InputError(
                f"scores must have shape (..., {periods.p}) for "
                f"{periods.describe()}, got {np.shape(scores)}"
            )
    else:
        per, _ = check_scores(scores, getattr(periods, "sizes", periods))
    blocks = jnp.split(jnp.asarray(scores), np.cumsum(per)[:-1].tolist(), axis=-1)
    return jnp.concatenate([jax.nn.log_softmax(b, axis=-1) for b in blocks], axis=-1)


def _best_two(
    score: jax.Array,
    index: jax.Array,
    valid: jax.Array,
    exclude: int,
    rivals: jax.Array | None = None,
) -> Decoded:
    """Best valid candidate (ties to the smaller index) and its best rival.

    score, index, valid: (c,) candidates of one query; ``rivals`` (c,) the
    candidates the runner-up is sought among (default: ``valid``). No match
    (-1) when no candidate is valid or the best score is not finite.
    """
    neg = jnp.asarray(-jnp.inf, score.dtype)
    masked = jnp.where(valid, score, neg)
    best = jnp.max(masked)
    big = jnp.iinfo(jnp.int32).max
    top = jnp.min(jnp.where(valid & (masked == best), index, big))
    found = jnp.any(valid) & jnp.isfinite(best)
    top = jnp.where(found, top, -1).astype(jnp.int32)
    rival = (valid if rivals is None else rivals) & (jnp.abs(index - top) > exclude)
    runner = jnp.where(found, jnp.max(jnp.where(rival, score, neg)), neg)
    return Decoded(top, jnp.where(found, best, neg), runner)


def _soft_one(s: jax.Array, periods: tuple[int, ...], n: int, exclude: int) -> Decoded:
    """One query: s (p,) -> scalars."""
    cols = place_columns(periods, n)
    total = s[cols[0]]
    for c in cols[1:]:
        total = total + s[c]
    index = jnp.arange(n, dtype=jnp.int32)
    return _best_two(total, index, jnp.ones((n,), bool), exclude)


def topm_combinations(
    s: jax.Array, periods: tuple[int, ...], top: int
) -> tuple[jax.Array, jax.Array]:
    """The top-m phase combinations of one query: s (p,) -> (score (c,), index (c,)).

    Every combination of the ``min(top, tau_g)`` best phases of each period,
    ``c = prod_g min(top, tau_g)`` of them, the last period varying fastest:
    ``score`` the sum of their phase scores (in the scores' dtype, periods added
    in order) and ``index`` its Chinese-remainder place ``(sum_g T_g[j_g]) mod
    M`` (int32, below ``M = prod(periods)``; at or beyond n: no place). Needs
    ``M < 2**30``.
    """
    tables, big_m = crt_tables(periods)
    score = index = None
    for off, t, table in zip(period_offsets(periods), periods, tables, strict=True):
        val, phase = jax.lax.top_k(s[off : off + t], min(top, t))
        part = jnp.asarray(table.astype(np.int32))[phase]
        if score is None:
            score, index = val, part
        else:
            score = (score[:, None] + val[None, :]).reshape(-1)
            index = ((index[:, None] + part[None, :]) % big_m).reshape(-1)
    return score, index


def chosen(periods: tuple[int, ...], top: int, wide: int) -> np.ndarray:
    """Which of :func:`topm_combinations` ``(s, periods, wide)``'s combinations
    (c,) bool, in its order, are combinations of the ``top <= wide`` best phases
    of every period (all of them when ``top == wide``)."""
    keep = np.ones((1,), bool)
    for t in periods:
        rank = np.arange(min(wide, t)) < top
        keep = (keep[:, None] & rank[None, :]).reshape(-1)
    return keep


def _topm_one(
    s: jax.Array, periods: tuple[int, ...], n: int, top: int, exclude: int
) -> Decoded:
    """One query: s (p,) -> scalars, the best of prod_g min(top, tau_g)
    combinations, its rival among those of the max(top, 2) best phases (for
    ``top = 1``, as the hard decode: every combination one phase away, a place
    or not, so that the confidence is the weakest phase margin)."""
    wide = max(top, 2)
    score, index = topm_combinations(s, periods, wide)
    valid = index < n
    if top > 1:  # every combination is a candidate
        return _best_two(score, index, valid, exclude)
    mask = valid & jnp.asarray(chosen(periods, top, wide))
    return _best_two(score, index, mask, exclude, rivals=jnp.ones_like(valid))


def _batched(one, scores: jax.Array, batch_size: int, **static) -> Decoded:
    """Apply a one-query decoder to scores (..., p), in batches of ``batch_size``."""
    lead = scores.shape[:-1]
    flat = scores.reshape((-1, scores.shape[-1]))
    out = jax.lax.map(
        functools.partial(one, **static), flat, batch_size=min(batch_size, len(flat))
    )
    return Decoded(*(x.reshape(lead) for x in out))


@functools.partial(jit, static_argnames=("periods", "n", "exclude", "batch_size"))
def _soft_jit(scores, periods, n, exclude, batch_size):
    return _batched(
        _soft_one, scores, batch_size, periods=periods, n=n, exclude=exclude
    )


@functools.partial(
    jit, static_argnames=("periods", "n", "top", "exclude", "batch_size")
)
def _topm_jit(scores, periods, n, top, exclude, batch_size):
    return _batched(
        _topm_one, scores, batch_size, periods=periods, n=n, top=top, exclude=exclude
    )


def _empty(lead: tuple[int, ...], dtype) -> Decoded:
    neg = jnp.full(lead, -jnp.inf, dtype)
    return Decoded(jnp.full(lead, -1, jnp.int32), neg, neg)


def soft_decode(
    scores: jax.Array,
    periods: Sequence[int],
    n: int,
    *,
    exclude: int = 0,
    batch_size: int = 256,
) -> Decoded:
    """Exact score-sum decode of b queries: scores (..., p) -> Decoded with shape (...).

    ``index = argmax_{i < n} sum_g s_g[i mod tau_g]`` (ties to the smaller index);
    ``runner_up`` is the best score of a place more than ``exclude`` frames away
    (``exclude = 0``: plain second best). Jit-compiled once per (periods, n,
    exclude) and shape; ``batch_size`` queries are scored at a time, so memory is
    ``O(batch_size * n)``.
    """
    per, n = check_scores(scores, periods, n)
    exclude = check_int(exclude, "exclude", 0)
    batch_size = check_int(batch_size, "batch_size", 1)
    scores = jnp.asarray(scores)
    if math.prod(scores.shape[:-1]) == 0:
        return _empty(scores.shape[:-1], scores.dtype)
    return _soft_jit(scores, per, n, exclude, batch_size)


def topm_decode(
    scores: jax.Array,
    periods: Sequence[int],
    n: int,
    top: int,
    *,
    exclude: int = 0,
    batch_size: int = 256,
) -> Decoded:
    """Top-m Chinese-remainder decode: scores (..., p) -> Decoded with shape (...).

    Scores the ``prod_g min(top, tau_g)`` places whose phases are among the ``top`` best
    of every period and keeps the best one below ``n`` (index -1 and score -inf when
    every combination is ``>= n``); the runner-up is the best other place among
    the combinations of the ``max(top, 2)`` best phases. ``top = 1`` is the
    paper's hard decode; ``top >= max(periods)`` equals :func:`soft_decode`
    exactly. Cost per query ``top ** r``
    instead of ``n``. Needs ``prod(periods) < 2**30`` (int32 index arithmetic).
    """
    per, n = check_scores(scores, periods, n)
    top = check_int(top, "top", 1)
    exclude = check_int(exclude, "exclude", 0)
    batch_size = check_int(batch_size, "batch_size", 1)
    if math.prod(per) >= _INT32_SAFE:
        raise InputError(
            f"prod(periods)={math.prod(per)} is too large for top-m decoding "
            f"(must be < 2**30)"
        )
    scores = jnp.asarray(scores)
    if math.prod(scores.shape[:-1]) == 0:
        return _empty(scores.shape[:-1], scores.dtype)
    return _topm_jit(scores, per, n, top, exclude, batch_size)
