"""The exact line search of a Newton step, every template along its own step.

The objective is piecewise quadratic along a line for the squared hinge, so its
minimiser along the step is the root of a piecewise-linear, nondecreasing
derivative: :func:`scale_by_exact_linesearch` finds it per template as an optax
transformation, chained after :func:`rhythmic_jax.solvers.newton_cg.newton_cg`
(:func:`rhythmic_jax.solvers.newton_cg.newton_solver`). The derivatives come
from autodiff of the objective, or from a
:class:`~rhythmic_jax.solvers.newton_system.NewtonSystem` already summed (a
streamed fit's, searched on the host in numpy).

Names: q = d + 1 parameters, p templates.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import optax

from rhythmic_jax.solvers.newton_system import (
    Iterate,
    NewtonSystem,
    array_module,
    summed,
)

__all__ = ["ExactLinesearchState", "scale_by_exact_linesearch"]


class ExactLinesearchState(NamedTuple):
    """The last step size of every template (1, p) and the objective before and
    after it (p,)."""

    step_size: jax.Array
    value: jax.Array
    new_value: jax.Array



def _bracketed_root(
    slope, t0, iters: int, rtol: float = 0.0, g0=None, loop=jax.lax.while_loop
):
    """Root over t >= 0 of a continuous, piecewise-linear, nondecreasing ``phi'``.

    ``slope(t)`` returns ``phi'(t)`` and ``phi''(t)`` (1, p). From ``t0`` each
    iteration takes Newton's step on the current piece when it stays inside the
    bracket found so far, else the bracket's secant (Newton alone can cycle
    between two pieces); on the root's piece either lands on it exactly.
    A column also stops once ``|phi'(t)| <= rtol |phi'(0)|``: in floating point
    Newton's step can creep towards the root by an ulp at a time from one side
    (the bracket never closes), which would run every column to ``iters``.
    ``g0``: ``phi'(0)`` where it is known (else ``slope`` at 0 gives it);
    ``loop``: ``jax.lax.while_loop``, or
    :func:`~rhythmic_jax.solvers.newton_system.host_loop` (numpy ``t0``).
    Returns t (1, p) and ``phi'(0)``.
    """
    xp = array_module(t0)

    def body(state):
        t, lo, glo, hi, ghi, done, it = state
        g, h = slope(t)
        left = g < 0
        lo, glo = xp.where(left, t, lo), xp.where(left, g, glo)
        hi, ghi = xp.where(left, hi, t), xp.where(left, ghi, g)
        newton = t - g / xp.maximum(h, 1e-300)
        inside = (newton > lo) & (newton < hi)
        secant = lo - glo * (hi - lo) / xp.where(ghi > glo, ghi - glo, 1.0)
        new = xp.where(inside | xp.isinf(hi), newton, secant)
        narrow = xp.isfinite(hi) & (hi - lo <= 1e-12 * hi)
        flat = xp.abs(g) <= rtol * xp.abs(g0)
        stop = done | (g == 0) | (new == t) | narrow | flat
        return xp.where(stop, t, new), lo, glo, hi, ghi, stop, it + 1

    def cond(state):
        *_, done, it = state
        return xp.logical_and(it < iters, ~xp.all(done))

    zero = xp.zeros_like(t0)
    if g0 is None:
        g0, _ = slope(zero)
    state = (t0, zero, g0, xp.full_like(t0, xp.inf), zero, g0 >= 0, 0)
    t, *_ = loop(cond, body, state)
    return xp.where(g0 < 0, t, 0.0), g0


def scale_by_exact_linesearch(
    max_iterations: int = 30, rtol: float = 1e-8
) -> optax.GradientTransformationExtraArgs:
    """Scale every template's step by its exact minimiser along the step.

    ``update(updates, state, params, *, value_fn)``: ``value_fn(params)`` gives
    one objective per template (p,), each depending on its own column only.
    ``phi_j(t) = value_fn(params + t updates)_j`` is convex and piecewise
    quadratic for the squared hinge; ``phi'`` and ``phi''`` are the gradient
    and its ``jax.jvp`` along the step, dotted with the step per template (one
    forward-over-reverse pass, cheaper than differentiating ``phi`` twice
    forward). The minimiser is found by
    :func:`_bracketed_root` from t = 1 (the Newton step); a step that does not
    decrease ``phi`` becomes 0.

    ``update(updates, state, params, *, system)`` takes ``phi`` from a
    :class:`NewtonSystem`'s ``value`` and ``line`` instead (``phi'(0)`` is its
    gradient along the step), and searches in its ``loop``.
    """

    def init_fn(params: Iterate) -> ExactLinesearchState:
        p, xp = params.theta.shape[-1], array_module(params.theta)
        zero = xp.zeros((p,), params.theta.dtype)
        return ExactLinesearchState(xp.ones((1, p), params.theta.dtype), zero, zero)

    def update_fn(updates, state, params, *, value_fn=None, system=None, **extra):
        del state, extra
        if system is not None and system.line is not None:
            return _search_system(updates, system, max_iterations, rtol)
        p = params.theta.shape[-1]
        grad = jax.grad(summed(value_fn))

        def at(t):  # (1, p) -> the iterate t along the step, per template
            return jax.tree.map(lambda a, s: a + t * s, params, updates)

        def along(tree):  # (p,) inner products with the step, per template
            leaves = zip(jax.tree.leaves(tree), jax.tree.leaves(updates), strict=True)
            return sum(jnp.sum(a * s, axis=tuple(range(a.ndim - 1))) for a, s in leaves)

        def slope(t):  # phi' and phi'' from one jvp of the gradient along the step
            g, hs = jax.jvp(grad, (at(t),), (updates,))
            return along(g)[None, :], along(hs)[None, :]

        def phi(t):
            return value_fn(at(t))

        t0 = jnp.ones((1, p), params.theta.dtype)
        t, _ = _bracketed_root(slope, t0, max_iterations, rtol)
        f0, f1 = phi(jnp.zeros_like(t)), phi(t)
        worse = (f1 > f0)[None, :]
        t = jnp.where(worse, 0.0, t)
        f1 = jnp.where(worse[0], f0, f1)
        scaled = jax.tree.map(lambda s: t * s, updates)
        return scaled, ExactLinesearchState(t, f0, f1)

    return optax.GradientTransformationExtraArgs(init_fn, update_fn)


def _search_system(updates: Iterate, system: NewtonSystem, iters: int, rtol: float):
    """:func:`scale_by_exact_linesearch`'s update along ``updates.theta`` (q, p)
    with ``phi`` from ``system.line`` (one call of ``along`` per iteration)."""
    s = updates.theta
    xp = array_module(s)
    along = system.line(s)
    g0 = xp.sum(system.grad * s, axis=0, keepdims=True)
    # from 1, or from 0 where the step does not descend (it stays there): the
    # search then ends at the step lengths of its last call of ``along``
    t0 = xp.where(g0 < 0, 1.0, 0.0).astype(g0.dtype)
    t, _ = _bracketed_root(lambda t: along(t)[1:], t0, iters, rtol, g0, system.loop)
    f0 = system.value
    f1 = f0 + along(t)[0]
    worse = (f1 > f0)[None, :]
    t = xp.where(worse, 0.0, t)
    f1 = xp.where(worse[0], f0, f1)
    scaled = jax.tree.map(lambda a: t * a, updates)
    return scaled, ExactLinesearchState(t, f0, f1)
