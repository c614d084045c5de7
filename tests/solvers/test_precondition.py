"""The Newton systems' preconditioner against dense numpy linear algebra."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from rhythmic_jax.solvers.precondition import (
    block_preconditioner,
    curvature_sums,
    diagonal_preconditioner,
    spectral_setup,
    top_eigen,
)

RNG = np.random.default_rng(0)
KEY = jax.random.PRNGKey(0)
N, Q, P, LAM = 80, 12, 3, 0.05


@pytest.fixture(scope="module")
def system():
    """Frames with a decaying spectrum, a bias column, and active sets (n, p)."""
    x = RNG.normal(size=(N, Q - 1)) * np.geomspace(3.0, 0.1, Q - 1)
    xa = np.hstack([x, np.ones((N, 1))]).astype(np.float32)
    mask = (RNG.random((N, P)) < 0.6).astype(np.float32)
    return xa, mask


def dense(xa, mask, j):
    """(q, q) system of template j: lam I + Xa^T diag(mask_j) Xa, in float64."""
    xa = xa.astype(np.float64)
    return LAM * np.eye(xa.shape[1]) + xa.T @ (mask[:, j, None] * xa)


def as_matrices(apply, q, p):
    """The (p, q, q) matrices of ``apply`` (one column per template)."""
    cols = [np.asarray(apply(jnp.tile(jnp.eye(q)[:, [i]], (1, p)))) for i in range(q)]
    return np.stack(cols, axis=2).transpose(1, 0, 2)


@pytest.mark.parametrize("k", [5, Q])  # Q: every direction, no iteration
def test_top_eigen_matches_eigh(system, k):
    xa, _ = system
    gram = xa.T.astype(np.float64) @ xa
    want = np.linalg.eigvalsh(gram)[::-1][:k]
    vecs, vals = top_eigen(jnp.asarray(gram, jnp.float32), k, 30, KEY)
    np.testing.assert_allclose(np.asarray(vals), want, rtol=1e-4)
    v = np.asarray(vecs, np.float64)  # products in float64, not the device's default
    np.testing.assert_allclose(v.T @ v, np.eye(k), atol=1e-5)
    ritz = v.T @ gram @ v
    np.testing.assert_allclose(np.diag(ritz), want, rtol=1e-4)


def test_setup_splits_each_frame_into_lead_and_rest(system):
    xa, _ = system
    vecs, lead, rest = spectral_setup(jnp.asarray(xa), rank=4, iters=20, key=KEY)
    np.testing.assert_allclose(np.asarray(lead), xa @ np.asarray(vecs), atol=1e-4)
    outside = xa - np.asarray(lead) @ np.asarray(vecs).T
    np.testing.assert_allclose(np.asarray(rest), (outside**2).sum(1), atol=1e-3)


def test_full_rank_and_block_invert_every_system_exactly(system):
    xa, mask = system
    vecs, lead, rest = spectral_setup(jnp.asarray(xa), rank=Q, iters=20, key=KEY)
    apply = block_preconditioner(vecs, lead, rest, jnp.asarray(mask), LAM, Q)
    got = as_matrices(apply, Q, P)
    for j in range(P):
        np.testing.assert_allclose(
            got[j], np.linalg.inv(dense(xa, mask, j)), rtol=2e-3, atol=2e-3
        )


@pytest.mark.parametrize("rank, block", [(6, 2), (6, 6), (1, 1)])
def test_partial_preconditioner_is_symmetric_positive_definite(system, rank, block):
    xa, mask = system
    vecs, lead, rest = spectral_setup(jnp.asarray(xa), rank=rank, iters=20, key=KEY)
    apply = block_preconditioner(vecs, lead, rest, jnp.asarray(mask), LAM, block)
    for j, m in enumerate(as_matrices(apply, Q, P)):
        np.testing.assert_allclose(m, m.T, atol=1e-4)
        assert np.linalg.eigvalsh((m + m.T) / 2).min() > 0
        # it reduces the spread of the spectrum it preconditions
        h = dense(xa, mask, j)
        cond = np.linalg.cond(h)
        root = np.linalg.cholesky(np.linalg.inv((m + m.T) / 2))
        assert np.linalg.cond(np.linalg.solve(root, np.linalg.solve(root, h).T)) < cond


def test_diagonal_preconditioner_inverts_a_hessian_diagonal_in_its_basis():
    """In the full eigenbasis of Xa^T Xa, with every frame active (h = 2C
    everywhere) the Hessian is diagonal there: the preconditioner built from
    the curvature sums is its exact inverse; with fewer vectors it is exact
    inside their span. On numpy arrays it stays numpy (a host CG's)."""
    rng = np.random.default_rng(6)
    n, q, p, c = 40, 9, 3, 1.5
    xa = rng.normal(size=(n, q)).astype(np.float32)
    vals, vecs = np.linalg.eigh(xa.T.astype(np.float64) @ xa)
    h = np.full((n, p), 2 * c, np.float32)
    hessian = np.eye(q) + 2 * c * xa.T.astype(np.float64) @ xa
    with jax.enable_x64(True):
        for k in (q, 4):
            basis = jnp.asarray(vecs[:, ::-1][:, :k], jnp.float32)
            sums = jax.tree.map(
                lambda a: np.asarray(a, np.float64),
                curvature_sums(jnp.asarray(xa), jnp.asarray(h), basis),
            )
            apply = diagonal_preconditioner(
                np.asarray(basis, np.float64), sums, np.ones((1, p))
            )
            v = vecs[:, ::-1][:, :k] @ rng.normal(size=(k, p))  # inside the span
            got = apply(hessian @ v)
            assert isinstance(got, np.ndarray)
            np.testing.assert_allclose(got, v, rtol=2e-4)


def test_jacobi_preconditioner_divides_by_the_hessian_diagonal(system):
    xa, mask = system
    diag = curvature_sums(jnp.asarray(xa), jnp.asarray(mask), None)
    want = np.stack([np.diag(dense(xa, mask, j)) for j in range(P)], axis=1)
    np.testing.assert_allclose(LAM + np.asarray(diag), want, rtol=1e-5)
    apply = diagonal_preconditioner(None, np.asarray(diag, np.float64), LAM)
    r = RNG.normal(size=(Q, P))
    np.testing.assert_allclose(apply(r), r / want, rtol=1e-5)
