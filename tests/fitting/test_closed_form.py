"""Closed-form templates: the direct solve, finite-difference gradients, the decode."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax import enable_x64

from rhythmic_jax.decoding.soft import soft_decode
from rhythmic_jax.fitting.closed_form import (
    place_log_scores,
    ridge_templates,
    window_periods,
)
from rhythmic_jax.solvers.objective import targets


def _direct(z, y, ridge):
    """Ridge with an unpenalised bias by numpy's solve of the normal equations."""
    n, k = z.shape
    a = np.hstack([z, np.ones((n, 1))])
    zc = z - z.mean(0)
    lam = ridge * np.trace(zc.T @ zc) / k
    pen = np.diag([lam] * k + [0.0])
    theta = np.linalg.solve(a.T @ a + pen, a.T @ y)
    return theta[:k], theta[k]


def test_ridge_templates_equal_the_direct_solve():
    rng = np.random.default_rng(0)
    z = rng.normal(size=(40, 6))
    y = np.asarray(targets(jnp.arange(40) + 3, (5, 7)), np.float64)
    with enable_x64():
        for ridge in (1e-3, 1.0, 30.0):
            t = ridge_templates(jnp.asarray(z), jnp.asarray(y), ridge)
            w, b = _direct(z, y, ridge)
            np.testing.assert_allclose(np.asarray(t.w), w, rtol=1e-8, atol=1e-10)
            np.testing.assert_allclose(np.asarray(t.b), b, rtol=1e-8, atol=1e-10)


def test_gradient_through_the_solve_matches_finite_differences():
    rng = np.random.default_rng(1)
    z0 = rng.normal(size=(30, 5))
    q = rng.normal(size=(8, 5))
    periods = (4, 5)
    with enable_x64():
        y = targets(jnp.arange(30), periods)

        def loss(z):
            t = ridge_templates(z, y, 0.5)
            s = jnp.asarray(q) @ t.w + t.b[None, :]
            p = place_log_scores(s, periods, jnp.arange(30), jnp.asarray(3.0))
            return -jnp.mean(jax.nn.log_softmax(p, axis=1)[:, :8].diagonal())

        # compiled, not op by op: the loss is evaluated 300 times
        value, grad = jax.jit(loss), jax.jit(jax.grad(loss))
        g = np.asarray(grad(jnp.asarray(z0)))
        eps = 1e-6
        fd = np.zeros_like(z0)
        for i in range(z0.shape[0]):
            for j in range(z0.shape[1]):
                e = np.zeros_like(z0)
                e[i, j] = eps
                fd[i, j] = (value(jnp.asarray(z0 + e)) - value(jnp.asarray(z0 - e))) / (
                    2 * eps
                )
    assert np.abs(g).max() > 1e-3  # the loss depends on the reference frames
    np.testing.assert_allclose(g, fd, rtol=1e-5, atol=1e-8)


def test_place_scores_are_the_soft_decode_sums():
    rng = np.random.default_rng(2)
    periods, n = (5, 7), 35
    s = jnp.asarray(rng.normal(size=(6, 12)), jnp.float32)
    got = place_log_scores(s, periods, jnp.arange(n), jnp.asarray(1.0))
    calibrated = jnp.concatenate(
        [jax.nn.log_softmax(s[:, :5], axis=1), jax.nn.log_softmax(s[:, 5:], axis=1)],
        axis=1,
    )
    ref = soft_decode(calibrated, periods, n)
    np.testing.assert_array_equal(np.asarray(got.argmax(1)), np.asarray(ref.index))
    np.testing.assert_allclose(np.asarray(got.max(1)), np.asarray(ref.score), 1e-5)


def test_window_periods_are_coprime_and_cover_the_window():
    per = window_periods(300, 2, 2)
    assert len(per) == 2 and np.gcd(*per) == 1 and per[0] * per[1] >= 300
