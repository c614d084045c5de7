"""The exact line search finds each template's minimum along its step, against a
fine grid."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax.solvers.exact_linesearch import scale_by_exact_linesearch
from rhythmic_jax.solvers.newton_system import Iterate


def test_line_search_finds_the_minimum_along_the_step():
    """Against a fine grid on [0, 3]: the piecewise-quadratic objective along a
    step, with many kinks (so Newton's method alone could cycle between pieces)."""

    rng = np.random.default_rng(0)
    n, p = 400, 16
    y = np.where(rng.random((n, p)) < 0.1, 1.0, -1.0)
    m = rng.normal(size=(n, p)) - 0.5 * y
    u = rng.normal(size=(n, p)) * 2.0 + 0.7 * y
    a, b, cc = (
        rng.random((1, p)) * 50,
        rng.normal(size=(1, p)) * 5,
        rng.random((1, p)) * 3,
    )
    c = 1.7

    def phi(t):  # t (k, 1, p) -> (k, p)
        h = np.maximum(0.0, 1.0 - y * (m + t * u))
        return 0.5 * (a + 2 * t * b + t * t * cc)[:, 0] + c * np.sum(h * h, axis=1)

    def value_fn(it):  # theta (1, p) is the step length along the line
        h = jnp.maximum(0.0, 1.0 - y * it.margins)
        t = it.theta
        return 0.5 * (a + 2 * t * b + t * t * cc)[0] + c * jnp.sum(h * h, axis=0)

    with jax.enable_x64(True):
        search = scale_by_exact_linesearch()
        start = Iterate(jnp.zeros((1, p)), jnp.asarray(m))
        step = Iterate(jnp.ones((1, p)), jnp.asarray(u))
        _, state = search.update(step, search.init(start), start, value_fn=value_fn)
        t, f = np.asarray(state.step_size), np.asarray(state.new_value)
    # the grid's minimum per column, 30 steps at a time (the whole (30001, n, p)
    # grid at once is 1.5 GB a temporary; the minimum is the same to the bit)
    steps = np.linspace(0.0, 3.0, 30001)[:, None, None]
    lowest = np.min([phi(s).min(axis=0) for s in np.array_split(steps, 1000)], axis=0)
    np.testing.assert_allclose(f, phi(t[None])[0], rtol=1e-12)
    assert np.all(f <= lowest + 1e-9 * np.abs(lowest))
    assert np.all(t > 0) and np.all(f < phi(np.zeros((1, 1, p)))[0])
    # stopping at a slope of 1e-8 of the start's (not only at an exact root)
    # gives the same minimum to rounding
    with jax.enable_x64(True):
        exact = scale_by_exact_linesearch(rtol=0.0)
        _, ref = exact.update(step, exact.init(start), start, value_fn=value_fn)
    np.testing.assert_allclose(f, np.asarray(ref.new_value), rtol=1e-13)
    np.testing.assert_allclose(t, np.asarray(ref.step_size), rtol=1e-6)

