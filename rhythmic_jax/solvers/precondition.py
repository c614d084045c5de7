"""The preconditioner of the Newton systems: leading eigenvectors, exact blocks.

Every Newton step solves ``(lam I + Xa^T D_j Xa) s_j = r_j`` for each template j
(``D_j`` its active frames). All templates share the frames, so they share the
leading eigenvectors ``V`` (q, k) of ``Xa^T Xa`` (:func:`top_eigen`, subspace
iteration in float32, computed once per fit by :func:`spectral_setup`). In their
span :func:`block_preconditioner` inverts each template's system exactly on the
first ``block`` directions (where the active set couples directions most) and by
its diagonal on the rest; outside it, by a scalar per template. A fit whose
frames are read in blocks (:mod:`rhythmic_jax.solvers.streamed`) cannot keep
``Xa V``: it sums :func:`curvature_sums` over the blocks and takes
:func:`diagonal_preconditioner`, the diagonal in the same basis and the same
scalar outside it. Both apply to jax arrays, or to numpy arrays on the host
(float64, no program), as the CG that calls them runs.

Names: n frames, q = d + 1 (the bias is a constant-1 feature), k eigenvectors,
p templates.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax.jit_options import jit

__all__ = [
    "block_preconditioner",
    "curvature_sums",
    "diagonal_preconditioner",
    "in_basis",
    "outside_norms",
    "spectral_setup",
    "top_eigen",
]


def top_eigen(gram: jax.Array, k: int, iters: int, key: jax.Array):
    """Leading eigenpairs of a symmetric PSD (q, q) matrix by subspace iteration.

    Returns orthonormal vectors (q, k) and Rayleigh-Ritz values (k,), largest
    first; a few iterations are enough for a preconditioner (any orthonormal
    basis keeps it exact, only its quality depends on the subspace). ``key``
    draws the random start basis. With ``k >= q`` the basis is every direction:
    the eigendecomposition itself, with no iteration and no start basis.
    """
    q = gram.shape[0]
    if k >= q:  # every direction: the eigendecomposition itself, no iteration
        vals, vecs = jnp.linalg.eigh(gram)
        return vecs[:, ::-1], jnp.maximum(vals[::-1], 0.0)
    basis = jax.random.normal(key, (q, k), gram.dtype)
    for _ in range(iters):
        basis, _ = jnp.linalg.qr(jnp.matmul(gram, basis, precision="highest"))
    vals, small = jnp.linalg.eigh(
        jnp.matmul(
            basis.T, jnp.matmul(gram, basis, precision="highest"), precision="highest"
        )
    )
    return jnp.matmul(basis, small, precision="highest")[:, ::-1], jnp.maximum(
        vals[::-1], 0.0
    )


@partial(jit, static_argnames=("rank", "iters"))
def spectral_setup(xa: jax.Array, rank: int, iters: int, key: jax.Array):
    """Leading eigenvectors ``V`` (q, k) of ``Xa^T Xa``, ``F = Xa V`` (n, k), and
    each frame's squared norm outside them, ``||xa_i||^2 - ||F_i||^2`` (n,)."""
    vecs, _ = top_eigen(jnp.matmul(xa.T, xa, precision="highest"), rank, iters, key)
    lead = jnp.matmul(xa, vecs, precision="highest")
    return vecs, lead, outside_norms(xa, lead)


def outside_norms(xa: jax.Array, lead: jax.Array) -> jax.Array:
    """Each row's squared norm outside an orthonormal basis V (q, k), from the
    rows ``xa`` (n, q) and their coefficients ``lead = xa V`` (n, k): (n,),
    ``||xa_i||^2 - ||lead_i||^2`` kept >= 0 against rounding."""
    rest = jnp.sum(xa * xa, axis=1) - jnp.sum(lead * lead, axis=1)
    return jnp.maximum(rest, 0.0)


def _matmul(a, b):
    """``a @ b``: numpy's for host arrays, else jax's at full float32 precision."""
    if isinstance(a, np.ndarray) and isinstance(b, np.ndarray):
        return a @ b
    return jnp.matmul(a, b, precision="highest")


def in_basis(vecs: jax.Array, inside, tail: jax.Array):
    """A preconditioner split by an orthonormal basis ``vecs`` (q, k): ``inside``
    maps the coefficients ``V^T v`` (k, p) to the system's inverse applied there;
    outside the basis each column is divided by ``tail`` (1, p). Returns
    ``apply`` mapping (q, p) -> (q, p) (numpy arrays stay numpy)."""

    def apply(v):
        coef = _matmul(vecs.T, v)
        return _matmul(vecs, inside(coef) - coef / tail) + v / tail

    return apply


def curvature_sums(xa: jax.Array, h: jax.Array, vecs: jax.Array | None):
    """What :func:`diagonal_preconditioner` needs of ``Xa^T diag(h_j) Xa`` over
    some frames ``xa`` (B, q) with curvatures ``h`` (B, p), summed over them: its
    diagonal in the basis ``vecs`` (q, k), ``sum_i h_ij (xa_i . v_l)^2`` (k, p),
    and its trace outside the basis, ``sum_i h_ij ||xa_i outside V||^2`` (p,);
    with ``vecs`` None its diagonal in theta (q, p) (Jacobi). Sums over blocks of
    frames add up."""
    if vecs is None:
        return jnp.matmul((xa * xa).T, h, precision="highest")
    lead = jnp.matmul(xa, vecs, precision="highest")
    return jnp.matmul((lead * lead).T, h, precision="highest"), jnp.matmul(
        outside_norms(xa, lead), h, precision="highest"
    )


def diagonal_preconditioner(vecs, sums, lam):
    """Preconditioner of ``H_j = lam_j I + Xa^T diag(h_j) Xa`` for every template
    from :func:`curvature_sums` over every frame: in the basis ``vecs`` (q, k) its
    diagonal ``lam + sums[0]``, outside it ``lam`` plus the mean over the q - k
    remaining directions of the trace there (as :func:`block_preconditioner`
    with no exact block); ``vecs`` None: ``1 / (lam + diagonal)`` (Jacobi).
    ``lam`` (1, p) or, for Jacobi, (q, p). Returns ``apply`` (q, p) -> (q, p)."""
    if vecs is None:
        diag = lam + sums
        return lambda r: r / diag
    inside, outside = sums
    q, k = vecs.shape
    diag = lam + inside
    tail = lam + outside[None, :] / max(q - k, 1)
    return in_basis(vecs, lambda coef: coef / diag, tail)


def block_preconditioner(vecs, lead, rest, mask, lam, block):
    """Preconditioner of ``H_j = lam I + Xa^T diag(mask_j) Xa`` for every template.

    In the leading eigen-directions ``V`` (q, k) of ``Xa^T Xa`` (``lead = Xa V``,
    (n, k)): exact on the first ``block`` (a Cholesky per template), the diagonal
    ``lam + sum_i mask_ij lead_il^2`` on the others; outside them a scalar per
    template, ``lam`` plus the mean over the q - k remaining directions of
    ``H_j``'s trace there (``rest`` (n,), each frame's squared norm outside V).
    ``mask`` (n, p) float32. Returns ``apply`` mapping (q, p) -> (q, p).
    """
    n, k = lead.shape
    q = vecs.shape[0]
    kb = min(block, k)
    diag = lam + jnp.matmul((lead * lead).T, mask, precision="highest")  # (k, p)
    tail = lam + jnp.matmul(rest[None, :], mask, precision="highest") / max(
        q - k, 1
    )  # (1, p)
    top = lead[:, :kb]
    outer = (top[:, :, None] * top[:, None, :]).reshape(n, kb * kb)
    blocks = jnp.matmul(outer.T, mask, precision="highest").T.reshape(-1, kb, kb)
    chol = jnp.linalg.cholesky(blocks + lam * jnp.eye(kb, dtype=lead.dtype)[None])

    def inside(coef):  # (k, p)
        head = jax.scipy.linalg.cho_solve((chol, True), coef[:kb].T[:, :, None])
        return jnp.concatenate([head[:, :, 0].T, coef[kb:] / diag[kb:]], axis=0)

    return in_basis(vecs, inside, tail)
