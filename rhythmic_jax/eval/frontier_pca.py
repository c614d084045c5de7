"""PCA, the field's usual compression baseline, as rows of the frontier.

The reference descriptors x (n, d) are centred on their mean mu (d,) and
projected on their k leading principal axes P (d, k) (the right singular
vectors of x - mu); a place keeps z = (x - mu) P, as float32 or as int8 (per
dimension j, ``round(255 (z_j - lo_j) / (hi_j - lo_j))`` with the (k,) float32
lo and range kept). A query q is projected the same way and scored by the inner
product of its projection with every place's (dequantised) one, the exact
inner product of the centred descriptors within the k axes kept. The bytes
count everything a search reads: ``(d k + d) 4`` for P and mu, ``n k 4`` (or
``n k + 2 k 4`` at int8) for the places.

:func:`pca_dims` picks the k whose bytes span a byte range (the maps', so the
baseline meets them where they are); :func:`PcaCodes` holds one fitted k.
Shapes: n places, d features, k kept axes, b queries.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax.jit_options import jit

__all__ = ["PcaCodes", "pca_bytes", "pca_dims", "principal_axes"]


def pca_bytes(n: int, d: int, k: int, dtype: str = "float32") -> int:
    """Bytes of k-axis PCA codes of n places of d features: projection and mean
    (float32), the places' codes, and at int8 their per-axis offset and range."""
    places = n * k * 4 if dtype == "float32" else n * k + 2 * k * 4
    return (d * k + d) * 4 + places


def pca_dims(n: int, d: int, low: float, high: float, most: int = 4) -> tuple[int, ...]:
    """Up to ``most`` powers of two k <= min(n, d) whose float32 or int8 PCA
    bytes lie in [low / 2, 2 high], spread from the fewest bytes to the most
    (the smallest k is kept when none fits)."""
    top = min(n, d)
    ks = [2**i for i in range(int(np.log2(top)) + 1)] if top >= 1 else []
    fit = [k for k in ks if any(low / 2 <= pca_bytes(n, d, k, t) <= 2 * high
                                for t in ("float32", "int8"))]  # fmt: skip
    if not fit:
        return tuple(ks[:1])
    if len(fit) <= most:
        return tuple(fit)
    pick = np.unique(np.round(np.linspace(0, len(fit) - 1, most)).astype(int))
    return tuple(fit[i] for i in pick)


def principal_axes(x, k: int) -> tuple[np.ndarray, np.ndarray]:
    """(mean (d,), the k leading principal axes (d, k)) of x (n, d): the right
    singular vectors of the centred x, by a float32 SVD."""
    x = np.asarray(x, np.float32)
    mean = x.mean(0)
    _, _, vt = np.linalg.svd(x - mean, full_matrices=False)
    return mean, np.ascontiguousarray(vt[:k].T)


@jit
def _project(q, mean, axes):
    return jnp.matmul(q - mean[None, :], axes, precision="highest")


@partial(jit, static_argnames="int8")
def _similarity(q, mean, axes, codes, lo, span, int8: bool):
    if int8:
        codes = codes.astype(jnp.float32) * (span / 255.0)[None, :] + lo[None, :]
    return jnp.matmul(_project(q, mean, axes), codes.T, precision="highest")


@dataclass(frozen=True)
class PcaCodes:
    """k-axis PCA codes of n places: ``mean`` (d,), ``axes`` (d, k), ``codes``
    (n, k) float32 or uint8, and for uint8 ``lo``/``span`` (k,)."""

    mean: np.ndarray
    axes: np.ndarray
    codes: np.ndarray
    lo: np.ndarray
    span: np.ndarray

    @classmethod
    def fit(cls, x, k: int, dtype: str = "float32", axes=None) -> PcaCodes:
        """x's (n, d) codes in ``dtype`` on its k leading axes (``axes``:
        :func:`principal_axes` of x, computed here when not given)."""
        x = np.asarray(x, np.float32)
        mean, axes = principal_axes(x, k) if axes is None else axes
        axes = np.ascontiguousarray(axes[:, :k], np.float32)
        z = ((x - mean) @ axes).astype(np.float32)
        lo = np.zeros(k, np.float32)
        span = np.ones(k, np.float32)
        if dtype == "int8":
            lo = z.min(0)
            span = np.where(z.max(0) > lo, z.max(0) - lo, 1.0).astype(np.float32)
            z = np.clip(np.round((z - lo) / span * 255.0), 0, 255).astype(np.uint8)
        return cls(np.asarray(mean, np.float32), axes, z, lo, span)

    @property
    def int8(self) -> bool:
        return self.codes.dtype == np.uint8

    def bytes(self) -> int:
        n, k = self.codes.shape
        return pca_bytes(n, len(self.mean), k, "int8" if self.int8 else "float32")

    def similarity(self, q) -> jax.Array:
        """Inner products (b, n) of the queries' (b, d) projections with the
        places' (dequantised) codes."""
        return _similarity(jnp.asarray(q, jnp.float32), self.mean, self.axes,
                           self.codes, self.lo, self.span, self.int8)  # fmt: skip

    def search(self, q) -> jax.Array:
        """The best place (b,) of each query: projection, scores, argmax."""
        return self.similarity(q).argmax(1)
