"""Optax loops: ridge start, full-batch L-BFGS, minibatch steps."""

from __future__ import annotations

import logging

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from rhythmic_jax.solvers.newton import newton_fit
from rhythmic_jax.solvers.objective import objective, targets, total_objective
from rhythmic_jax.solvers.optax_loops import (
    TrainState,
    _lbfgs_step,
    adam,
    fit_full_batch,
    init_state,
    minibatch_step,
    ridge_start,
)


def data(n, d, periods=(4, 5), seed=0):
    x = np.random.default_rng(seed).normal(size=(n, d)).astype(np.float32)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    return x, targets(np.arange(n), periods)


@pytest.mark.parametrize("n, d", [(40, 10), (20, 60)])
def test_ridge_start_is_the_closed_form_solution(n, d):
    x, y = data(n, d)
    c = 3.0
    params = ridge_start(x, y, c)
    xa = np.hstack([x, np.ones((n, 1), np.float32)]).astype(np.float64)
    ref = np.linalg.solve(xa.T @ xa + np.eye(d + 1) / (2 * c), xa.T @ np.asarray(y))
    np.testing.assert_allclose(np.asarray(params.w), ref[:-1], atol=2e-3)
    np.testing.assert_allclose(np.asarray(params.b), ref[-1], atol=2e-3)


def test_full_batch_lbfgs_reaches_the_newton_optimum():
    x, y = data(60, 30)
    c = 2.0
    params, history = fit_full_batch(x, y, c, progress=False)
    _, info = newton_fit(x, y, c, progress=False)
    ours = np.asarray(objective(params, jnp.asarray(x), y, c))
    np.testing.assert_allclose(ours, info.objective, rtol=1e-4)
    assert np.all(np.diff(history) <= 1e-3 * abs(history[0]))


def test_minibatch_steps_descend_and_do_not_recompile(caplog):
    x, y = data(64, 16)
    c = 1.0
    opt = optax.adam(1e-2)
    state = init_state(ridge_start(x, y, c), opt)
    start = float(jnp.sum(objective(state.params, jnp.asarray(x), y, c)))

    def compiles():
        return sum("Compiling" in r.getMessage() for r in caplog.records)

    with caplog.at_level(logging.WARNING, logger="jax"), jax.log_compiles():
        minibatch_step(state, x[:16], y[:16], c, 4.0)
        first = compiles()
        for i in range(4):
            sl = slice(16 * i, 16 * (i + 1))
            state, _ = minibatch_step(state, x[sl], y[sl], c, 4.0)
        assert compiles() == first
        minibatch_step(state, x[:8], y[:8], c, 8.0)  # a new shape compiles
        assert compiles() > first
    assert int(state.step) == 4
    end = float(jnp.sum(objective(state.params, jnp.asarray(x), y, c)))
    assert end < start


def test_the_state_carries_its_optimizer_and_equal_settings_compile_once():
    """The optimiser is a static field of the state: not a leaf, and two states
    made with the same settings (separate objects) share one compiled step; other
    settings compile again and step as plain optax does."""
    x, y = data(24, 7)  # shapes no other test compiles
    c, init = 1.5, ridge_start(x, y, 1.5)

    def fit(tx, steps=3):
        state = TrainState.create(init, tx)
        for i in range(steps):
            sl = slice(8 * i, 8 * (i + 1))
            state, _ = minibatch_step(state, x[sl], y[sl], c, 3.0)
        return state

    before = minibatch_step._cache_size()
    a, b = fit(adam(0.03)), fit(adam(0.03))
    assert minibatch_step._cache_size() == before + 1
    assert a.tx == b.tx == adam(0.03) != adam(0.1)
    assert isinstance(a.tx.tx, optax.GradientTransformation)
    arrays = jax.tree.leaves((a.params, a.opt_state, a.step))
    assert len(jax.tree.leaves(a)) == len(arrays)  # the optimiser is no leaf
    np.testing.assert_array_equal(np.asarray(a.params.w), np.asarray(b.params.w))
    assert int(a.step) == 3

    other = fit(adam(0.1))  # another key: its own compilation and its own steps
    assert minibatch_step._cache_size() == before + 2
    plain, opt = init, optax.adam(0.1)
    opt_state = opt.init(plain)
    for i in range(3):
        sl = slice(8 * i, 8 * (i + 1))
        grad = jax.grad(total_objective)(plain, x[sl], y[sl], c, 3.0)
        updates, opt_state = opt.update(grad, opt_state, plain)
        plain = optax.apply_updates(plain, updates)
    np.testing.assert_allclose(other.params.w, plain.w, rtol=1e-6, atol=1e-7)
    assert not np.allclose(np.asarray(other.params.w), np.asarray(a.params.w))


def test_two_lbfgs_fits_compile_the_step_once():
    x, y = data(28, 9)
    before = _lbfgs_step._cache_size()
    first, _ = fit_full_batch(x, y, 2.0, steps=3)
    compiled = _lbfgs_step._cache_size()
    assert before < compiled <= before + 2  # optax's initial state: weak types
    second, _ = fit_full_batch(x, y, 2.0, steps=3)
    assert _lbfgs_step._cache_size() == compiled
    np.testing.assert_array_equal(np.asarray(first.w), np.asarray(second.w))
