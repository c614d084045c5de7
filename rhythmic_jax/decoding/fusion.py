"""A hybrid decode: a map's place scores fused with binary-code similarities.

A map scores place ``i`` by ``S(i) = sum_g s_g[i mod tau_g]``
(:mod:`rhythmic_jax.decoding.soft`); a code per place (:mod:`rhythmic_jax.map.codes`)
scores it by ``C(i)``, the bits the query's code shares with place i's. The two live
on different scales, so each is standardised over the places of the query and
the fused score is

    F(i) = w z(S)(i) + (1 - w) z(C)(i),      z(v) = (v - mean v) / std v,

with ``w`` in [0, 1] the map's share (``w = 1``: the map alone, ``w = 0``: the codes
alone; both give the same argmax as their part). ``w`` is settled on places that
are never scored (:func:`learn_weight`: training places, or a fixed 0.5).

Top-m keeps the ``prod_g min(top, tau_g)`` places of the map's best phase
combinations and, when ``w < 1``, as many places of the highest code similarity;
the map part is standardised with the moments over every phase combination,
``mean S = sum_g mean s_g`` and ``var S = sum_g var s_g`` (exact when ``n =
prod tau``), so no place outside the candidates is scored by the map.

Sequences: the map's scores are summed along the diagonal in the phase domain
(:mod:`rhythmic_jax.decoding.sequence`), the codes' standardised similarities in
the place domain, ``A(t, i) = sum_l z(C^{t-l})(i - o_l)`` (places off the route count 0,
the mean of a standardised frame); the two sums are then fused as above.

Shapes: ``b`` queries (``T`` frames of a sequence), ``p = sum(periods)``, ``n``
places.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax.decoding.buckets import head, in_host_memory, pad_rows
from rhythmic_jax.decoding.hard import Decoded, check_scores
from rhythmic_jax.decoding.sequence import _sequence_scores_jit, frame_offsets
from rhythmic_jax.decoding.soft import _best_two, chosen, topm_combinations
from rhythmic_jax.errors import InputError
from rhythmic_jax.jit_options import jit
from rhythmic_jax.map.config import check_weight
from rhythmic_jax.map.periods import period_offsets, place_columns

__all__ = [
    "check_weight",
    "code_sequence_scores",
    "fused_decode",
    "fused_place_scores",
    "fused_sequence_decode",
    "learn_weight",
]

_EPS = 1e-12


def _z(v: jax.Array, mean, std) -> jax.Array:
    return (v - mean) / jnp.maximum(std, _EPS)


def _zrow(v: jax.Array) -> jax.Array:
    return _z(
        v, jnp.mean(v, axis=-1, keepdims=True), jnp.std(v, axis=-1, keepdims=True)
    )


def _place_sum(s: jax.Array, periods: tuple[int, ...], n: int) -> jax.Array:
    """(..., p) phase scores -> (..., n) place scores ``sum_g s_g[i mod tau_g]``."""
    cols = place_columns(periods, n)
    total = s[..., cols[0]]
    for c in cols[1:]:
        total = total + s[..., c]
    return total


def _soft_one(s, sim, weight, periods, n, exclude) -> Decoded:
    """One query: phase scores s (p,), code similarities sim (n,) -> scalars."""
    total = weight * _zrow(_place_sum(s, periods, n)) + (1 - weight) * _zrow(sim)
    return _best_two(
        total, jnp.arange(n, dtype=jnp.int32), jnp.ones((n,), bool), exclude
    )


def _topm_one(s, sim, weight, periods, n, top, codes, exclude) -> Decoded:
    """One query, over the map's top-m places (and the codes' best when codes);
    the runner-up among the candidates of ``max(top, 2)`` (so that the hard
    decode, ``top = 1``, has rivals to measure its answer against)."""
    wide = max(top, 2)
    keep = chosen(periods, top, wide)
    score, index = topm_combinations(s, periods, wide)
    mean_s = var_s = 0.0
    for off, t in zip(period_offsets(periods), periods, strict=True):
        block = s[off : off + t]
        mean_s, var_s = mean_s + jnp.mean(block), var_s + jnp.var(block)
    std_s = jnp.sqrt(var_s)
    mu, sd = jnp.mean(sim), jnp.std(sim)
    valid = index < n
    mask = valid if top == wide else valid & jnp.asarray(keep)
    fused = weight * _z(score, mean_s, std_s)
    if codes:  # static: w < 1
        fused = fused + (1 - weight) * _z(sim[jnp.minimum(index, n - 1)], mu, sd)
        val, idx = jax.lax.top_k(sim, min(len(index), n))
        cols = place_columns(periods, n)
        s_idx = sum(s[jnp.asarray(c)[idx]] for c in cols)
        extra = weight * _z(s_idx, mean_s, std_s) + (1 - weight) * _z(val, mu, sd)
        fused = jnp.concatenate([fused, extra])
        index = jnp.concatenate([index, idx.astype(index.dtype)])
        valid = jnp.concatenate([valid, jnp.ones(idx.shape, bool)])
        # the answer among as many best-code places as top-m combinations
        first = np.arange(len(idx)) < min(int(keep.sum()), n)
        mask = jnp.concatenate([mask, jnp.asarray(first)])
    if top == wide:  # every candidate may answer
        return _best_two(fused, index, valid, exclude)
    return _best_two(fused, index, mask, exclude, rivals=valid)


def _batched(one, s, sim, weight, batch_size, **static) -> Decoded:
    return jax.lax.map(
        lambda a: functools.partial(one, **static)(*a, weight),
        (s, sim),
        batch_size=min(batch_size, len(s)),
    )


@functools.partial(
    jit,
    static_argnames=("periods", "n", "method", "top", "codes", "exclude", "batch"),
)
def _fused_jit(s, sim, weight, periods, n, method, top, codes, exclude, batch):
    if method == "soft":
        return _batched(
            _soft_one, s, sim, weight, batch,
            periods=periods, n=n, exclude=exclude,
        )  # fmt: skip
    return _batched(
        _topm_one, s, sim, weight, batch,
        periods=periods, n=n, top=top, codes=codes, exclude=exclude,
    )  # fmt: skip


def _check(scores, sims, periods, n, method, top, weight, exclude):
    per, n = check_scores(scores, periods, n)
    if in_host_memory(scores) is not None or not isinstance(scores, jax.Array):
        scores = np.asarray(scores)  # kept on the host: padded there
    else:
        scores = jnp.asarray(scores)
    if in_host_memory(sims) is not None or not isinstance(sims, jax.Array):
        sims = np.asarray(sims, np.float32)
    else:
        sims = jnp.asarray(sims, jnp.float32)
    if scores.ndim != 2 or sims.shape != (scores.shape[0], n):
        raise InputError(
            f"fusion needs map scores (b, p) and code similarities (b, n={n}), got "
            f"{scores.shape} and {sims.shape}"
        )
    if method not in ("soft", "topm", "hard"):
        raise InputError(f"method must be soft, topm or hard, got {method!r}")
    if method == "hard":  # the argmax combination: top-m with top = 1
        method, top = "topm", 1
    for name, value, low in (("top", top, 1), ("exclude", exclude, 0)):
        if isinstance(value, bool) or not isinstance(value, int | np.integer):
            raise InputError(f"{name} must be an integer >= {low}, got {value!r}")
        if value < low:
            raise InputError(f"{name} must be an integer >= {low}, got {value!r}")
    if method == "topm" and math.prod(per) >= 2**30:
        raise InputError(f"prod(periods)={math.prod(per)} too large for top-m")
    return scores, sims, per, n, method, int(top), check_weight(weight), int(exclude)


def fused_decode(
    scores,
    sims,
    periods: Sequence[int],
    n: int,
    weight: float = 0.5,
    method: str = "soft",
    top: int = 3,
    *,
    exclude: int = 0,
    batch_size: int = 256,
) -> Decoded:
    """Decode b queries from map scores (b, p) and code similarities (b, n).

    ``method``: "soft" (every place), "topm" (the map's combinations of the ``top``
    best phases of every period and as many best-code places) or "hard" (top-m
    with ``top = 1``). Returns
    :class:`~rhythmic_jax.decoding.hard.Decoded` whose scores are fused z-scores;
    its confidence (:func:`rhythmic_jax.decoding.hard.confidence`) is the
    answer's fused score minus the best rival's, in z-score units, the rival
    sought among the candidates of ``max(top, 2)`` (finite; 0 for no match).
    Jit-compiled once per (periods, n, method, top, weight, exclude) and bucket
    of rows (:func:`~rhythmic_jax.decoding.buckets.bucket`: the rows are padded
    where they lie, host inputs on the host, and the results cut where they
    were computed); ``batch_size`` queries are fused at a time, so the program
    holds ``batch_size x n`` fused scores.
    """
    s, sim, per, n, method, top, weight, exclude = _check(
        scores, sims, periods, n, method, top, weight, exclude
    )
    if s.shape[0] == 0:
        neg = jnp.zeros((0,), s.dtype)
        return Decoded(jnp.zeros((0,), jnp.int32), neg, neg)
    w = jnp.float32(weight)
    batch = int(batch_size)
    (s, sim), b = _bucketed(s, sim)
    codes = isinstance(weight, jax.core.Tracer) or weight < 1  # traced: both terms
    out = _fused_jit(s, sim, w, per, n, method, top, codes, exclude, batch)
    return head(out, b)


def _bucketed(*arrays):
    """Arrays (b, ...) padded to :func:`~rhythmic_jax.decoding.buckets.bucket`
    ``(b)`` rows (on the host where they lie there) as device arrays (a numpy
    argument would key a program apart from a device array), and b."""
    out = [pad_rows(a) for a in arrays]
    b = out[0][1]
    return [
        a if isinstance(a, jax.core.Tracer) else jax.device_put(a) for a, _ in out
    ], b


@jit
def _fused_scores_jit(place, sims, weight):
    return weight * _zrow(place) + (1 - weight) * _zrow(sims)


def fused_place_scores(scores, sims, periods, n: int, weight: float = 0.5):
    """Fused score of every place: (b, p), (b, n) -> (b, n) (for ranking top K).

    ``sims = None``: the map's own place scores ``sum_g s_g[i mod tau_g]``.
    """
    if sims is None:
        per, n = check_scores(scores, periods, n)
        return _place_sum_jit(jnp.asarray(scores), per, n)
    s, sim, per, n, *_ = _check(scores, sims, periods, n, "soft", 1, weight, 0)
    place = _place_sum_jit(s, per, n)
    return _fused_scores_jit(place, sim, jnp.float32(check_weight(weight)))


_place_sum_jit = jit(_place_sum, static_argnums=(1, 2))


@functools.partial(jit, static_argnames=("length", "speed"))
def _code_seq_jit(sims, length, speed):
    frames, n = sims.shape
    offs = frame_offsets(length, speed)
    pad = max(abs(o) for o in offs)
    z = jnp.pad(_zrow(sims), ((length - 1, 0), (pad, pad)))
    acc = jnp.zeros_like(sims)
    for step, o in enumerate(offs):
        row0 = length - 1 - step
        acc = acc + z[row0 : row0 + frames, pad - o : pad - o + n]
    return acc


def code_sequence_scores(sims, length: int, speed: float = 1.0) -> jax.Array:
    """Code similarities of T consecutive frames (T, n) summed along the diagonal.

    ``A(t, i) = sum_{l < L, l <= t} z(C^{t-l})(i - o_l)``, ``o_l = round(l v)``,
    places ``i - o_l`` off the route adding 0. Returns (T, n).
    """
    sims = jnp.asarray(sims, jnp.float32)
    if sims.ndim != 2 or isinstance(length, bool) or int(length) != length:
        raise InputError(f"need sims (T, n) and an integer length, got {sims.shape}")
    if length < 1:
        raise InputError(f"length must be >= 1, got {length}")
    return _code_seq_jit(sims, int(length), float(speed))


def fused_sequence_decode(
    scores,
    sims,
    periods: Sequence[int],
    n: int,
    length: int,
    speeds: Sequence[float] = (1.0,),
    weight: float = 0.5,
    method: str = "soft",
    top: int = 3,
    *,
    exclude: int = 0,
) -> tuple[jax.Array, jax.Array]:
    """Sequence decode of T consecutive frames: (T, p), (T, n) -> index, confidence.

    Per speed, the map's scores are accumulated in the phase domain and the codes'
    in the place domain, then fused and decoded; per frame the speed with the best
    fused score wins. ``weight = 1`` equals
    :func:`rhythmic_jax.decoding.sequence.sequence_decode` (same method).
    """
    s, sim, per, n, method, top, weight, exclude = _check(
        scores, sims, periods, n, method, top, weight, exclude
    )
    out = []
    for v in speeds:
        # jitted (once per bucket): an eager loop traces a new body every call
        acc = _sequence_scores_jit(s, per, int(length), float(v))
        out.append(
            fused_decode(
                acc,
                code_sequence_scores(sim, length, v),
                per,
                n,
                weight,
                method,
                top,
                exclude=exclude,
            )  # fmt: skip
        )
    stacked = Decoded(*(jnp.stack(x) for x in zip(*out, strict=True)))
    pick = jnp.argmax(stacked.score, axis=0)[None, :]
    best = Decoded(*(jnp.take_along_axis(x, pick, axis=0)[0] for x in stacked))
    return best.index, best.confidence


def learn_weight(
    scores,
    sims,
    periods: Sequence[int],
    n: int,
    gt,
    tolerance: int = 1,
    grid: Sequence[float] = tuple(np.linspace(0.0, 1.0, 21)),
    length: int | None = None,
) -> tuple[float, dict[float, float]]:
    """The map's share ``w`` with the best recall@1 on labelled queries.

    Call it on places that are never scored (a training segment's map, codes and
    queries). ``gt`` (b,) true places; ``length``: tune for sequences of that
    length instead of single frames. Ties go to the ``w`` nearest 0.5. Returns
    ``(w, {w: recall@1})``.
    """
    gt = np.asarray(gt)
    table = {}
    for w in grid:
        w = round(float(w), 6)
        if length and length > 1:
            idx, _ = fused_sequence_decode(scores, sims, periods, n, length, weight=w)
        else:
            idx = fused_decode(scores, sims, periods, n, w).index
        idx = np.asarray(idx)
        table[w] = float(np.mean((idx >= 0) & (np.abs(idx - gt) <= tolerance)))
    best = max(table.values())
    w = min((w for w, r in table.items() if r == best), key=lambda w: abs(w - 0.5))
    return w, table
