"""Baselines beside a map in ``evaluate``: a representation at the map's bytes,
and brute force on a map's learned embedding.

A map is judged against what its own storage buys. :func:`at_bytes` takes the
budget ``B`` (the map's templates, codes and embedding, in bytes) and the
reference frames (m, d) brute force searches, and returns the first that fits:

- **int8 per place** (:class:`rhythmic_jax.map.scalar_codes.ScalarCodeBook`,
  faiss's 8-bit codec): ``m * d + 2 * d * 4`` bytes; cosine with the decoded
  frames;
- **PCA to k dims**, float32: the mean (d), the projection P (d, k) and the
  projected frames Y = (X - mean) P (m, k), ``4 * (d + d * k + m * k)`` bytes,
  k the largest that fits; a query's similarity to frame i is the inner product
  with its reconstruction, ``q . mean + (q P) . Y_i`` (the brute-force inner
  product, approximated).

:func:`on_embedding`: the frames and the queries embedded as the map embeds them
(:func:`rhythmic_jax.decoding.queries.queries`), cosine in the embedded space;
``m * k * 4`` bytes plus the embedding's.

Each gives a :class:`Peer`: its similarity function from raw query descriptors
(b, d) to (b, m), the one :func:`rhythmic_jax.eval.report.evaluate_map` ranks
and times, so its latency includes the encoding (the projection, the embedding).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax.jit_options import jit

__all__ = ["Peer", "at_bytes", "on_embedding", "pca_dims", "principal_axes"]

_F32 = 4


@dataclass(frozen=True)
class Peer:
    """A baseline's row: ``name`` (its label), ``storage_bytes`` (all a search
    needs), ``similarity`` (raw queries (b, d) -> (b, m) similarities to the
    reference frames, higher is closer) and ``note`` (what it is, in words)."""

    name: str
    storage_bytes: int
    similarity: Callable[[np.ndarray], jax.Array]
    note: str


def pca_dims(m: int, d: int, budget: int) -> int:
    """The largest k with ``4 * (d + d * k + m * k) <= budget`` (0: none fits),
    at most ``min(m, d)``."""
    k = (int(budget) // _F32 - int(d)) // (int(d) + int(m))
    return max(0, min(k, int(m), int(d)))


@jit
def _pca_similarity(q, mean, proj, coords) -> jax.Array:
    """``q . mean + (q P) . Y_i``: queries (b, d) -> (b, m)."""
    z = jnp.matmul(q, proj, precision="highest")
    base = jnp.matmul(q, mean, precision="highest")[:, None]
    return base + jnp.matmul(z, coords.T, precision="highest")


@jit
def _cosine(q, ref) -> jax.Array:
    q = q / jnp.maximum(jnp.linalg.norm(q, axis=1, keepdims=True), 1e-12)
    return jnp.matmul(q, ref.T, precision="highest")


def principal_axes(xc: np.ndarray, k: int) -> np.ndarray:
    """The k leading right singular vectors (d, k) float32 of centred rows xc
    (m, d): the top eigenvectors of the smaller of ``xc xc^T`` (m, m) and
    ``xc^T xc`` (d, d), in float64 (only k of them computed; one LAPACK
    thread, as on a busy machine more only wait, and a full SVD took seconds)."""
    from scipy.linalg import eigh
    from threadpoolctl import threadpool_limits

    x = np.asarray(xc, np.float64)
    m, d = x.shape
    with threadpool_limits(limits=1):
        if m < d:  # the Gram matrix: v = xc^T u / sqrt(lambda)
            lam, u = eigh(x @ x.T, subset_by_index=[m - k, m - 1])
            v = (x.T @ u[:, ::-1]) / np.sqrt(np.maximum(lam[::-1], 1e-30))[None, :]
        else:
            v = eigh(x.T @ x, subset_by_index=[d - k, d - 1])[1][:, ::-1]
    return np.ascontiguousarray(v, np.float32)


def at_bytes(reference: np.ndarray, budget: int) -> Peer | str:
    """int8 per place when its bytes fit ``budget``, else PCA to the most dims
    that fit; a string saying why when neither does. ``reference``: (m, d)."""
    from rhythmic_jax.map.scalar_codes import ScalarCodeBook, scalar_code_bytes

    reference = np.asarray(reference, np.float32)
    m, d = reference.shape
    int8 = scalar_code_bytes(m, d)["total"]
    if int8 <= budget:
        book = ScalarCodeBook.fit(reference)
        return Peer("int8/place", int8, book.similarity,
                    f"int8 per place: {m} frames x {d} bytes + the range, "
                    f"{int8:,} B <= the map's {budget:,} B")  # fmt: skip
    k = pca_dims(m, d, budget)
    if k < 1:
        return (f"no baseline at the map's {budget:,} B: int8 per place takes "
                f"{int8:,} B and PCA to 1 dim {4 * (2 * d + m):,} B")  # fmt: skip
    mean = reference.mean(axis=0)
    proj = principal_axes(reference - mean, k)  # (d, k)
    coords = (reference - mean) @ proj  # (m, k)
    size = _F32 * (d + d * k + m * k)
    args = tuple(jnp.asarray(a, jnp.float32) for a in (mean, proj, coords))

    def similarity(q):
        return _pca_similarity(jnp.asarray(q, jnp.float32), *args)

    return Peer(f"PCA {k}", size, similarity,
                f"PCA {k}: {k} of {d} dims in float32 (mean, projection and "
                f"{m} projected frames), {size:,} B <= the map's {budget:,} B; "
                f"int8 per place would take {int8:,} B")  # fmt: skip


def on_embedding(model, reference: np.ndarray) -> Peer:
    """Brute force (cosine) on the map's embedding of the frames (m, d)."""
    from rhythmic_jax.decoding.queries import queries as embedded

    ref = np.asarray(embedded(model.value, np.asarray(reference, np.float32)))
    ref = ref / np.maximum(np.linalg.norm(ref, axis=1, keepdims=True), 1e-12)
    refj = jnp.asarray(ref, jnp.float32)
    m, k = ref.shape
    size = m * k * _F32 + model.embedding_bytes

    def similarity(q):
        return _cosine(jnp.asarray(embedded(model.value, q), jnp.float32), refj)

    return Peer("embedded BF", size, similarity,
                f"embedded BF: brute force on the map's {k}-d embedding, {m} "
                f"frames x {k} float32 + the embedding, {size:,} B")  # fmt: skip
