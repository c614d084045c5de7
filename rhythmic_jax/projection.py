"""Linear projections of descriptors, fitted on the reference set (pure JAX).

* PCA: keep the k directions of largest variance of the map descriptors.
* LDA: the paper's projection for multi-exemplar data (Sec. 5: VGG16 fc7 to 64-d
  on Oxford RobotCar). Classes are place labels shared by several traversals;
  the projection maximises between-place over within-place scatter.

Each ``fit_*`` returns a NamedTuple of arrays; ``project`` applies either one:
``y = (x - mean) @ components.T``, optionally L2-normalised per row.

Shapes: n frames, d input features, k output dimensions, c classes.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax.errors import InputError

__all__ = ["LDA", "PCA", "fit_lda", "fit_pca", "project"]


class PCA(NamedTuple):
    """mean (d,), components (k, d) orthonormal rows, explained_variance (k,)."""

    mean: jax.Array
    components: jax.Array
    explained_variance: jax.Array


class LDA(NamedTuple):
    """mean (d,), components (k, d) (scalings, not orthonormal),
    explained_variance_ratio (k,): share of the between-class variance."""

    mean: jax.Array
    components: jax.Array
    explained_variance_ratio: jax.Array


def _as_matrix(x, name: str) -> jax.Array:
    host = np.asarray(x, dtype=np.float32)
    if host.ndim != 2 or host.shape[0] == 0 or host.shape[1] == 0:
        raise InputError(f"{name}: expected a non-empty (n, d) array, got {host.shape}")
    if not np.isfinite(host).all():
        raise InputError(f"{name}: contains NaN or infinite values")
    return jnp.asarray(host)


def _right_singular(a: jax.Array, exact: bool = False) -> tuple[jax.Array, jax.Array]:
    """Right singular pairs of a (m, d), largest first: (s (q,), v (d, q)).

    q = min(m, d). Fast (``exact=False``): eigh of the smaller Gram matrix, a a^T
    (m x m) when m < d, else a^T a (d x d); squaring the condition number, it
    resolves singular values down to about 3e-4 of the largest in float32.
    ``exact=True``: QR of the tall one of a, a^T, then the SVD of its q x q
    triangle, accurate for the small singular values too at some extra cost.
    Signs: each vector's largest-magnitude entry is positive (deterministic, like
    scikit-learn's ``svd_flip``).
    """
    hi = jax.lax.Precision.HIGHEST
    wide = a.shape[0] < a.shape[1]
    if exact:
        r = jnp.linalg.qr(a.T if wide else a, mode="r")  # (q, q)
        if wide:  # a = r^T q^T: right vectors of a are q @ left vectors of r^T
            u, s, _ = jnp.linalg.svd(r.T, full_matrices=False)
            v = jnp.matmul(a.T, u, precision=hi) / jnp.maximum(s, 1e-30)[None, :]
        else:
            _, s, vt = jnp.linalg.svd(r, full_matrices=False)
            v = vt.T
    elif wide:
        lam, u = jnp.linalg.eigh(jnp.matmul(a, a.T, precision=hi))
        lam, u = lam[::-1], u[:, ::-1]
        s = jnp.sqrt(jnp.maximum(lam, 0.0))
        v = jnp.matmul(a.T, u, precision=hi) / jnp.maximum(s, 1e-30)[None, :]
    else:
        lam, v = jnp.linalg.eigh(jnp.matmul(a.T, a, precision=hi))
        lam, v = lam[::-1], v[:, ::-1]
        s = jnp.sqrt(jnp.maximum(lam, 0.0))
    pick = jnp.argmax(jnp.abs(v), axis=0)
    sign = jnp.sign(v[pick, jnp.arange(v.shape[1])])
    return s, v * jnp.where(sign == 0, 1.0, sign)[None, :]


def fit_pca(x: jax.Array, k: int) -> PCA:
    """Principal components of the rows of x (n, d); k <= min(n - 1, d).

    explained_variance = s^2 / (n - 1) for the singular values s of x - mean, as
    scikit-learn's ``PCA`` reports it.
    """
    x = _as_matrix(x, "pca input")
    n, d = x.shape
    if not isinstance(k, int) or not 1 <= k <= min(n - 1, d):
        raise InputError(f"pca k={k!r}: need 1 <= k <= min(n - 1, d) = {min(n - 1, d)}")
    return PCA(*_pca(x, k))


@functools.partial(jax.jit, static_argnames="k")
def _pca(x: jax.Array, k: int) -> tuple[jax.Array, jax.Array, jax.Array]:
    mean = x.mean(axis=0)
    s, v = _right_singular(x - mean[None, :])
    return mean, v[:, :k].T, s[:k] ** 2 / (x.shape[0] - 1)


def fit_lda(x: jax.Array, labels, k: int = 64, tol: float = 1e-4) -> LDA:
    """Fisher LDA of x (n, d) with class labels (n,) to k <= c - 1 dimensions.

    Whitens the within-class covariance S_w = sum_i (x_i - m_{y_i})(...)^T / n
    (directions with singular value below ``tol`` times the largest are dropped),
    then takes the principal axes of the class means weighted by
    sqrt(n_c / (c - 1)) in that space; the same solution as scikit-learn's
    ``LinearDiscriminantAnalysis(solver="svd")`` (generalised eigenvectors of
    S_b v = lambda S_w v, scaled so that v^T S_w v = 1).
    """
    x = _as_matrix(x, "lda input")
    labels = np.asarray(labels)
    n, d = x.shape
    if labels.shape != (n,):
        raise InputError(f"lda labels: expected shape ({n},), got {labels.shape}")
    classes, y = np.unique(labels, return_inverse=True)
    c = len(classes)
    if c < 2 or n <= c:
        raise InputError(
            f"lda: need at least 2 classes and more frames ({n}) than c={c}"
        )
    if not isinstance(k, int) or not 1 <= k <= c - 1:
        raise InputError(f"lda k={k!r}: need 1 <= k <= classes - 1 = {c - 1}")
    y = jnp.asarray(y.ravel(), dtype=jnp.int32)
    means, mean, counts, s, v = _lda_within(x, y, c)
    rank = int(jnp.sum(s > tol * s[0]))
    components, ratio, s2 = _lda_between(means, mean, counts, s, v, rank, k)
    if int(jnp.sum(s2 > tol * s2[0])) < k:
        raise InputError(f"lda k={k}: the class means span fewer than {k} directions")
    return LDA(mean, components, ratio)


@functools.partial(jax.jit, static_argnames="c")
def _lda_within(x: jax.Array, y: jax.Array, c: int) -> tuple[jax.Array, ...]:
    """Class means (c, d), mean (d,), counts (c,) and the singular pairs of the
    within-class deviations / sqrt(n)."""
    counts = jax.ops.segment_sum(jnp.ones_like(y, jnp.float32), y, num_segments=c)
    means = jax.ops.segment_sum(x, y, num_segments=c) / counts[:, None]
    s, v = _right_singular((x - means[y]) / jnp.sqrt(x.shape[0]), exact=True)
    return means, x.mean(axis=0), counts, s, v


@functools.partial(jax.jit, static_argnames=("rank", "k"))
def _lda_between(means, mean, counts, s, v, rank: int, k: int):
    """Components (k, d), their between-class variance ratios (k,), and all the
    between-class singular values in the whitened space."""
    white = v[:, :rank] / s[None, :rank]  # (d, r): white^T S_w white = I
    c = means.shape[0]
    between = jnp.sqrt(counts / (c - 1))[:, None] * (means - mean[None, :])
    s2, v2 = _right_singular(jnp.matmul(between, white, precision="highest"))
    components = jnp.matmul(white, v2[:, :k], precision="highest").T
    return components, (s2**2 / jnp.sum(s2**2))[:k], s2


def project(model: PCA | LDA, x: jax.Array, normalize: bool = False) -> jax.Array:
    """(n, d) -> (n, k): ``(x - mean) @ components.T``; rows to unit L2 norm when
    ``normalize`` (all-zero rows stay zero)."""
    x = jnp.asarray(x, dtype=jnp.float32)
    if x.ndim != 2 or x.shape[1] != model.mean.shape[0]:
        raise InputError(
            f"project: expected (n, {model.mean.shape[0]}) features, got {x.shape}"
        )
    return _project(model.mean, model.components, x, normalize)


@functools.partial(jax.jit, static_argnames="normalize")
def _project(mean, components, x, normalize: bool) -> jax.Array:
    y = jnp.matmul(x - mean[None, :], components.T, precision="highest")
    if normalize:
        norm = jnp.linalg.norm(y, axis=1, keepdims=True)
        y = y / jnp.maximum(norm, 1e-12)
    return y
