"""The map made differentiable: closed-form templates and a soft place decode.

With every margin active the squared hinge of one template is a ridge problem,
so the templates of a window of frames z (n, k) with +-1 targets y (n, p) are

    w = (A^T A + lam I)^{-1} A^T (y - ybar),  b = ybar - zbar w,  A = z - zbar,

solved by a Cholesky factorisation (``jax.scipy.linalg.cho_solve``), through
which gradients flow to z. ``lam = ridge * tr(A^T A) / k`` is relative to the
frames' scale; a large ``ridge`` tends to the class-mean (prototype) template.
Queries are then decoded in the place domain as :mod:`rhythmic_jax.decoding.soft` does,
with per-period log-softmax calibration: place i of the window scores
``S(i) = sum_k log softmax(scale * s_k)[(i + offset) mod tau_k]``.

Shapes: n frames, k dimensions, p = sum(periods) templates, b queries.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax.solvers.objective import Templates

__all__ = ["place_log_scores", "ridge_templates"]


def ridge_templates(z: jax.Array, y: jax.Array, ridge: float) -> Templates:
    """Ridge templates of frames z (n, k) for targets y (n, p), differentiable in z.

    Minimises ``sum_i ||z_i w + b - y_i||^2 + lam ||w||^2`` with an unpenalised
    bias, ``lam = ridge * tr(A^T A) / k``; returns w (k, p), b (p,).
    """
    zbar = z.mean(axis=0)
    ybar = y.mean(axis=0)
    a = z - zbar[None, :]
    gram = jnp.matmul(a.T, a, precision="highest")
    lam = ridge * jnp.trace(gram) / z.shape[1]
    factor = jax.scipy.linalg.cho_factor(gram + lam * jnp.eye(z.shape[1]))
    w = jax.scipy.linalg.cho_solve(
        factor, jnp.matmul(a.T, y - ybar[None, :], precision="highest")
    )
    return Templates(w=w, b=ybar - jnp.matmul(zbar, w, precision="highest"))


def place_log_scores(
    s: jax.Array, periods: Sequence[int], places: jax.Array, scale: jax.Array
) -> jax.Array:
    """Calibrated scores (b, m) of the places ``places`` (m,) from scores s (b, p)."""
    out, start = 0.0, 0
    for t in periods:
        logp = jax.nn.log_softmax(scale * s[:, start : start + t], axis=1)
        out = out + logp[:, places % t]
        start += t
    return out


def window_periods(n: int, r: int, level: int) -> tuple[int, ...]:
    """r pairwise co-prime periods near ``level * ceil(n ** (1/r))`` (episodes)."""
    from rhythmic_jax.map.periods import candidate_periods, choose_periods

    cands = candidate_periods(n, r, level, 7)
    return tuple(int(t) for t in choose_periods(cands, np.zeros(len(cands)), n, r))
