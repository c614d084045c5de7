"""Exact solver for the joint objective: ridge start + active-set Newton-CG.

With the active set ``D = {i : y_i m_i < 1}`` held fixed, the squared hinge is a
ridge problem (``(1 - y m)^2 = (y - m)^2`` for ``y = ±1``), so a Newton step is the
ridge solution on the active frames (Chapelle, "Training a support vector machine
in the primal", 2007)::

    primal:  (lam I + Xa^T D Xa) theta = Xa^T D y          theta = [w; b], (d+1, p)
    Gram:    (K_DD + lam I) alpha_D = y_D,  alpha_~D = 0    K = Xa Xa^T, (n, n)

with ``Xa = [X, 1]`` (the bias as a constant-1 feature), ``lam = 1 / (2 C)`` and
``w = Xa^T alpha`` in the Gram form. With every frame active this is a closed-form
ridge solve: the start. Each step solves the system by conjugate gradients for all
p templates at once (float32 products), then takes an exact line search on the
piecewise-quadratic objective along the step; objective, margins and line search
run in float64. The primal form is used when ``d + 1 <= n`` and the Gram form
otherwise: a CG product costs ``2 n (d+1) p`` against ``n^2 p``, and the spectral
preconditioner (top eigenvectors of ``Xa^T Xa``) fits the primal system better,
so it needs several times fewer CG iterations there (measured on 3576 Nordland
frames of 2048-d: 193 against 674). This is the same objective as
:func:`rhythmic_jax.objective.objective`, solved to its optimum.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from rhythmic_jax.objective import Templates

__all__ = ["NewtonConfig", "NewtonInfo", "newton_fit"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class NewtonConfig:
    """Settings of :func:`newton_fit`.

    Attributes:
      tol: stop when no template's objective fell by more than ``tol`` (relative)
        in the last step.
      max_iter: most Newton steps.
      cg_tol: relative residual at which CG stops.
      max_cg: most CG iterations per Newton step.
      form: "auto", "primal" or "gram".
      precond_rank: eigenvectors of the Gram matrix kept in the CG preconditioner.
    """

    tol: float = 1e-7
    max_iter: int = 40
    cg_tol: float = 1e-5
    max_cg: int = 400
    form: str = "auto"
    precond_rank: int = 512


@dataclass(frozen=True)
class NewtonInfo:
    """What a solve did: form used, steps, CG iterations, per-template objective."""

    form: str
    steps: int
    cg_iterations: tuple[int, ...]
    objective: np.ndarray


def _cg(op, precond, rhs: jax.Array, x0: jax.Array, tol: float, max_iter: int):
    """Batched preconditioned conjugate gradients: ``op(x) = rhs`` per column.

    ``op`` and ``precond`` map (q, p) -> (q, p), each symmetric positive definite
    per column (``precond`` approximates the inverse of ``op``). Stops when every
    column's residual is below ``tol`` times its right-hand side. Returns the
    solution and the number of iterations taken.
    """
    bnorm = jnp.maximum(jnp.linalg.norm(rhs, axis=0, keepdims=True), 1e-30)
    r = rhs - op(x0)
    z = precond(r)
    rz = jnp.sum(r * z, axis=0, keepdims=True)
    rn = jnp.linalg.norm(r, axis=0, keepdims=True)

    def cond(state):
        *_, rn, it = state
        return jnp.logical_and(it < max_iter, jnp.any(rn > tol * bnorm))

    def body(state):
        x, r, d, rz, rn, it = state
        ad = op(d)
        live = rn > tol * bnorm
        dad = jnp.sum(d * ad, axis=0, keepdims=True)
        step = jnp.where(live, rz / jnp.where(dad > 0, dad, 1.0), 0.0)
        x = x + step * d
        r = r - step * ad
        z = precond(r)
        rz_new = jnp.sum(r * z, axis=0, keepdims=True)
        beta = jnp.where(live, rz_new / jnp.where(rz > 0, rz, 1.0), 0.0)
        d = z + beta * d
        return x, r, d, rz_new, jnp.linalg.norm(r, axis=0, keepdims=True), it + 1

    x, *_, it = jax.lax.while_loop(cond, body, (x0, r, z, rz, rn, 0))
    return x, it


def _top_eigen(a: jax.Array, k: int, iters: int = 4, seed: int = 0):
    """Top-k eigenpairs of a symmetric PSD (q, q) matrix by subspace iteration.

    Returns eigenvectors (q, k) and eigenvalues (k,), largest first.
    """
    q = a.shape[0]
    k = min(k, q)
    basis = jax.random.normal(jax.random.PRNGKey(seed), (q, k), dtype=a.dtype)
    for _ in range(iters):
        basis, _ = jnp.linalg.qr(a @ basis)
    vals, small = jnp.linalg.eigh(basis.T @ a @ basis)
    return (basis @ small)[:, ::-1], vals[::-1]


def _spectral_precond(vecs, vals, lam, rho):
    """Inverse of ``lam I + rho A`` with A replaced by its top-k part plus a floor.

    ``vecs`` (q, k), ``vals`` (k,) from :func:`_top_eigen`; ``rho`` (p,) is each
    template's fraction of active frames (``Xa^T D Xa ~ rho Xa^T Xa``).
    """
    inv_top = 1.0 / (lam + rho[None, :] * vals[:, None])  # (k, p)
    inv_tail = 1.0 / (lam + rho[None, :] * vals[-1])  # (1, p)

    def apply(v):
        coef = vecs.T @ v
        return vecs @ (coef * inv_top) + (v - vecs @ coef) * inv_tail

    return apply


def _line_search(m, u, y, a, b, cc, c, iters: int = 30):
    """Exact minimiser over t >= 0 of the objective along a step, per template.

    ``phi(t) = 0.5 (a + 2 t b + t^2 cc) + C sum_i max(0, 1 - y_i (m_i + t u_i))^2``
    is convex and piecewise quadratic; Newton's method on ``phi'`` from t = 0 lands
    on the minimiser after a few pieces. Arrays: m, u, y (n, p); a, b, cc (1, p).
    Returns t (1, p) and phi(t) (p,).
    """
    yu = y * u
    slack0 = 1.0 - y * m

    def phi(t):
        h = jnp.maximum(0.0, slack0 - t * yu)
        quad = 0.5 * (a + 2 * t * b + t * t * cc)
        return quad + c * jnp.sum(h * h, axis=0, keepdims=True)

    def body(_, t):
        slack = slack0 - t * yu
        act = slack > 0
        g = (
            b
            + t * cc
            - 2 * c * jnp.sum(jnp.where(act, yu * slack, 0.0), 0, keepdims=True)
        )
        h = cc + 2 * c * jnp.sum(jnp.where(act, yu * yu, 0.0), axis=0, keepdims=True)
        return jnp.maximum(t - g / jnp.maximum(h, 1e-300), 0.0)

    t = jax.lax.fori_loop(0, iters, body, jnp.zeros_like(a))
    t = jnp.where(phi(t) <= phi(jnp.zeros_like(t)), t, 0.0)
    return t, phi(t)[0]


@jax.jit
def _gram_step(k64, k32, vecs, vals, alpha, y, c, cg_tol, max_cg):
    lam = 0.5 / c
    m = k64 @ alpha
    mask = (y * m < 1.0).astype(jnp.float32)
    lam32 = lam.astype(jnp.float32)
    pre = _spectral_precond(vecs, vals, lam32, jnp.mean(mask, axis=0))

    def op(v):
        return mask * (k32 @ (mask * v)) + lam32 * v

    def precond(r):
        return mask * pre(mask * r)

    beta, it = _cg(
        op,
        precond,
        (mask * y).astype(jnp.float32),
        (mask * alpha).astype(jnp.float32),
        cg_tol,
        max_cg,
    )
    delta = beta.astype(alpha.dtype) - alpha
    u = k64 @ delta
    a = jnp.sum(alpha * m, axis=0, keepdims=True)
    b = jnp.sum(alpha * u, axis=0, keepdims=True)
    cc = jnp.sum(delta * u, axis=0, keepdims=True)
    f0 = 0.5 * a[0] + c * jnp.sum(jnp.square(jnp.maximum(0.0, 1.0 - y * m)), axis=0)
    t, f1 = _line_search(m, u, y, a, b, cc, c)
    return alpha + t * delta, f0, f1, it


@jax.jit
def _primal_step(xa64, xa32, vecs, vals, theta, y, c, cg_tol, max_cg):
    lam = 0.5 / c
    m = xa64 @ theta
    mask = (y * m < 1.0).astype(jnp.float32)
    lam32 = lam.astype(jnp.float32)
    precond = _spectral_precond(vecs, vals, lam32, jnp.mean(mask, axis=0))

    def op(v):
        return xa32.T @ (mask * (xa32 @ v)) + lam32 * v

    rhs = xa32.T @ (mask * y).astype(jnp.float32)
    beta, it = _cg(op, precond, rhs, theta.astype(jnp.float32), cg_tol, max_cg)
    delta = beta.astype(theta.dtype) - theta
    u = xa64 @ delta
    a = jnp.sum(theta * theta, axis=0, keepdims=True)
    b = jnp.sum(theta * delta, axis=0, keepdims=True)
    cc = jnp.sum(delta * delta, axis=0, keepdims=True)
    f0 = 0.5 * a[0] + c * jnp.sum(jnp.square(jnp.maximum(0.0, 1.0 - y * m)), axis=0)
    t, f1 = _line_search(m, u, y, a, b, cc, c)
    return theta + t * delta, f0, f1, it


def _ridge(g: jax.Array, rhs: jax.Array, lam: float) -> jax.Array:
    """Solve ``(g + lam I) z = rhs`` by Cholesky (g symmetric PSD)."""
    chol = jnp.linalg.cholesky(g + lam * jnp.eye(g.shape[0], dtype=g.dtype))
    return jax.scipy.linalg.cho_solve((chol, True), rhs)


def newton_fit(
    x: np.ndarray | jax.Array,
    y: np.ndarray | jax.Array,
    c: float,
    config: NewtonConfig = NewtonConfig(),
    progress: bool = True,
) -> tuple[Templates, NewtonInfo]:
    """Minimise the joint squared-hinge objective of p templates exactly.

    Args:
      x: (n, d) frames (float32).
      y: (n, p) ±1 targets (:func:`rhythmic_jax.objective.targets`).
      c: the penalty C.
      config: solver settings.
      progress: show a progress bar over Newton steps.

    Returns:
      Templates with ``w`` (d, p) and ``b`` (p,) as float32, and a
      :class:`NewtonInfo`.
    """
    n, d = x.shape
    form = config.form
    if form == "auto":
        form = "gram" if n < d + 1 else "primal"
    if form not in ("gram", "primal"):
        raise ValueError(f"form must be 'auto', 'gram' or 'primal', got {form!r}")
    with jax.enable_x64(True):
        x64 = jnp.asarray(np.asarray(x, dtype=np.float64))
        xa64 = jnp.concatenate([x64, jnp.ones((n, 1), jnp.float64)], axis=1)
        y64 = jnp.asarray(np.asarray(y, dtype=np.float64))
        c64 = jnp.float64(c)
        lam = 0.5 / float(c)
        if form == "gram":
            mat = gram = xa64 @ xa64.T
            theta = _ridge(mat, y64, lam)
            step = _gram_step
        else:
            mat = xa64
            gram = xa64.T @ xa64
            theta = _ridge(gram, xa64.T @ y64, lam)
            step = _primal_step
        mat32 = mat.astype(jnp.float32)
        vecs, vals = _top_eigen(gram, config.precond_rank)
        vecs, vals = vecs.astype(jnp.float32), vals.astype(jnp.float32)
        cg_its: list[int] = []
        f_prev = None
        bar = tqdm(
            range(config.max_iter), desc=f"newton ({form})", disable=not progress
        )
        steps = 0
        for steps in bar:  # noqa: B007
            theta, f0, f1, it = step(
                mat, mat32, vecs, vals, theta, y64, c64, config.cg_tol, config.max_cg
            )
            cg_its.append(int(it))
            rel = float(jnp.max((f0 - f1) / jnp.maximum(jnp.abs(f0), 1e-30)))
            bar.set_postfix(objective=f"{float(jnp.sum(f1)):.6g}", rel=f"{rel:.1e}")
            f_prev = f1
            if rel <= config.tol:
                break
        bar.close()
        if form == "gram":
            w = x64.T @ theta
            b = jnp.sum(theta, axis=0)
        else:
            w, b = theta[:-1], theta[-1]
        params = Templates(
            w=jnp.asarray(np.asarray(w, dtype=np.float32)),
            b=jnp.asarray(np.asarray(b, dtype=np.float32)),
        )
        info = NewtonInfo(
            form=form,
            steps=steps + 1,
            cg_iterations=tuple(cg_its),
            objective=np.asarray(f_prev, dtype=np.float64),
        )
    log.debug("newton: %s form, %d steps, CG %s", form, info.steps, cg_its)
    return params, info
