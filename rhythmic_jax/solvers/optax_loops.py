"""Optimiser loops over the one objective: full-batch and minibatch, with optax.

Both loops minimise :func:`rhythmic_jax.objective.total_objective`, the vmapped
squared hinge of every template. The full-batch loop runs optax L-BFGS from the
closed-form ridge start (with every margin active the squared hinge is a ridge
problem); the minibatch loop takes optax steps on frames that arrive in batches
(augmented on the fly, or streamed from disk), weighting each batch by
``n / batch`` so its gradient is unbiased. The exact solver beside them is
:func:`rhythmic_jax.solvers.newton.newton_fit`.

State is explicit: :class:`TrainState` in, :class:`TrainState` out.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from rhythmic_jax.objective import Templates, total_objective
from rhythmic_jax.progress import bar
from rhythmic_jax.solvers.span import in_span

__all__ = [
    "TrainState",
    "fit_full_batch",
    "init_state",
    "minibatch_step",
    "ridge_start",
]


class TrainState(NamedTuple):
    """Parameters, optimiser state and the number of steps taken."""

    params: Templates
    opt_state: optax.OptState
    step: jax.Array


def ridge_start(x: jax.Array, y: jax.Array, c: float) -> Templates:
    """Closed-form optimum with every margin active: a ridge regression to ±1.

    Solves ``(lam I + Xa^T Xa) theta = Xa^T y`` with ``Xa = [x, 1]``,
    ``lam = 1 / (2C)``; in the Gram form ``(Xa Xa^T + lam I) alpha = y`` when the
    frames are solved in their span (:func:`rhythmic_jax.solvers.span.in_span`).
    Shapes: x (n, d), y (n, p) -> w (d, p), b (p,).
    """
    x = jnp.asarray(x, jnp.float32)
    n, d = x.shape
    xa = jnp.concatenate([x, jnp.ones((n, 1), x.dtype)], axis=1)
    lam = 0.5 / c
    if in_span(n, d):
        g = xa @ xa.T
        alpha = jax.scipy.linalg.solve(g + lam * jnp.eye(n), y, assume_a="pos")
        theta = xa.T @ alpha
    else:
        g = xa.T @ xa
        theta = jax.scipy.linalg.solve(
            g + lam * jnp.eye(d + 1), xa.T @ y, assume_a="pos"
        )
    return Templates(w=theta[:-1], b=theta[-1])


@functools.lru_cache(maxsize=32)
def adam(learning_rate: float) -> optax.GradientTransformation:
    """``optax.adam``, one object per learning rate: the jitted steps take the
    optimiser as a static argument, so a fresh object would recompile them."""
    return optax.adam(learning_rate)


def init_state(
    params: Templates, optimizer: optax.GradientTransformation
) -> TrainState:
    """Fresh :class:`TrainState` at ``params``."""
    return TrainState(params, optimizer.init(params), jnp.zeros((), jnp.int32))


@functools.partial(jax.jit, static_argnames=("optimizer",))
def minibatch_step(
    state: TrainState,
    x: jax.Array,
    y: jax.Array,
    c: float,
    scale: float,
    optimizer: optax.GradientTransformation,
) -> tuple[TrainState, jax.Array]:
    """One optax step on a batch: x (m, d), y (m, p); ``scale = n / m``.

    Returns the new state and the batch estimate of the joint objective.
    """
    loss, grad = jax.value_and_grad(total_objective)(state.params, x, y, c, scale)
    updates, opt_state = optimizer.update(grad, state.opt_state, state.params)
    params = optax.apply_updates(state.params, updates)
    return TrainState(params, opt_state, state.step + 1), loss


@functools.partial(jax.jit, static_argnames=("optimizer",))
def _lbfgs_step(state: TrainState, x, y, c, optimizer):
    def fun(params):
        return total_objective(params, x, y, c)

    value_and_grad = optax.value_and_grad_from_state(fun)
    value, grad = value_and_grad(state.params, state=state.opt_state)
    updates, opt_state = optimizer.update(
        grad, state.opt_state, state.params, value=value, grad=grad, value_fn=fun
    )
    params = optax.apply_updates(state.params, updates)
    return TrainState(params, opt_state, state.step + 1), value


def fit_full_batch(
    x: jax.Array,
    y: jax.Array,
    c: float,
    *,
    steps: int = 300,
    tol: float = 1e-7,
    init: Templates | None = None,
    optimizer: optax.GradientTransformation | None = None,
    progress: bool = False,
) -> tuple[Templates, np.ndarray]:
    """Full-batch optax L-BFGS on the joint objective from the ridge start.

    Args:
      x: (n, d) frames; y: (n, p) ±1 targets; c: penalty.
      steps: most iterations; tol: stop when the objective's relative decrease
        over 10 steps falls below it.
      init: start (default :func:`ridge_start`).
      optimizer: an optax transformation supporting ``value_fn`` (default
        ``optax.lbfgs()``).

    Returns:
      The templates and the objective after every step, (steps_taken,).
    """
    x = jnp.asarray(x, jnp.float32)
    y = jnp.asarray(y, jnp.float32)
    optimizer = optimizer or optax.lbfgs()
    state = init_state(init if init is not None else ridge_start(x, y, c), optimizer)
    history: list[float] = []
    for _ in bar(range(steps), show=progress, desc="l-bfgs"):
        state, value = _lbfgs_step(state, x, y, c, optimizer)
        history.append(float(value))
        if len(history) > 10 and history[-11] - history[-1] <= tol * abs(history[-1]):
            break
    return state.params, np.asarray(history)
