"""Newton-CG as optax transformations over the one objective.

The iterate is :class:`Iterate`: every template's parameters ``theta`` (q, p) with
their margins ``m = Xa theta`` (n, p) kept in step (the design ``Xa = [X, 1]``,
q = d + 1). The objective is passed as optax's ``value_fn``: a function of the
iterate, :func:`rhythmic_jax.solvers.objective.margin_objectives` (one value per
template;
their sum is minimised; a scalar works too). Everything the solver needs of it
comes from autodiff:

- the gradient: ``jax.grad`` of ``value_fn`` gives ``(d/dtheta, d/dm)``; the
  chain rule through ``m = Xa theta`` makes it ``g = d/dtheta + Xa^T d/dm``;
- Hessian-vector products: ``jax.linearize`` of that gradient, applied to
  ``(v, Xa v)`` and pulled back by ``Xa^T`` (the squared hinge's second
  derivative is its generalised Hessian,
  ``rhythmic_jax.solvers.objective.squared_hinge``);
- the line search: the gradient and its ``jax.jvp`` along the step.

:func:`newton_cg` turns the gradient into the Newton step by preconditioned
conjugate gradients (Chapelle, "Training a support vector machine in the primal",
2007), stopping per template at ``||r|| <= eta ||g||``, and returns the step with
its margins (``Xa s``, accumulated from CG's own products). It is chained with
:func:`scale_by_exact_linesearch`, the exact minimiser along the step of every
template separately (the objective is piecewise quadratic along a line). optax's
``scale_by_zoom_linesearch`` takes one step size for the whole tree, i.e. one for
every template, and also chains after :func:`newton_cg` (tested); the exact
per-template search takes fewer Newton steps and is the default.

Both transformations also take the system already summed
(:class:`NewtonSystem`, the ``system`` argument): the gradient, Hessian-vector
products and the objective along a step given as functions, e.g. passes over
frames read from disk in blocks (:mod:`rhythmic_jax.solvers.streamed`). Run by
:func:`host_loop` over numpy arrays, CG and the line search are the same code in
float64 numpy on the host, and compile no program.

The iterate, the system and the host loop are defined in
:mod:`rhythmic_jax.solvers.newton_system`, the line search in
:mod:`rhythmic_jax.solvers.exact_linesearch`; both are importable from here.

Names: n frames, q = d + 1 parameters, p templates.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax

from rhythmic_jax.solvers.exact_linesearch import (
    ExactLinesearchState as ExactLinesearchState,
)
from rhythmic_jax.solvers.exact_linesearch import (
    scale_by_exact_linesearch as scale_by_exact_linesearch,
)
from rhythmic_jax.solvers.newton_system import Iterate as Iterate
from rhythmic_jax.solvers.newton_system import NewtonSystem as NewtonSystem
from rhythmic_jax.solvers.newton_system import array_module, summed
from rhythmic_jax.solvers.newton_system import host_loop as host_loop
from rhythmic_jax.solvers.precondition import block_preconditioner

__all__ = [
    "bucket",
    "ExactLinesearchState",
    "derivatives",
    "host_loop",
    "round_design",
    "in_memory_system",
    "Iterate",
    "NewtonCGState",
    "NewtonSystem",
    "newton_cg",
    "newton_solver",
    "scale_by_exact_linesearch",
]


class NewtonCGState(NamedTuple):
    """Steps taken, each template's last Newton decrement (p,) (the model's
    predicted decrease ``-0.5 g . s``, an estimate of ``f - f*``) and the CG
    iterations of the last step."""

    count: jax.Array
    decrement: jax.Array
    cg_iterations: jax.Array


def bucket(live: int, p: int) -> int:
    """Columns to gather for ``live`` templates: p, or a power of two below it
    (few distinct shapes, so few compilations)."""
    size = 8
    while size < live:
        size *= 2
    return min(size, p)


def _cg(hvp, precond, r0, eta, max_iter, loop=jax.lax.while_loop):
    """Preconditioned CG from 0 for ``H s = r0``, every column (template) at once.

    ``hvp`` maps (q, p) to ``(H v, Xa v)``, or to ``(H v, None)`` where the
    margins are not kept (a streamed fit). Column j stops when
    ``||r_j|| <= eta ||r0_j||``. ``loop`` runs it: ``jax.lax.while_loop``, or
    :func:`host_loop` where every product is a pass over files (with ``r0`` a
    numpy array, in numpy). Returns the step ``s`` (q, p), its margins ``Xa s``
    (n, p) (accumulated from the products, no extra product; None without
    margins) and the number of iterations.
    """
    xp = array_module(r0)
    target = eta * xp.linalg.norm(r0, axis=0, keepdims=True)
    z = precond(r0)
    rz = xp.sum(r0 * z, axis=0, keepdims=True)
    if loop is jax.lax.while_loop:
        _, xz = jax.eval_shape(hvp, r0)
        zero_u = None if xz is None else jnp.zeros(xz.shape, xz.dtype)
    else:
        zero_u = None

    def live(r):
        return xp.linalg.norm(r, axis=0, keepdims=True) > target

    def cond(state):
        *_, r, _, _, it = state
        return xp.logical_and(it < max_iter, xp.any(live(r)))

    def body(state):
        s, u, r, d, rz, it = state
        on = live(r)
        ad, xd = hvp(d)
        dad = xp.sum(d * ad, axis=0, keepdims=True)
        step = xp.where(on, rz / xp.where(dad > 0, dad, 1.0), 0.0)
        s, r = s + step * d, r - step * ad
        u = None if xd is None else u + step * xd
        z = precond(r)
        rz_new = xp.sum(r * z, axis=0, keepdims=True)
        beta = rz_new / xp.where(rz > 0, rz, 1.0)
        d = xp.where(on, z + beta * d, d)
        return s, u, r, d, xp.where(on, rz_new, rz), it + 1

    init = (xp.zeros_like(r0), zero_u, r0, z, rz, xp.int32(0))
    s, u, *_, it = loop(cond, body, init)
    return s, u, it


def in_memory_system(
    value_fn, grad: Iterate, params: Iterate, design, spectral, block,
    exact_gradient: bool = True, rounded=None,
):  # fmt: skip
    """:class:`NewtonSystem` of ``value_fn`` at ``params`` with every frame's
    margins in memory: :func:`derivatives` and the spectral block preconditioner
    (:func:`rhythmic_jax.solvers.precondition.block_preconditioner`).

    CG solves ``H s = -g`` divided by the loss's largest curvature (2C for the
    squared hinge): active frames weigh 1 and the regulariser 1 / (2C). The step
    is the same in exact arithmetic, but not in float32, where the
    preconditioner's leading block rounds differently at each scale (~1e-3 on
    the first step); at this one it rounds as the solver was measured with.
    ``exact_gradient``, ``rounded``: see :func:`derivatives`.
    """
    f32 = design.dtype
    g, hvp, weight, lam = derivatives(
        value_fn, grad, params, design, exact_gradient, rounded
    )
    top = jnp.max(weight)
    scale = 1.0 / jnp.where(top > 0, top, 1.0)
    precond = block_preconditioner(
        *spectral, (weight * scale).astype(f32), (lam * scale).astype(f32), block
    )
    return NewtonSystem(g, lambda v: hvp(v, scale), precond, scale, f32)


def newton_cg(
    eta: float = 0.1, max_cg: int = 200, block: int = 32, exact_gradient: bool = True
) -> optax.GradientTransformationExtraArgs:
    """The Newton step of every template, by preconditioned CG.

    ``update(grad, state, params, *, value_fn, design, spectral, max_cg=None,
    rounded=None)``:
    ``grad`` is ``jax.grad`` of ``value_fn`` at ``params`` (an :class:`Iterate`),
    ``design`` the (n, q) float32 ``Xa``, ``spectral`` the preconditioner's
    ``(vecs, lead, rest)`` (:func:`rhythmic_jax.solvers.precondition.spectral_setup`)
    , ``max_cg`` (traced) caps CG for this step and ``rounded``, optionally, the
    design rounded for CG's products (:func:`derivatives`). Returns the step as an
    :class:`Iterate` ``(s, Xa s)`` and the new :class:`NewtonCGState`.

    ``update(grad, state, params, *, system, max_cg=None)`` instead takes the
    system already summed (:class:`NewtonSystem`: a streamed fit's, whose
    products are passes over blocks of frames; ``grad`` is then unused); the
    step's margins are then None. In memory the step's margins come from CG's
    products, or, where those are rounded (``rounded``), from one product
    ``Xa s`` in the design's dtype. With numpy arrays (``params.theta`` and the
    system's) the state and step are numpy arrays too.

    Args:
      eta: CG forcing term (relative residual at which a template stops).
      max_cg: default cap on CG iterations.
      block: leading eigen-directions the preconditioner inverts exactly.
      exact_gradient: sum the gradient over frames in the iterate's dtype
        (float64) rather than the design's (see :func:`derivatives`).
    """

    def init_fn(params: Iterate) -> NewtonCGState:
        p, xp = params.theta.shape[-1], array_module(params.theta)
        return NewtonCGState(
            count=xp.zeros([], xp.int32),
            decrement=xp.full((p,), xp.inf, params.theta.dtype),
            cg_iterations=xp.zeros([], xp.int32),
        )

    def update_fn(
        updates: Iterate,
        state: NewtonCGState,
        params: Iterate,
        *,
        value_fn=None,
        design: jax.Array | None = None,
        spectral: tuple[jax.Array, jax.Array, jax.Array] | None = None,
        system: NewtonSystem | None = None,
        max_cg: Any = max_cg,
        rounded=None,
        **extra_args,
    ) -> tuple[Iterate, NewtonCGState]:
        del extra_args
        if system is None:
            system = in_memory_system(
                value_fn, updates, params, design, spectral, block, exact_gradient,
                rounded,
            )  # fmt: skip
        dtype = params.theta.dtype
        r0 = -(system.grad * system.scale).astype(system.dtype)
        s, u, it = _cg(system.hvp, system.precond, r0, eta, max_cg, system.loop)
        if u is None and design is not None:  # CG's products were rounded
            u = jnp.matmul(design, s, precision="highest")
        s = s.astype(dtype)
        u = None if u is None else u.astype(dtype)
        decrement = 0.5 * array_module(s).sum(-system.grad * s, axis=0)
        new_state = NewtonCGState(state.count + 1, decrement, it)
        return Iterate(s, u), new_state

    return optax.GradientTransformationExtraArgs(init_fn, update_fn)


def derivatives(
    value_fn,
    grad: Iterate,
    params: Iterate,
    design: jax.Array,
    exact_gradient: bool = True,
    rounded=None,
):
    """What Newton-CG needs of the objective, by autodiff, at ``params``.

    Args:
      value_fn: the objective of an :class:`Iterate` (summed if it gives one
        value per template).
      grad: ``jax.grad`` of it at ``params``: ``(d/dtheta, d/dm)``.
      params: the iterate, theta (q, p) and margins (n, p) (float64 or 32).
      design: ``Xa`` (n, q), the product's dtype (float32).
      exact_gradient: sum the gradient's product over frames in the iterate's
        dtype (float64), so the optimum does not move with the order of the
        sum; False: in the design's (float32), a cheaper product exact to
        ~1e-6 relative, which a solve to a 1e-3 gap does not see
        (``reports/solver.md`` runs ``FAST`` so).
      rounded: None, or the design rounded for the Hessian's two products,
        ``(Xa, Xa^T)`` as (n, q) and (q, n) arrays of a narrower dtype
        (:func:`round_design`): the vectors are rounded to it too and the
        products summed in the design's dtype. In bfloat16 (8 bits of
        mantissa) that is half the time of a float32 product where the CPU
        multiplies bfloat16 natively
        (:func:`rhythmic_jax.solvers.precision.native_bfloat16`), with CG's
        directions off by ~1e-3, which the exact line search and a 1e-3 gap
        do not see; the gradient, the margins and the line search keep their
        dtypes. The transposed copy is stored because XLA's CPU bfloat16
        product of a transposed operand takes a slower kernel than one of a
        row-major operand.

    Returns:
      ``g`` (q, p): the gradient in theta, ``d/dtheta + Xa^T d/dm`` (the chain
      rule through ``m = Xa theta``); ``hvp``: ``(v (q, p), scale=1)`` ->
      ``(scale H v, Xa v)`` in the design's dtype (``Xa v`` None where
      ``rounded``), H the (generalised) Hessian in theta
      (scaled before the cast); the Hessian's diagonal in the margins (n, p)
      and its (mean) curvature in theta (), in the iterate's dtype, which the
      preconditioner takes.
    """
    xa, dtype = design, params.theta.dtype
    f32 = xa.dtype
    xh, xht = (xa, xa.T) if rounded is None else rounded
    # float64 sums over frames (in the iterate's dtype): the optimum the gradient
    # defines does not move with the order of the sum (rows split over
    # processes), as float32's did by ~1e-6
    if exact_gradient:
        g = grad.theta + jnp.matmul(
            xa.T.astype(dtype), grad.margins, precision="highest"
        )
    else:
        g = grad.theta + jnp.matmul(
            xa.T, grad.margins.astype(f32), precision="highest"
        ).astype(dtype)
    _, hessian = jax.linearize(jax.grad(summed(value_fn)), params)
    # The Hessian is block-diagonal in (theta, m) (a regulariser in theta, a
    # per-frame loss in m): applied to ones it gives both diagonals.
    curv = hessian(jax.tree.map(jnp.ones_like, params))

    def hvp(v, scale=1.0):
        xv = jnp.dot(
            xh, v.astype(xh.dtype), precision="highest", preferred_element_type=f32
        )
        h = hessian(Iterate(v.astype(dtype), xv.astype(dtype)))
        scale = jnp.asarray(scale, dtype)
        loss = jnp.dot(
            xht,
            (h.margins * scale).astype(xht.dtype),
            precision="highest",
            preferred_element_type=f32,
        )
        hv = loss + h.theta.astype(f32) * scale.astype(f32)
        return hv, xv if rounded is None else None

    return g, hvp, curv.margins, jnp.mean(curv.theta)


def newton_solver(
    eta: float = 0.1, max_cg: int = 200, block: int = 32, exact_gradient: bool = True
) -> optax.GradientTransformationExtraArgs:
    """``optax.chain(newton_cg(...), scale_by_exact_linesearch())``: a full
    Newton step; its state is ``(NewtonCGState, ExactLinesearchState)``."""
    return optax.chain(
        newton_cg(eta, max_cg, block, exact_gradient), scale_by_exact_linesearch()
    )


def round_design(design: jax.Array, dtype) -> tuple[jax.Array, jax.Array]:
    """``(Xa, Xa^T)`` rounded to ``dtype``: (n, q) and a stored (q, n) copy, the
    ``rounded`` argument of :func:`derivatives`."""
    xh = design.astype(dtype)
    return xh, jnp.transpose(xh)  # eager: a (q, n) array of its own
