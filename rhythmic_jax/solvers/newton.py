"""Exact solver for the joint objective: Newton-CG with a gap estimate.

Every template minimises ``f(theta) = 0.5 ||theta||^2 + C sum_i h_i^2`` with
``h_i = max(0, 1 - y_i m_i)``, margins ``m = Xa theta`` and ``Xa = [X, 1]`` (the
bias as a constant-1 feature); theta is (q,), q = d + 1. That is
:func:`rhythmic_jax.solvers.objective.margin_objectives`, the one vmapped objective at
the margins, and each step is the optax chain
:func:`rhythmic_jax.solvers.newton_cg.newton_solver` on it (gradient, Hessian-vector
products and line search all by autodiff of that objective). This module drives
the steps: the preconditioner's setup, which templates are still running, the
stopping rule and the span of wide frames.

- Newton steps (Chapelle, "Training a support vector machine in the primal",
  2007): with the active set ``D = {i : h_i > 0}`` held fixed the objective is
  quadratic and the step ``s`` solves ``(I + 2C Xa^T D Xa) s = -g``. The first
  step, from theta = 0 where every frame is active, is the ridge solution. An
  exact line search on the piecewise-quadratic objective (float64, Newton's
  method on its derivative safeguarded by a bracket, a few passes over the
  margins) follows each step; margins are updated from the products CG already
  made.
- inexact solves: conjugate gradients in float32 for every template at once,
  stopping per template at the forcing term ``||r|| <= eta ||g||`` (relative
  to the step's own gradient, so near the optimum CG still works), and at a cap
  on iterations that may grow from step to step (``cg_start``): the first steps
  after the ridge start mostly find the active set, and accurate solves of their
  quadratic models gain little (measured in ``reports/solver.md``).
- preconditioner (:mod:`rhythmic_jax.solvers.precondition`): the leading eigenvectors
  ``V`` of ``Xa^T Xa`` (subspace iteration, float32). In their span the system
  is inverted exactly on the first ``block`` directions (a small Cholesky per
  template: the largest eigenvalues, where the active set couples directions
  most) and by its diagonal on the rest; outside it, by a scalar per template.
- stop: CG gives the Newton decrement ``-0.5 g . s``, the gap of the quadratic
  model, which estimates ``f - f*`` (exactly once the active set settles; it can
  fall short while frames still leave it, so the fast setting keeps a margin). A
  template whose estimate is below ``gap_tol * f`` takes that last step and
  leaves; later steps run on the others only, until none is left.
- one program per fit: a step runs on chunks of a fixed number of gathered
  columns (:func:`chunk_width`, about a quarter of the templates; the last
  chunk padded by repeating one of its columns), so whichever templates are
  still running, the step compiles once for a problem's shape. Each template's
  step is its own (CG and the line search stop per column), so the chunks
  change no template's result, only the rounding of the products.

- wide frames (d > 2n, deep descriptors): the problem is solved over the
  n-dimensional span of the frames (:mod:`rhythmic_jax.solvers.span`), the same
  optimum at products of n instead of d per frame (3576 x 10976
  EfficientNet-Lite0 frames, 441 templates: ``reports/span.md``).

Its settings and account (:class:`NewtonConfig`, ``FAST``, :class:`NewtonInfo`,
:class:`FitWarning`) are defined in :mod:`rhythmic_jax.solvers.newton_config`.

Measured on 3576 Nordland frames of 2048-d, 441 templates: ``reports/solver.md``.
This is the same objective as :func:`rhythmic_jax.solvers.objective.objective`; with the
default (small) ``gap_tol`` it is solved to its optimum.
"""

from __future__ import annotations

import dataclasses
import logging
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import optax
import scipy.linalg  # at import: loaded mid-process it changed a fit's last bits
from threadpoolctl import threadpool_limits

from rhythmic_jax.jit_options import jit
from rhythmic_jax.progress import bar as progress_bar
from rhythmic_jax.solvers.newton_cg import Iterate, newton_solver, round_design
from rhythmic_jax.solvers.newton_config import FAST as FAST
from rhythmic_jax.solvers.newton_config import FitWarning as FitWarning
from rhythmic_jax.solvers.newton_config import NewtonConfig, NewtonInfo
from rhythmic_jax.solvers.newton_config import step_cap_line as step_cap_line
from rhythmic_jax.solvers.objective import Templates, margin_objectives
from rhythmic_jax.solvers.precision import resolve_hessian_dtype
from rhythmic_jax.solvers.precondition import spectral_setup
from rhythmic_jax.solvers.span import in_span, lift, row_factor

__all__ = [
    "FAST", "FitWarning", "NewtonConfig", "NewtonInfo", "chunk_width", "chunks",
    "newton_fit", "step_cap_line",
]  # fmt: skip

log = logging.getLogger(__name__)


# ------------------------------------------------------------------ pieces


REFRESH_AFTER = 20  # CG iterations after which a step's margins are recomputed


@jit
def _margins(xa: jax.Array, theta: jax.Array) -> jax.Array:
    """Margins ``Xa theta`` (n, p) from scratch: float32 product, float64 result."""
    return jnp.matmul(xa, theta.astype(jnp.float32), precision="highest").astype(
        theta.dtype
    )


@jit
def _design(x: jax.Array, bias: jax.Array) -> jax.Array:
    """The design ``Xa = [x, bias]`` (n, q) in float32; jitted, so frames sharded
    over a mesh keep their sharding."""
    return jnp.concatenate([x.astype(jnp.float32), bias[:, None]], axis=1)


@jit
def _zeros_like(y: jax.Array) -> jax.Array:
    """Zeros of y's shape, dtype and sharding."""
    return y - y


@partial(jit, static_argnames=("rank", "iters"))
def _spectral(xa: jax.Array, rank: int, iters: int, seed) -> tuple:
    """:func:`~rhythmic_jax.solvers.precondition.spectral_setup` from an integer
    seed (the key is drawn inside the program: no program of its own)."""
    return spectral_setup(xa, rank, iters, jax.random.PRNGKey(seed))


@partial(jit, static_argnames=("eta", "max_cg", "block"))
def _start(params: Iterate, eta: float, max_cg: int, block: int):
    """The optimiser's initial state for ``params`` (one program)."""
    return newton_solver(eta, max_cg, block).init(params)


@jit
def _warm(w: jax.Array, b: jax.Array, xa: jax.Array) -> Iterate:
    """The float64 iterate of templates ``w`` (d, p), ``b`` (p,): theta (q, p)
    and its margins ``Xa theta`` (n, p)."""
    theta = jnp.concatenate([w, jnp.reshape(b, (1, -1))]).astype(jnp.float64)
    return Iterate(theta, _margins(xa, theta))


@jit
def _finish(theta: jax.Array, xa: jax.Array, y: jax.Array, c: jax.Array):
    """Every template's objective (p,) from margins made afresh, and the
    templates as float32: w (d, p), b (p,)."""
    final = margin_objectives(theta, _margins(xa, theta), y, c)
    theta = theta.astype(jnp.float32)
    return final, theta[:-1], theta[-1]


def chunk_width(p: int) -> int:
    """Columns a compacted Newton step gathers per call for p templates: a
    multiple of 8 near p / 4, at most p. One width per problem: the step
    compiles once, and templates still running are stepped in
    ``ceil(live / width)`` calls (at least a quarter of the step's cost, where
    powers of two down to 8 would compile once each)."""
    return min(p, max(8, -(-p // 32) * 8))


def chunks(todo: np.ndarray, width: int) -> list[np.ndarray]:
    """``todo`` (live,) split into (width,) column sets, the last padded by
    repeating its first column (a repeated column is stepped twice alike)."""
    out = []
    for start in range(0, len(todo), width):
        part = todo[start : start + width]
        out.append(np.concatenate([part, np.full(width - len(part), part[0])]))
    return out


def _take(tree, cols):
    """Columns ``cols`` (templates, the last axis) of every array of a tree;
    scalars are shared."""
    if cols is None:
        return tree
    return jax.tree.map(lambda a: a[..., cols] if a.ndim else a, tree)


def _put(tree, part, cols):
    """``tree`` with its columns ``cols`` replaced by ``part`` (see :func:`_take`)."""
    if cols is None:
        return part
    return jax.tree.map(
        lambda a, b: a.at[..., cols].set(b) if a.ndim else b, tree, part
    )


@partial(jit, static_argnames=("eta", "block", "exact_gradient"))
def _newton_step(
    xa, spectral, cols, params, opt_state, y, c, eta, block, max_cg,
    exact_gradient=True, rounded=None,
):  # fmt: skip
    """One Newton step of the templates ``cols`` (b,) of ``params`` (an
    :class:`~rhythmic_jax.solvers.newton_cg.Iterate`: theta (q, p), margins
    (n, p)); ``cols=None``: all p (no gather). The step is
    :func:`~rhythmic_jax.solvers.newton_cg.newton_solver` (optax) on
    :func:`~rhythmic_jax.solvers.objective.margin_objectives`.

    Returns the updated iterate and optimiser state (other columns unchanged),
    and for the gathered columns the objective before and after (b,), the Newton
    decrement (b,) and the CG iterations (at most ``max_cg``, traced: no
    recompilation). ``rounded``: the design rounded for CG's products
    (:func:`~rhythmic_jax.solvers.newton_cg.round_design`), or None.
    """
    optimizer = newton_solver(eta=eta, block=block, exact_gradient=exact_gradient)
    part, state, yb = _take(params, cols), _take(opt_state, cols), _take(y, cols)

    def value_fn(it: Iterate) -> jax.Array:
        return margin_objectives(it.theta, it.margins, yb, c)

    grad = jax.grad(lambda it: jnp.sum(value_fn(it)))(part)
    updates, state = optimizer.update(
        grad, state, part, value_fn=value_fn, design=xa, spectral=spectral,
        max_cg=max_cg, rounded=rounded,
    )  # fmt: skip
    part = optax.apply_updates(part, updates)
    cg_state, search = state
    params, opt_state = _put(params, part, cols), _put(opt_state, state, cols)
    return (
        params, opt_state, search.value, search.new_value,
        cg_state.decrement, cg_state.cg_iterations,
    )  # fmt: skip


def _cg_cap(config: NewtonConfig, step: int) -> int:
    """CG iterations allowed in Newton step ``step`` (0: the ridge step):
    ``cg_start`` after the ridge step, one more each step, at most ``max_cg``."""
    if config.cg_start is None:
        return config.max_cg
    return min(config.max_cg, config.cg_start + max(step - 1, 0))


# ---------------------------------------------------------------------- solve


def newton_fit(
    x: np.ndarray | jax.Array,
    y: np.ndarray | jax.Array,
    c: float,
    config: NewtonConfig = NewtonConfig(),  # noqa: B008 (a frozen dataclass)
    progress: bool = False,
    *,
    bias: jax.Array | None = None,
    init: Templates | None = None,
    stop=None,
) -> tuple[Templates, NewtonInfo]:
    """Minimise the joint squared-hinge objective of p templates.

    Args:
      x: (n, d) frames (float32). A ``jax.Array`` sharded by rows over a mesh
        (:mod:`rhythmic_jax.solvers.distributed`, frames of several processes) keeps
        its sharding: every product runs on local frames and XLA reduces.
      y: (n, p) ±1 targets (:func:`rhythmic_jax.solvers.objective.targets`), sharded as
      x.
      c: the penalty C.
      config: solver settings.
      progress: show a progress bar over Newton steps.
      bias: (n,) the design's bias column, sharded as x: 1 for a frame, 0 for a
        padding row (zero features) that evens out the shards. A padding row
        adds nothing to any product and exactly C to every template's
        objective, which is taken off. Default: all ones.
      init: starting templates, w (d, p) and b (p,) (a warm start); default
        zero, from which the first step is the ridge solution.
      stop: optional ``stop(step, margins) -> (p,) bool``, called after every
        Newton step with the margins ``Xa theta`` (n, p) of all templates: the
        templates it marks take no further step (their columns keep their
        values; e.g. :class:`rhythmic_jax.solvers.candidates.DropLosers`).

    Returns:
      Templates with ``w`` (d, p) and ``b`` (p,) as float32, and a
      :class:`NewtonInfo`.
    """
    n, d = x.shape
    local = not isinstance(x, jax.Array) or x.is_fully_addressable
    if config.span and in_span(n, d) and local and bias is None:
        factor = row_factor(np.asarray(x))
        reduced = dataclasses.replace(config, span=False)
        if init is not None:  # the same margins in the span: L beta = X w
            margins = np.asarray(x, np.float64) @ np.asarray(init.w, np.float64)
            beta = scipy.linalg.solve_triangular(factor, margins, lower=True)
            init = Templates(jnp.asarray(beta, jnp.float32), init.b)
        params, info = newton_fit(
            factor.astype(np.float32), y, c, reduced, progress=progress, init=init,
            stop=stop,
        )  # fmt: skip
        w = lift(np.asarray(x), factor, np.asarray(params.w))
        return Templates(w=jnp.asarray(w, jnp.float32), b=params.b), info
    if bias is None:
        bias, pad = np.ones((n,), np.float32), 0
    else:  # padding rows: C each
        pad = n - int(np.rint(float(jnp.sum(bias))))
    xa = _design(x if isinstance(x, jax.Array) else jax.device_put(x), bias)
    narrow = resolve_hessian_dtype(config.hessian_dtype)
    rounded = None if narrow is None else round_design(xa, narrow)
    rank = min(config.rank, d + 1)
    with threadpool_limits(limits=1):  # LAPACK's threads wait on a busy machine
        vecs, lead, rest = jax.block_until_ready(
            _spectral(xa, rank, config.power_iters, np.uint32(config.seed))
        )
    with jax.enable_x64(True):
        if isinstance(y, jax.Array) and len(y.sharding.device_set) > 1:  # keep it
            y64 = y.astype(jnp.float64)
        else:
            y64 = jax.device_put(np.asarray(y, dtype=np.float64))
        p = y64.shape[1]
        c64 = jax.device_put(np.float64(c))
        offset = float(c) * pad
        if init is None:
            theta = jax.device_put(np.zeros((d + 1, p)))
            if len(y64.sharding.device_set) > 1:  # sharded frames: margins alike
                params = Iterate(theta, _zeros_like(y64))
            else:
                params = Iterate(theta, jax.device_put(np.zeros((n, p))))
        else:
            params = _warm(init.w, init.b, xa)
        opt_state = _start(params, config.eta, config.max_cg, config.block)
        objective = np.full(p, np.nan)
        gap = np.full(p, np.inf)
        todo = np.arange(p)
        width = chunk_width(p) if config.compact else p
        cg_its: list[int] = []
        widths: list[int] = []
        bar = progress_bar(range(config.max_iter), show=progress, desc="newton")
        for step in bar:
            cap = jax.device_put(np.int32(_cg_cap(config, step)))
            parts = chunks(todo, width) if config.compact else [None]
            its, values = [], []
            for cols in parts:
                params, opt_state, f0, f1, dec, it = _newton_step(
                    xa, (vecs, lead, rest), cols, params, opt_state, y64, c64,
                    config.eta, config.block, cap, config.exact_gradient, rounded,
                )  # fmt: skip
                its.append(it)  # read after the loop: the calls queue up
                values.append((f0, f1, dec))
            its = [int(it) for it in its]
            cg_its.append(max(its))
            widths.append(width * len(parts))
            if max(its) > REFRESH_AFTER:  # CG's float32 margin updates drift
                params = params._replace(margins=_margins(xa, params.theta))
            f0, f1, dec = (np.concatenate([np.asarray(v[i]) for v in values])
                           for i in range(3))  # fmt: skip
            f0, f1 = f0 - offset, f1 - offset
            cols = np.concatenate(parts) if config.compact else np.arange(p)
            # padding repeats a column: take each column's values once (all equal)
            cols, first = np.unique(cols, return_index=True)
            f0, f1, dec = f0[first], f1[first], dec[first]
            objective[cols] = f1
            gap[cols] = dec / np.maximum(np.abs(f0), 1e-300)
            done = (gap[cols] <= config.gap_tol) | (f1 >= f0)
            bar.set_postfix(
                objective=f"{np.nansum(objective):.6g}", gap=f"{np.max(gap):.1e}"
            )
            todo = np.setdiff1d(todo, cols[done])
            if stop is not None and len(todo):
                todo = todo[~np.asarray(stop(step, params.margins), bool)[todo]]
            if len(todo) == 0 or (not config.compact and np.all(gap <= config.gap_tol)):
                break
        bar.close()
        final, w, b = _finish(params.theta, xa, y64, c64)
        objective = np.asarray(final) - offset
        info = NewtonInfo(
            steps=len(cg_its),
            cg_iterations=tuple(cg_its),
            columns=tuple(widths),
            objective=objective,
            gap_estimate=gap,
            capped=int(len(todo)) if len(cg_its) == config.max_iter else 0,
        )
    log.debug("newton: %d steps, CG %s, columns %s", info.steps, cg_its, widths)
    return Templates(w=w, b=b), info
