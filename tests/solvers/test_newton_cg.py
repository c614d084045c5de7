"""Newton-CG as optax transformations: its derivatives are the objective's, and
driven through optax's init/update it reaches liblinear's optimum."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from rhythmic_jax.solvers.newton_cg import (
    Iterate,
    derivatives,
    newton_cg,
    newton_solver,
    round_design,
)
from rhythmic_jax.solvers.objective import (
    Templates,
    margin_objectives,
    targets,
    total_objective,
)
from rhythmic_jax.solvers.precondition import spectral_setup


def problem(n=90, d=12, periods=(4, 5), seed=0):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, d))
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.asarray(targets(np.arange(n), periods), np.float64)
    return x, y, 1.7


def design(x):
    return np.concatenate([x, np.ones((len(x), 1))], axis=1)


def start(xa, y, seed=1):
    theta = np.random.default_rng(seed).normal(size=(xa.shape[1], y.shape[1]))
    return Iterate(jnp.asarray(theta), jnp.asarray(xa @ theta))


def margin_value(y, c):
    """The templates' objectives at an Iterate's theta and margins: (p,)."""
    return lambda p: margin_objectives(p.theta, p.margins, jnp.asarray(y), c)


def test_gradient_and_hvp_equal_jax_grad_of_the_objective_and_differences():
    x, y, c = problem()
    xa = design(x)
    with jax.enable_x64(True):
        it = start(xa, y)

        value_fn = margin_value(y, c)

        def f(theta):  # the vmapped objective of the templates, summed
            w, b = theta[:-1], theta[-1]
            return total_objective(Templates(w, b), jnp.asarray(x), jnp.asarray(y), c)

        grad = jax.grad(lambda p: jnp.sum(value_fn(p)))(it)
        g, hvp, weight, lam = derivatives(value_fn, grad, it, jnp.asarray(xa))
        np.testing.assert_allclose(g, jax.grad(f)(it.theta), rtol=1e-10)
        v = np.random.default_rng(2).normal(size=it.theta.shape)
        hv, xv = hvp(jnp.asarray(v))
        np.testing.assert_allclose(xv, xa @ v, rtol=1e-10)
        jvp = jax.jvp(jax.grad(f), (it.theta,), (jnp.asarray(v),))[1]
        np.testing.assert_allclose(hv, jvp, rtol=1e-9)
        # the products CG takes, of the system divided by the loss's curvature
        scaled, _ = hvp(jnp.asarray(v), 1 / (2 * c))
        np.testing.assert_allclose(scaled, jvp / (2 * c), rtol=1e-9)
        eps = 1e-6  # a piecewise quadratic: central differences are exact off kinks
        fd = (jax.grad(f)(it.theta + eps * v) - jax.grad(f)(it.theta - eps * v)) / (
            2 * eps
        )
        np.testing.assert_allclose(hv, fd, rtol=1e-5, atol=1e-6)
        # the generalised Hessian of the squared hinge: 2C on active frames only
        active = y * np.asarray(it.margins) < 1
        np.testing.assert_array_equal(weight, np.where(active, 2 * c, 0.0))
        assert float(lam) == 1.0


@pytest.mark.parametrize("search", ["exact", "zoom"])
def test_optax_loop_reaches_the_linearsvc_optimum(search, liblinear_objectives):
    """The transformation driven as any optax optimiser: init, update with
    ``value_fn``, apply_updates. Chained with the exact per-template search (the
    default) or with optax's zoom line search (one step size for all)."""
    x, y, c = problem(seed=3)
    xa = design(x)
    ref = liblinear_objectives(x, y, c)
    with jax.enable_x64(True):
        yj = jnp.asarray(y)
        xa32 = jnp.asarray(xa, jnp.float32)
        spectral = spectral_setup(xa32, 8, 2, jax.random.key(0))
        if search == "exact":
            opt = newton_solver(eta=1e-3)

            def value_fn(p):
                return margin_objectives(p.theta, p.margins, yj, c)

        else:
            opt = optax.chain(newton_cg(eta=1e-3), optax.scale_by_zoom_linesearch(20))

            def value_fn(p, design=None, spectral=None):  # zoom hands its extra
                # arguments on to value_fn, so it names newton_cg's
                return jnp.sum(margin_objectives(p.theta, p.margins, yj, c))

        @jax.jit
        def step(params, state):
            value, grad = jax.value_and_grad(lambda p: jnp.sum(value_fn(p)))(params)
            updates, state = opt.update(
                grad, state, params, value=value, grad=grad, value_fn=value_fn,
                design=xa32, spectral=spectral,
            )  # fmt: skip
            return optax.apply_updates(params, updates), state

        params = Iterate(jnp.zeros((xa.shape[1], y.shape[1])), jnp.zeros_like(yj))
        state = opt.init(params)
        for _ in range(30):
            params, state = step(params, state)
        got = np.asarray(margin_objectives(params.theta, xa @ params.theta, yj, c))
        np.testing.assert_allclose(params.margins, xa @ params.theta, atol=1e-4)
    np.testing.assert_allclose(got, ref, rtol=1e-6)
    assert np.all(state[0].decrement <= 1e-8 * got)


def _float32_problem(**shape):
    """A problem at a random start, with its float32 design: ``(x32, it,
    value_fn, grad)``; call under ``jax.enable_x64``."""
    x, y, c = problem(**shape)
    xa = design(x)
    it = start(xa, y)
    value_fn = margin_value(y, c)
    grad = jax.grad(lambda p: jnp.sum(value_fn(p)))(it)
    return jnp.asarray(xa, jnp.float32), it, value_fn, grad


def test_float32_gradient_sum_is_the_float64_one_to_single_precision():
    """``exact_gradient=False`` (``FAST``) sums the gradient's product over frames
    in float32: the same gradient to single precision, the same Hessian."""
    with jax.enable_x64(True):
        x32, it, value_fn, grad = _float32_problem()
        g64, hvp64, *_ = derivatives(value_fn, grad, it, x32)
        g32, hvp32, *_ = derivatives(value_fn, grad, it, x32, exact_gradient=False)
        assert g32.dtype == g64.dtype
        scale = np.linalg.norm(np.asarray(g64), axis=0)
        err = np.linalg.norm(np.asarray(g32) - np.asarray(g64), axis=0)
        assert np.all(err <= 1e-5 * scale), (err / scale).max()
        assert np.any(err > 0)  # it did sum in float32
        v = jnp.asarray(np.random.default_rng(2).normal(size=it.theta.shape))
        np.testing.assert_array_equal(hvp32(v)[0], hvp64(v)[0])


def test_bfloat16_hessian_products_round_only_the_directions():
    """``hessian_dtype=bfloat16`` rounds the Hessian's products to bfloat16's 8
    bits (~4e-3 relative, not float32's 1e-7) and keeps no margins of them; the
    gradient is untouched, and a Newton step's margins are ``Xa s`` exactly."""
    with jax.enable_x64(True):
        x32, it, value_fn, grad = _float32_problem(n=300, d=40)
        g32, hvp32, *_ = derivatives(value_fn, grad, it, x32)
        pair = round_design(x32, jnp.bfloat16)
        assert pair[1].shape == x32.T.shape and pair[1].dtype == jnp.bfloat16
        g16, hvp16, *_ = derivatives(value_fn, grad, it, x32, True, pair)
        np.testing.assert_array_equal(g16, g32)
        v = jnp.asarray(np.random.default_rng(2).normal(size=it.theta.shape))
        (h32, xv32), (h16, xv16) = hvp32(v), hvp16(v)
        assert xv32 is not None and xv16 is None
        assert h16.dtype == jnp.float32
        err = np.linalg.norm(np.asarray(h16) - np.asarray(h32)) / np.linalg.norm(h32)
        assert 1e-5 < err < 2e-2, err

        spectral = spectral_setup(x32, 20, 3, jax.random.PRNGKey(0))
        opt = newton_cg(eta=1e-3)
        step, _ = opt.update(
            grad, opt.init(it), it, value_fn=value_fn, design=x32, spectral=spectral,
            rounded=pair,
        )  # fmt: skip
        np.testing.assert_allclose(
            step.margins, np.asarray(x32, np.float64) @ np.asarray(step.theta),
            rtol=1e-5, atol=1e-6,
        )  # fmt: skip
