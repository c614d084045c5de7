"""Linear projections of descriptors, fitted on the reference set (pure JAX).

PCA keeps the k directions of largest variance of the map descriptors.
:func:`fit_pca` returns a NamedTuple of arrays; :func:`project` applies it:
``y = (x - mean) @ components.T``, optionally L2-normalised per row.

Shapes: n frames, d input features, k output dimensions.
"""

from __future__ import annotations

import functools
import numbers
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.jit_options import jit

__all__ = ["PCA", "fit_pca", "project"]


class PCA(NamedTuple):
    """mean (d,), components (k, d) orthonormal rows, explained_variance (k,)."""

    mean: jax.Array
    components: jax.Array
    explained_variance: jax.Array


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
    top = min(n - 1, d)
    whole = isinstance(k, numbers.Integral) and not isinstance(k, bool)
    if not (whole and 1 <= k <= top):
        raise InputError(f"pca k={k!r}: need 1 <= k <= min(n - 1, d) = {top}")
    return PCA(*_pca(x, k))


@functools.partial(jit, static_argnames="k")
def _pca(x: jax.Array, k: int) -> tuple[jax.Array, jax.Array, jax.Array]:
    mean = x.mean(axis=0)
    s, v = _right_singular(x - mean[None, :])
    return mean, v[:, :k].T, s[:k] ** 2 / (x.shape[0] - 1)


def project(model: PCA, x: jax.Array, normalize: bool = False) -> jax.Array:
    """(n, d) -> (n, k): ``(x - mean) @ components.T``; rows to unit L2 norm when
    ``normalize`` (all-zero rows stay zero)."""
    x = jnp.asarray(x, dtype=jnp.float32)
    if x.ndim != 2 or x.shape[1] != model.mean.shape[0]:
        raise InputError(
            f"project: expected (n, {model.mean.shape[0]}) features, got {x.shape}"
        )
    return _project(model.mean, model.components, x, normalize)


@functools.partial(jit, static_argnames="normalize")
def _project(mean, components, x, normalize: bool) -> jax.Array:
    y = jnp.matmul(x - mean[None, :], components.T, precision="highest")
    if normalize:
        norm = jnp.linalg.norm(y, axis=1, keepdims=True)
        y = y / jnp.maximum(norm, 1e-12)
    return y
