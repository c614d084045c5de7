"""One protocol, ``solver.run(init_params, *args)``: full batch and minibatch."""

from __future__ import annotations

import numpy as np
import pytest

from rhythmic_jax.solvers.newton import newton_fit
from rhythmic_jax.solvers.objective import objective, targets
from rhythmic_jax.solvers.optax_loops import ridge_start
from rhythmic_jax.solvers.protocol import (
    LBFGS,
    Minibatch,
    Newton,
    Solution,
    solver_for,
)
from rhythmic_jax.solvers.resumable import RunConfig


def data(n=60, d=16, periods=(4, 5), seed=0):
    x = np.random.default_rng(seed).normal(size=(n, d)).astype(np.float32)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    return x, np.asarray(targets(np.arange(n), periods)), 2.0


def total(params, x, y, c):
    return float(np.sum(objective(params, x, y, c)))


def test_full_batch_solvers_share_run_and_reach_the_newton_optimum():
    x, y, c = data()
    ref, _ = newton_fit(x, y, c)
    got = Newton().run(None, x, y, c)
    assert isinstance(got, Solution)
    np.testing.assert_allclose(got.params.w, ref.w, atol=1e-6)
    assert got.info.steps >= 2
    lbfgs = LBFGS(steps=200).run(None, x, y, c)
    f_ref = total(ref, x, y, c)
    # float32 templates and objective: the optimum is known to ~1e-7 relative
    assert f_ref * (1 - 1e-6) <= total(lbfgs.params, x, y, c) <= f_ref * (1 + 1e-4)
    assert len(lbfgs.info) > 1
    assert solver_for("lbfgs") == LBFGS() and solver_for("newton") == Newton()
    with pytest.raises(ValueError, match="unknown solver"):
        solver_for("sgd")


@pytest.mark.parametrize("shape", [(60, 16), (20, 70)])  # primal and span
def test_newton_warm_start_from_the_optimum_stops_at_once(shape):
    x, y, c = data(*shape)
    cold = Newton().run(None, x, y, c)
    warm = Newton().run(cold.params, x, y, c)
    assert warm.info.steps < cold.info.steps and warm.info.steps <= 2
    np.testing.assert_allclose(warm.info.objective, cold.info.objective, rtol=1e-6)


def test_minibatch_run_descends_from_its_start():
    x, y, c = data(n=64)
    init = ridge_start(x[:16], y[:16], c)
    order = np.random.default_rng(0).permutation(64)

    def batches(epoch):
        del epoch
        return [(x[order[i : i + 16]], y[order[i : i + 16]]) for i in range(0, 64, 16)]

    config = RunConfig(epochs=3, batch_size=16, learning_rate=1e-2)
    got = Minibatch(config).run(init, batches, c, 64)
    assert total(got.params, x, y, c) < total(init, x, y, c)
    assert got.info["step"] > 0
    with pytest.raises(ValueError, match="starting templates"):
        Minibatch(config).run(None, batches, c, 64)
