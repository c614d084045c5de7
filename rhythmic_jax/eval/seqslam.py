"""SeqSLAM-style sequence matching on full descriptors: the baseline to compare with.

This is not the map's method (it keeps every descriptor); it is the reference that
:mod:`rhythmic_jax.decoding.sequence` is measured against (Milford & Wyeth, "SeqSLAM",
ICRA 2012; the paper's named future work). With L2-normalised queries ``Q`` (T, d)
and references ``X`` (N, d):

    S = Q X^T                                          (T, N) cosine similarities
    S~[t, i] = (S[t, i] - mu_w(t, i)) / sigma_w(t, i)  optional contrast enhancement
    D[t, i] = sum_{l=0}^{L-1} S~[t - l, i - o_l],      o_l = round(l * v)
    index[t] = argmax_i max_v D_v[t, i]

``mu_w, sigma_w`` are the mean and standard deviation of ``S[t, j]`` over the
references ``|j - i| <= w // 2`` (clipped at the ends of the map): SeqSLAM's local
patch normalisation of the difference matrix along the reference axis (the sign
flips between differences and similarities; the argmax is the same). Terms with
``t - l < 0`` or ``i - o_l`` outside ``[0, N)`` contribute 0, so the window ends at
``t`` (causal, as an online robot would run it). Queries are processed in chunks of
``chunk`` rows: memory ``O((chunk + L) * N)`` besides the descriptors.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax.decoding.sequence import frame_offsets
from rhythmic_jax.errors import InputError
from rhythmic_jax.jit_options import jit
from rhythmic_jax.progress import bar
from rhythmic_jax.validate import check_int

__all__ = [
    "enhance_contrast",
    "normalise_rows",
    "seqslam_decode",
    "sequence_similarity",
    "similarity",
]

_EPS = 1e-6


@jit
def normalise_rows(a: jax.Array) -> jax.Array:
    """Rows scaled to unit L2 norm (zero rows stay zero): (m, d) -> (m, d)."""
    a = jnp.asarray(a)
    norm = jnp.linalg.norm(a, axis=-1, keepdims=True)
    return a / jnp.maximum(norm, _EPS)


@jit
def similarity(queries: jax.Array, references: jax.Array) -> jax.Array:
    """Cosine similarity matrix: queries (T, d), references (N, d) -> S (T, N)."""
    return jnp.matmul(
        normalise_rows(queries), normalise_rows(references).T, precision="highest"
    )


@functools.partial(jit, static_argnames=("window",))
def enhance_contrast(sim: jax.Array, window: int) -> jax.Array:
    """Local contrast along the reference axis: S (T, N) -> (S - mu) / sigma (T, N).

    ``mu[t, i]``, ``sigma[t, i]``: mean and (population) standard deviation of
    ``S[t, j]`` for ``|j - i| <= window // 2``, ``0 <= j < N``; sigma floored at 1e-6.
    """
    half = int(window) // 2
    n = sim.shape[-1]
    i = np.arange(n)
    count = (np.minimum(i + half, n - 1) - np.maximum(i - half, 0) + 1).astype(
        np.float32
    )

    def window_sum(x):
        return jax.lax.reduce_window(
            x,
            jnp.zeros((), x.dtype),
            jax.lax.add,
            (1, 2 * half + 1),
            (1, 1),
            ((0, 0), (half, half)),
        )

    mean = window_sum(sim) / count[None, :]
    var = jnp.maximum(window_sum(sim * sim) / count[None, :] - mean * mean, 0.0)
    return (sim - mean) / jnp.maximum(jnp.sqrt(var), _EPS)


def _diagonal_sums(ext: jax.Array, length: int, speed: float) -> jax.Array:
    """ext (L - 1 + c, N) with L - 1 earlier rows on top -> D (c, N).

    ``D[t, i] = sum_l ext[L - 1 + t - l, i - o_l]``, zero outside the columns.
    """
    rows, n = ext.shape
    c = rows - (length - 1)
    offs = frame_offsets(length, speed)
    left, right = max(0, max(offs)), max(0, -min(offs))
    padded = jnp.pad(ext, ((0, 0), (left, right)))
    out = jnp.zeros((c, n), ext.dtype)
    for step, o in enumerate(offs):
        r0, c0 = length - 1 - step, left - o
        out = out + padded[r0 : r0 + c, c0 : c0 + n]
    return out


def sequence_similarity(sim: jax.Array, length: int, speed: float = 1.0) -> jax.Array:
    """Diagonal sums of a full similarity matrix: S (T, N) -> D (T, N).

    ``D[t, i] = sum_{l=0}^{L-1} S[t - l, i - round(l * speed)]``, out-of-range terms
    0. Builds (T, N) arrays: use :func:`seqslam_decode` for large inputs.
    """
    length = _check_positive(length, "length")
    return _sequence_similarity(sim, length, float(speed))


@functools.partial(jit, static_argnames=("length", "speed"))
def _sequence_similarity(sim: jax.Array, length: int, speed: float) -> jax.Array:
    """:func:`sequence_similarity` once checked, one program."""
    sim = jnp.asarray(sim)
    ext = jnp.concatenate([jnp.zeros((length - 1, sim.shape[1]), sim.dtype), sim])
    return _diagonal_sums(ext, length, speed)


@functools.partial(jit, static_argnames=("length", "speeds", "window", "chunk"))
def _chunk_jit(queries, valid, references, start, length, speeds, window, chunk):
    """Best reference and score for query rows [start, start + chunk) of the padding."""
    rows = length - 1 + chunk
    q = jax.lax.dynamic_slice_in_dim(queries, start, rows, axis=0)
    ok = jax.lax.dynamic_slice_in_dim(valid, start, rows, axis=0)
    sim = jnp.matmul(q, references.T, precision="highest")
    if window is not None:
        sim = enhance_contrast(sim, window)
    sim = jnp.where(ok[:, None], sim, 0.0)
    best_score = best_index = None
    for v in speeds:
        d = _diagonal_sums(sim, length, v)
        score, index = jnp.max(d, axis=1), jnp.argmax(d, axis=1).astype(jnp.int32)
        if best_score is None:
            best_score, best_index = score, index
        else:
            better = score > best_score
            best_score = jnp.where(better, score, best_score)
            best_index = jnp.where(better, index, best_index)
    return best_index, best_score


def _check_positive(value: int, name: str) -> int:
    return check_int(value, name, 1)


def seqslam_decode(
    queries: jax.Array,
    references: jax.Array,
    length: int = 10,
    speeds: Sequence[float] = (1.0,),
    *,
    contrast_window: int | None = None,
    chunk: int = 256,
    progress: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """SeqSLAM match of every query frame: Q (T, d), X (N, d) -> index (T,), score (T,).

    ``index[t] = argmax_i max_v sum_l S~[t - l, i - round(l v)]`` (first speed and
    smallest ``i`` on ties); ``score`` is that maximum. ``contrast_window`` (e.g. 10)
    turns on the local contrast enhancement; ``chunk`` queries are scored at a time.
    """
    q = queries if isinstance(queries, jax.Array) else np.asarray(queries)
    x = references if isinstance(references, jax.Array) else np.asarray(references)
    if q.ndim != 2 or x.ndim != 2 or q.shape[1] != x.shape[1]:
        raise InputError(
            f"queries (T, d) and references (N, d) must share d, got {q.shape} and "
            f"{x.shape}"
        )
    if x.shape[0] == 0:
        raise InputError("references must hold at least one descriptor (N >= 1)")
    length = _check_positive(length, "length")
    chunk = _check_positive(chunk, "chunk")
    if contrast_window is not None:
        contrast_window = _check_positive(contrast_window, "contrast_window")
    if isinstance(speeds, int | float):
        speeds = (speeds,)
    speeds = tuple(float(v) for v in speeds)
    if not speeds or not all(math.isfinite(v) for v in speeds):
        raise InputError(
            f"speeds must be a non-empty sequence of finite numbers: {speeds}"
        )
    frames = q.shape[0]
    if frames == 0:
        return np.zeros((0,), np.int32), np.zeros((0,), np.float32)
    chunk = min(chunk, frames)
    total = math.ceil(frames / chunk) * chunk
    # the padded queries and their mask on the host; normalised in one program
    valid = np.zeros(length - 1 + total, bool)
    valid[length - 1 : length - 1 + frames] = True
    qpad, xn = _prepare(q, x, length - 1, total - frames)
    valid = jax.device_put(valid)
    indices, scores = [], []
    starts = range(0, total, chunk)
    for start in bar(starts, show=progress, desc="seqslam"):
        i, s = _chunk_jit(
            qpad, valid, xn, start, length, speeds, contrast_window, chunk
        )
        indices.append(i)
        scores.append(s)
    # numpy: joining the chunks compiles nothing
    index = np.concatenate([np.asarray(i) for i in indices])[:frames]
    return index, np.concatenate([np.asarray(v) for v in scores])[:frames]


@functools.partial(jit, static_argnames=("before", "after"))
def _prepare(q, x, before: int, after: int):
    """Unit rows of queries (T, d), padded with ``before`` zero rows on top and
    ``after`` below, and of references (N, d), in their common float dtype."""
    dtype = jnp.result_type(q.dtype, x.dtype, jnp.float32)
    qn = normalise_rows(q.astype(dtype))
    return jnp.pad(qn, ((before, after), (0, 0))), normalise_rows(x.astype(dtype))
