"""Optimiser loops over the one objective: full-batch and minibatch, with optax.

Both loops minimise :func:`rhythmic_jax.solvers.objective.total_objective`, the vmapped
squared hinge of every template. The full-batch loop runs optax L-BFGS from the
closed-form ridge start (with every margin active the squared hinge is a ridge
problem); the minibatch loop takes optax steps on frames that arrive in batches
(augmented on the fly, or streamed from disk), weighting each batch by
``n / batch`` so its gradient is unbiased. The exact solver beside them is
:func:`rhythmic_jax.solvers.newton.newton_fit`.

State is explicit: :class:`TrainState` in, :class:`TrainState` out. As in flax's
``TrainState``, the state carries its optimiser (a static field of the pytree,
:class:`Optimizer`) and :meth:`TrainState.apply_gradients` takes a step with it,
so the jitted steps take the state alone. An :class:`Optimizer` compares by the
settings that made it (:func:`adam`, :func:`lbfgs`), so two fits with the same
settings share one compiled step.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Hashable
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax

from rhythmic_jax.jit_options import jit
from rhythmic_jax.progress import bar
from rhythmic_jax.solvers.objective import Templates, total_objective
from rhythmic_jax.solvers.span import in_span

__all__ = [
    "Optimizer",
    "TrainState",
    "adam",
    "fit_full_batch",
    "init_state",
    "lbfgs",
    "minibatch_step",
    "ridge_start",
]


@dataclass(frozen=True, eq=False)
class Optimizer:
    """An optax transformation and the settings that made it.

    Two optimisers are equal when their ``key`` is (a hashable description of
    the transformation, e.g. ``("adam", 0.01)``): a jitted step whose state
    carries one compiles once per key, not once per object. Wrapping a plain
    transformation (:meth:`of`) keys it by the object itself.
    """

    tx: optax.GradientTransformation
    key: Hashable

    @classmethod
    def of(cls, tx: optax.GradientTransformation | Optimizer) -> Optimizer:
        """``tx`` as an :class:`Optimizer` (keyed by itself unless it is one)."""
        return tx if isinstance(tx, Optimizer) else cls(tx, tx)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Optimizer) and self.key == other.key

    def __hash__(self) -> int:
        return hash(self.key)

    def init(self, params) -> optax.OptState:
        return self.tx.init(params)

    def update(self, updates, state, params=None, **extra_args):
        return self.tx.update(updates, state, params, **extra_args)


def adam(learning_rate: float) -> Optimizer:
    """``optax.adam(learning_rate)``, keyed by its learning rate."""
    return Optimizer(optax.adam(learning_rate), ("adam", float(learning_rate)))


def lbfgs() -> Optimizer:
    """``optax.lbfgs()`` with its default settings."""
    return Optimizer(optax.lbfgs(), ("lbfgs",))


@functools.partial(
    jax.tree_util.register_dataclass,
    data_fields=["params", "opt_state", "step"],
    meta_fields=["tx"],
)
@dataclass(frozen=True)
class TrainState:
    """Parameters, optimiser state, the number of steps taken and the optimiser
    (static: part of the tree's structure, not a leaf)."""

    params: Templates
    opt_state: optax.OptState
    step: jax.Array
    tx: Optimizer

    @classmethod
    def create(
        cls, params: Templates, tx: optax.GradientTransformation | Optimizer
    ) -> TrainState:
        """Fresh state at ``params``, the optimiser's state initialised."""
        tx = Optimizer.of(tx)
        return cls(params, tx.init(params), jnp.zeros((), jnp.int32), tx)

    def apply_gradients(self, grads: Templates, **extra_args: Any) -> TrainState:
        """One optimiser step: the update of ``grads`` applied to the parameters;
        ``extra_args`` go to the transformation (``value=``, ``value_fn=``, ...)."""
        updates, opt_state = self.tx.update(
            grads, self.opt_state, self.params, **extra_args
        )
        params = optax.apply_updates(self.params, updates)
        return dataclasses.replace(
            self, params=params, opt_state=opt_state, step=self.step + 1
        )


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
        g = jnp.matmul(xa, xa.T, precision="highest")
        alpha = jax.scipy.linalg.solve(g + lam * jnp.eye(n), y, assume_a="pos")
        theta = jnp.matmul(xa.T, alpha, precision="highest")
    else:
        g = jnp.matmul(xa.T, xa, precision="highest")
        theta = jax.scipy.linalg.solve(
            g + lam * jnp.eye(d + 1),
            jnp.matmul(xa.T, y, precision="highest"),
            assume_a="pos",
        )
    return Templates(w=theta[:-1], b=theta[-1])


def init_state(
    params: Templates, optimizer: optax.GradientTransformation | Optimizer
) -> TrainState:
    """Fresh :class:`TrainState` at ``params`` (:meth:`TrainState.create`)."""
    return TrainState.create(params, optimizer)


@jit
def minibatch_step(
    state: TrainState, x: jax.Array, y: jax.Array, c: float, scale: float
) -> tuple[TrainState, jax.Array]:
    """One step of the state's optimiser on a batch: x (m, d), y (m, p);
    ``scale = n / m``.

    Returns the new state and the batch estimate of the joint objective.
    """
    loss, grad = jax.value_and_grad(total_objective)(state.params, x, y, c, scale)
    return state.apply_gradients(grad), loss


@jit
def _lbfgs_step(state: TrainState, x, y, c):
    def fun(params):
        return total_objective(params, x, y, c)

    value_and_grad = optax.value_and_grad_from_state(fun)
    value, grad = value_and_grad(state.params, state=state.opt_state)
    state = state.apply_gradients(grad, value=value, grad=grad, value_fn=fun)
    return state, value


def fit_full_batch(
    x: jax.Array,
    y: jax.Array,
    c: float,
    *,
    steps: int = 300,
    tol: float = 1e-7,
    init: Templates | None = None,
    optimizer: optax.GradientTransformation | Optimizer | None = None,
    progress: bool = False,
) -> tuple[Templates, np.ndarray]:
    """Full-batch optax L-BFGS on the joint objective from the ridge start.

    Args:
      x: (n, d) frames; y: (n, p) ±1 targets; c: penalty.
      steps: most iterations; tol: stop when the objective's relative decrease
        over 10 steps falls below it.
      init: start (default :func:`ridge_start`).
      optimizer: an optax transformation supporting ``value_fn``, or an
        :class:`Optimizer` of one (default :func:`lbfgs`).

    Returns:
      The templates and the objective after every step, (steps_taken,).
    """
    x = jnp.asarray(x, jnp.float32)
    y = jnp.asarray(y, jnp.float32)
    optimizer = lbfgs() if optimizer is None else optimizer
    state = init_state(init if init is not None else ridge_start(x, y, c), optimizer)
    history: list[float] = []
    for _ in bar(range(steps), show=progress, desc="l-bfgs"):
        state, value = _lbfgs_step(state, x, y, c)
        history.append(float(value))
        if len(history) > 10 and history[-11] - history[-1] <= tol * abs(history[-1]):
            break
    return state.params, np.asarray(history)
