"""Wide features (d > n): solve in the n-dimensional span of the frames.

Every template's optimal weights lie in the span of the frames (the representer
theorem: the gradient of the objective is a combination of frames plus ``w``
itself), so with ``X X^T = L L^T`` (Cholesky, (n, n)) the substitution
``w = X^T L^{-T} beta`` gives

    x_i . w = (L beta)_i        and        ||w||^2 = ||beta||^2,

the SAME objective over frames ``L`` of n dimensions instead of d; the bias stays
a constant-1 feature beside them. A solver's product then costs ``n^2`` per
template instead of ``n d`` (deep descriptors: 10976-d for 3576 frames, 3x
fewer FLOPs), and the reduction itself is one (n, d) x (d, n) product and a
Cholesky. This is the primal-side twin of the kernel (Gram) form, and keeps the
primal solver's preconditioner and stopping rule unchanged.
"""

from __future__ import annotations

import numpy as np

__all__ = ["in_span", "lift", "row_factor"]


def in_span(n: int, d: int) -> bool:
    """Whether n frames of d features are solved in their span (the one rule).

    True when ``d > 2n``: below that the reduction's (n, d) x (d, n) product and
    Cholesky cost more than they save (measured on 3705 x 4096 frames in
    ``reports/span.md``). The Newton solver, the ridge start and the memory
    estimate all take their primal or span form from this rule.
    """
    return d > 2 * n


def row_factor(x: np.ndarray, jitter: float = 1e-9) -> np.ndarray:
    """Lower-triangular ``L`` (n, n), float64, with ``L L^T = X X^T + eps I``.

    ``x`` (n, d). ``eps = jitter * mean(diag(X X^T))`` keeps the factor defined
    when frames repeat (a stopped train gives identical frames); it is raised
    tenfold until the factorisation succeeds. Its effect on the objective is of
    order ``sqrt(eps)``.
    """
    x64 = np.asarray(x, np.float64)
    gram = x64 @ x64.T
    if not np.all(np.isfinite(gram)):
        raise ValueError("frames hold NaN or inf")
    scale = max(float(np.trace(gram)) / len(gram), 1e-300)
    eps = jitter * scale
    for _ in range(8):
        try:
            return np.linalg.cholesky(gram + eps * np.eye(len(gram)))
        except np.linalg.LinAlgError:
            eps *= 10.0
    raise np.linalg.LinAlgError("X X^T is not positive semi-definite")


def lift(x: np.ndarray, factor: np.ndarray, beta: np.ndarray) -> np.ndarray:
    """Weights ``w = X^T L^{-T} beta`` (d, p) from reduced weights ``beta`` (n, p).

    ``x`` (n, d) the frames, ``factor`` L from :func:`row_factor`.
    """
    import scipy.linalg  # deferred: 0.2 s, and a query never solves

    coef = scipy.linalg.solve_triangular(
        factor.T, np.asarray(beta, np.float64), lower=False
    )
    return np.asarray(x, np.float64).T @ coef
