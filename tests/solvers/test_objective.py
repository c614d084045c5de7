"""The vmapped squared-hinge objective against numpy loops and liblinear's primal."""

from __future__ import annotations

import logging
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from sklearn.svm import LinearSVC

from rhythmic_jax.map.periods import period_offsets
from rhythmic_jax.solvers.objective import (
    Templates,
    classifier_objective,
    default_c,
    objective,
    period_errors,
    phase_predictions,
    scores,
    squared_hinge,
    targets,
    total_objective,
)

PERIODS = (3, 4, 5)
# jitted once so that the loops below do not compile every eager op per call
_one = jax.jit(classifier_objective)
_objective = jax.jit(objective)
_period_errors = jax.jit(period_errors, static_argnums=2)
_phase_predictions = jax.jit(phase_predictions, static_argnums=1)


def liblinear_primal(w, b, x, y, c, a=1.0):
    """0.5 (||w||^2 + b^2) + C sum_i a_i max(0, 1 - y_i (w . x_i + b))^2 in float64."""
    w, x, y = (np.asarray(v, np.float64) for v in (w, x, y))
    b = float(b)
    hinge = np.maximum(0.0, 1.0 - y * (x @ w + b)) ** 2
    return 0.5 * (w @ w + b * b) + c * np.sum(np.asarray(a, np.float64) * hinge)


def _problem(n=40, d=6, periods=PERIODS, seed=0):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, d)).astype(np.float32)
    labels = rng.integers(0, 3 * n, n)
    p = sum(periods)
    params = Templates(
        jnp.asarray(rng.normal(scale=0.3, size=(d, p)).astype(np.float32)),
        jnp.asarray(rng.normal(scale=0.3, size=(p,)).astype(np.float32)),
    )
    return x, labels, params


def test_targets_against_loop():
    labels = np.array([0, 1, 2, 3, 4, 5, 11, 12, 59, 60, 7, 7])
    got = np.asarray(targets(labels, PERIODS))
    assert got.shape == (len(labels), sum(PERIODS)) and got.dtype == np.float32
    want = np.empty_like(got)
    for i, lab in enumerate(labels):
        col = 0
        for t in PERIODS:
            for j in range(t):
                want[i, col] = 1.0 if lab % t == j else -1.0
                col += 1
    np.testing.assert_array_equal(got, want)
    # exactly one +1 per period per frame
    for off, t in zip(period_offsets(PERIODS), PERIODS, strict=True):
        np.testing.assert_array_equal((got[:, off : off + t] > 0).sum(1), 1)


def test_period_offsets_and_default_c():
    assert period_offsets((3, 4, 5)) == (0, 3, 7)
    assert period_offsets((7,)) == (0,)
    assert default_c(7403) == pytest.approx(math.log(7403))


@pytest.mark.parametrize("shape", [(), (7,), (3, 5), (2, 3, 4)])
def test_squared_hinge_keeps_shape_and_matches_numpy(shape):
    rng = np.random.default_rng(1)
    s = rng.normal(scale=2.0, size=shape).astype(np.float32)
    y = np.where(rng.random(shape) < 0.5, -1.0, 1.0).astype(np.float32)
    got = np.asarray(squared_hinge(jnp.asarray(s), jnp.asarray(y)))
    assert got.shape == shape
    np.testing.assert_allclose(got, np.maximum(0.0, 1.0 - y * s) ** 2, rtol=1e-6)


def test_squared_hinge_is_zero_beyond_the_margin():
    s = jnp.array([2.0, 1.0, 0.5, -3.0])
    y = jnp.array([1.0, 1.0, 1.0, -1.0])
    np.testing.assert_allclose(np.asarray(squared_hinge(s, y)), [0.0, 0.0, 0.25, 0.0])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_vmapped_objective_equals_loop_and_liblinear(seed):
    x, labels, params = _problem(seed=seed)
    y = targets(labels, PERIODS)
    c = default_c(len(x))
    got = np.asarray(_objective(params, jnp.asarray(x), y, c))
    assert got.shape == (sum(PERIODS),)
    w, b, yn = np.asarray(params.w), np.asarray(params.b), np.asarray(y)
    for j in range(sum(PERIODS)):
        one = _one(params.w[:, j], params.b[j], jnp.asarray(x), y[:, j], c)
        assert float(one) == pytest.approx(got[j], rel=1e-5)
        ref = liblinear_primal(w[:, j], b[j], x, yn[:, j], c)
        assert got[j] == pytest.approx(ref, rel=1e-5)
    assert float(total_objective(params, jnp.asarray(x), y, c)) == pytest.approx(
        got.sum(), rel=1e-5
    )


def test_frame_weight_scales_the_loss_only():
    x, labels, params = _problem(seed=3)
    x = jnp.asarray(x)
    y = targets(labels, PERIODS)
    c = 1.7
    base = np.asarray(_objective(params, x, y, c))
    reg = 0.5 * np.asarray(jnp.sum(params.w**2, 0) + params.b**2)
    scaled = np.asarray(_objective(params, x, y, c, 2.5))
    np.testing.assert_allclose(scaled - reg, 2.5 * (base - reg), rtol=1e-5)
    # per-frame weights against the numpy primal
    a = np.random.default_rng(4).random(len(labels)).astype(np.float32)
    got = np.asarray(_objective(params, x, y, c, jnp.asarray(a)))
    w, b, yn = np.asarray(params.w), np.asarray(params.b), np.asarray(y)
    for j in range(sum(PERIODS)):
        ref = liblinear_primal(w[:, j], b[j], x, yn[:, j], c, a)
        assert got[j] == pytest.approx(ref, rel=1e-5)
    # zero weight on every frame leaves the regulariser
    np.testing.assert_allclose(
        np.asarray(_objective(params, x, y, c, jnp.zeros(len(labels)))), reg, rtol=1e-6
    )


def test_gradient_matches_analytic_formula():
    x, labels, params = _problem(n=50, d=5, seed=5)
    y = targets(labels, PERIODS)
    c = 0.8
    a = np.random.default_rng(6).random(len(labels)).astype(np.float32)
    grad = jax.jit(jax.grad(total_objective))(
        params, jnp.asarray(x), y, c, jnp.asarray(a)
    )
    w, b = np.asarray(params.w, np.float64), np.asarray(params.b, np.float64)
    xn, yn = x.astype(np.float64), np.asarray(y, np.float64)
    # d/dw [C sum a (1 - y s)_+^2] = -2 C sum a y (1 - y s)_+ x
    slack = np.maximum(0.0, 1.0 - yn * (xn @ w + b))  # (n, p)
    coef = -2.0 * c * a[:, None] * yn * slack
    np.testing.assert_allclose(
        np.asarray(grad.w), w + xn.T @ coef, rtol=1e-4, atol=1e-4
    )
    np.testing.assert_allclose(
        np.asarray(grad.b), b + coef.sum(0), rtol=1e-4, atol=1e-4
    )


def test_gradient_vanishes_at_liblinear_optimum():
    # LinearSVC (intercept_scaling=1) minimises exactly classifier_objective with
    # the same C: its solution must be a stationary point of ours.
    x, labels, _ = _problem(n=60, d=4, periods=(3,), seed=7)
    y = np.asarray(targets(labels, (3,)))
    c = default_c(len(x))
    grad_fn = jax.jit(jax.grad(classifier_objective, argnums=(0, 1)))
    for j in range(3):
        svc = LinearSVC(C=c, loss="squared_hinge", tol=1e-10, max_iter=100_000)
        svc.fit(x.astype(np.float64), y[:, j])
        w = jnp.asarray(svc.coef_[0], jnp.float32)
        b = jnp.asarray(svc.intercept_[0], jnp.float32)
        gw, gb = grad_fn(w, b, jnp.asarray(x), jnp.asarray(y[:, j]), c)
        scale = 1.0 + float(jnp.abs(w).max())
        assert float(jnp.abs(gw).max()) < 2e-3 * scale * c * len(x) ** 0.5
        assert abs(float(gb)) < 2e-3 * scale * c * len(x) ** 0.5
        # and it is a minimum: random perturbations only increase the objective
        f0 = liblinear_primal(svc.coef_[0], svc.intercept_[0], x, y[:, j], c)
        rng = np.random.default_rng(j)
        for _ in range(5):
            dw = rng.normal(scale=1e-2, size=4)
            db = rng.normal(scale=1e-2)
            f1 = liblinear_primal(
                svc.coef_[0] + dw, svc.intercept_[0] + db, x, y[:, j], c
            )
            assert f1 >= f0 - 1e-9


def test_scores_and_phase_predictions_against_loop():
    x, _, params = _problem(n=30, seed=8)
    s = scores(params, jnp.asarray(x))
    np.testing.assert_allclose(
        np.asarray(s),
        x @ np.asarray(params.w) + np.asarray(params.b),
        rtol=1e-5,
        atol=1e-5,
    )
    got = np.asarray(_phase_predictions(s, PERIODS))
    assert got.shape == (30, len(PERIODS)) and got.dtype == np.int32
    sn = np.asarray(s)
    for i in range(30):
        off = 0
        for k, t in enumerate(PERIODS):
            assert got[i, k] == int(np.argmax(sn[i, off : off + t]))
            off += t


def test_phase_predictions_of_targets_are_the_phases():
    labels = np.arange(100)
    y = targets(labels, PERIODS)
    want = np.stack([labels % t for t in PERIODS], axis=1)
    np.testing.assert_array_equal(np.asarray(_phase_predictions(y, PERIODS)), want)


def test_period_errors_against_numpy_loop():
    rng = np.random.default_rng(9)
    n = 200
    labels = rng.integers(0, 1000, n)
    s = rng.normal(size=(n, sum(PERIODS))).astype(np.float32)
    # make some frames right in some periods so the errors are not all ~1 - 1/t
    s = s + 3.0 * np.asarray(targets(labels, PERIODS)) * (rng.random((n, 1)) < 0.5)
    got = np.asarray(_period_errors(jnp.asarray(s), jnp.asarray(labels), PERIODS))
    assert got.shape == (len(PERIODS),)
    want = []
    off = 0
    for t in PERIODS:
        wrong = 0
        for i in range(n):
            wrong += int(np.argmax(s[i, off : off + t])) != labels[i] % t
        want.append(wrong / n)
        off += t
    np.testing.assert_allclose(got, want, rtol=1e-6)
    assert 0.1 < got.min() and got.max() < 0.9


def test_period_errors_zero_on_targets():
    labels = jnp.arange(60)
    got = _period_errors(targets(labels, PERIODS), labels, PERIODS)
    np.testing.assert_array_equal(np.asarray(got), 0.0)


def test_jitted_gradient_step_does_not_recompile(caplog):
    traces = []

    def _gradient_step(params, x, y, c, lr):
        traces.append(1)  # runs once per trace, not per call
        grad = jax.grad(total_objective)(params, x, y, c)
        return jax.tree_util.tree_map(lambda p, g: p - lr * g, params, grad)

    step = jax.jit(_gradient_step)
    x, labels, params = _problem(n=30, seed=10)
    y = targets(labels, PERIODS)
    with caplog.at_level(logging.WARNING, logger="jax"), jax.log_compiles():
        new = step(params, jnp.asarray(x), y, 1.0, 0.01)
        first = sum(
            "Compiling jit(_gradient_step" in r.getMessage() for r in caplog.records
        )
        x2, labels2, _ = _problem(n=30, seed=11)  # same shapes, new values
        newer = step(new, jnp.asarray(x2), targets(labels2, PERIODS), 2.0, 0.02)
        second = sum(
            "Compiling jit(_gradient_step" in r.getMessage() for r in caplog.records
        )
        assert len(traces) == 1 and first == 1 and second == 1
        assert not np.allclose(np.asarray(newer.w), np.asarray(new.w))
        # a new shape does compile again: the counters are live
        x3, labels3, _ = _problem(n=31, seed=12)
        step(params, jnp.asarray(x3), targets(labels3, PERIODS), 1.0, 0.01)
        third = sum(
            "Compiling jit(_gradient_step" in r.getMessage() for r in caplog.records
        )
    assert len(traces) == 2 and third == 2
