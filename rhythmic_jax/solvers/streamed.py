"""Newton-CG over frames read in blocks: a fit whose memory does not grow with n.

:func:`rhythmic_jax.solvers.newton.newton_fit` keeps every frame's margins, (n, p)
float64: 5.8 GB for 10^6 frames and 721 templates. Here nothing of size n is
kept but, optionally, one bit per frame and template and a checkpoint of the
state after every Newton step. The objective is the one of every fit,
:func:`rhythmic_jax.solvers.objective.margin_objectives`: its regulariser (theta alone,
float64 on the host) plus a sum over frames, which the passes over the frames of
:class:`rhythmic_jax.solvers.passes.Passes` sum block by block in float64.

Every Newton step is :func:`rhythmic_jax.solvers.newton_cg.newton_solver`, the
optax chain of the in-memory fit (``newton_cg``, preconditioned CG stopping per
template at ``||r|| <= eta ||g||``, then ``scale_by_exact_linesearch``, every
template's exact minimiser along its step), handed a
:class:`~rhythmic_jax.solvers.newton_cg.NewtonSystem` whose sums are passes
(:func:`_system`) and run by :func:`~rhythmic_jax.solvers.newton_cg.host_loop` in
float64 numpy:

- a gradient pass gives the objective, its gradient and the preconditioner's
  curvature sums: CG is preconditioned by the Hessian's diagonal in the leading
  eigenvectors of ``Xa^T Xa`` (one pass per fit, ``StreamConfig.spectral_rank``)
  and a scalar outside them
  (:func:`~rhythmic_jax.solvers.precondition.diagonal_preconditioner`), or by
  its diagonal in theta (Jacobi);
- every CG iteration is one Hessian pass;
- every iteration of the line search (Newton's method on ``phi'``, safeguarded
  by a bracket, from the Newton step t = 1) is one pass giving ``phi``,
  ``phi'`` and ``phi''`` at one step length per template; most steps take two
  or three.

The only programs a fit compiles are the pass kernels and one for the
regulariser's derivatives (nine, whatever the templates still going). The
stopping rule is :mod:`rhythmic_jax.solvers.newton`'s (a template stops once
its Newton decrement is below ``gap_tol`` times its objective); once a template
stops, the passes carry only the templates still going (``StreamConfig.compact``),
in kernel calls of one width (:func:`rhythmic_jax.solvers.newton.chunk_width`,
about p / 4). Every pass's sums go through ``reduce``
(:func:`rhythmic_jax.solvers.distributed.allreduce` when each process streams
its own rows), so K processes take the same steps.

Names: n frames, d features, q = d + 1, p templates, B rows per block.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax.io.atomic import atomic_path
from rhythmic_jax.io.frame_files import Frames
from rhythmic_jax.io.reader import load_npz, npz_headers
from rhythmic_jax.jit_options import jit
from rhythmic_jax.progress import bar as progress_bar
from rhythmic_jax.solvers.newton import chunk_width
from rhythmic_jax.solvers.newton_cg import (
    Iterate,
    NewtonSystem,
    host_loop,
    newton_solver,
)
from rhythmic_jax.solvers.objective import Templates, margin_objectives
from rhythmic_jax.solvers.passes import Passes
from rhythmic_jax.solvers.precondition import diagonal_preconditioner

__all__ = [
    "FAST_STREAM",
    "StreamConfig",
    "StreamInfo",
    "stream_errors",
    "streamed_newton_fit",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class StreamConfig:
    """Settings of :func:`streamed_newton_fit`.

    Attributes:
      gap_tol: a template stops once its Newton decrement is at most
        ``gap_tol`` times its objective.
      eta: CG stops per template at ``||r|| <= eta ||g||``.
      max_iter: most Newton steps; max_cg: most CG iterations (passes) per step.
      cg_start: if set, the step after the first (ridge) one allows this many
        CG iterations and each later step one more, up to ``max_cg`` (as
        :class:`rhythmic_jax.solvers.newton.NewtonConfig`'s).
      block_rows: frames per block (the memory the fit holds grows with it).
      keep_active: keep where each frame's curvature is not 0 after the
        gradient pass, one bit per frame and template (n p / 8 bytes), so that
        a CG pass makes one product with the frames instead of two (when the
        curvature takes one value wherever it is not 0, as the squared hinge's).
      spectral_rank: precondition CG in the leading ``spectral_rank``
        eigenvectors of ``Xa^T Xa`` (one extra pass and a (q, q) eigen-solve per
        fit): each template's Hessian diagonal in that basis and one scalar
        outside it, summed in the gradient pass. 0: the Hessian's diagonal
        (Jacobi), which for correlated features (Nordland's 2048-d patches)
        leaves CG's truncated steps so poor that 40 Newton steps do not reach
        a 0.1 % gap.
      compact: passes after a template has stopped carry only the templates
        still going, in kernel calls of
        :func:`~rhythmic_jax.solvers.newton.chunk_width` columns (the last
        padded with repeats; one shape, so a fit compiles each kernel twice at
        most): a template that needs more steps than the others no longer
        costs a pass over every template's columns.
    """

    gap_tol: float = 1e-6
    eta: float = 0.1
    max_iter: int = 40
    max_cg: int = 50
    cg_start: int | None = None
    block_rows: int = 8192
    keep_active: bool = True
    spectral_rank: int = 256
    compact: bool = True

    def cg_cap(self, step: int) -> int:
        """CG iterations allowed in Newton step ``step`` (0: the ridge step)."""
        if self.cg_start is None:
            return self.max_cg
        return min(self.max_cg, self.cg_start + max(step - 1, 0))


FAST_STREAM = StreamConfig(gap_tol=1e-3, max_cg=8, cg_start=3)


@dataclass
class StreamInfo:
    """What a streamed solve did: steps, CG passes and line-search passes per
    step, templates each step carried (padding included), seconds per pass, the
    final objective (p,) and each template's last Newton decrement relative to
    its objective (p,): the estimated gap before its last step (a template
    stops at ``gap_tol``)."""

    steps: int = 0
    cg_iterations: list[int] = field(default_factory=list)
    line_passes: list[int] = field(default_factory=list)
    columns: list[int] = field(default_factory=list)
    pass_seconds: list[float] = field(default_factory=list)
    objective: np.ndarray | None = None
    gap_estimate: np.ndarray | None = None


def streamed_newton_fit(
    frames: Frames,
    labels: np.ndarray,
    periods: Sequence[int],
    c: float,
    config: StreamConfig = StreamConfig(),
    rows: tuple[int, int] | None = None,
    reduce: Callable = lambda tree: tree,
    progress: bool = True,
    checkpoint: str | Path | None = None,
) -> tuple[Templates, StreamInfo]:
    """Minimise the joint squared-hinge objective with frames read in blocks.

    Args:
      frames: the frames on disk; labels: (stop - start,) places of this
        process's rows; periods: candidate periods (p = sum); c: C.
      rows: this process's ``(start, stop)`` (default: all frames).
      reduce: sums a tree of arrays over processes (default: one process).
      checkpoint: a ``.npz`` file this process's state is saved to after every
        Newton step; a fit of the same frames and settings that finds it goes on
        from the step it holds (a killed fit loses at most one step).

    Returns:
      Templates ``w`` (d, p), ``b`` (p,) float32 (numpy) and a :class:`StreamInfo`.
    """
    start, stop = rows or (0, frames.n)
    periods = tuple(int(t) for t in periods)
    p, q = sum(periods), frames.d + 1
    block = max(1, min(config.block_rows, frames.n))
    width = chunk_width(p) if config.compact else p
    stream = Passes(frames, start, stop, np.asarray(labels, np.int32), periods,
                     block, reduce, config.keep_active, width)  # fmt: skip
    done = np.zeros(p, bool)
    info = StreamInfo()
    theta = np.zeros((q, p))
    # what the steps depend on (not the block size or the step cap)
    key = " ".join(map(repr, (frames.n, q, start, stop, periods, c, config.gap_tol,
                              config.eta, config.max_cg, config.cg_start,
                              config.spectral_rank)))  # fmt: skip
    first = _resume(checkpoint, key, theta, done, info, stream, reduce)
    bar = progress_bar(range(first, config.max_iter), show=progress,
                       desc="newton (streamed)")  # fmt: skip
    vecs = None
    if config.spectral_rank > 0 and not done.all():
        vecs = _spectral_basis(stream, config.spectral_rank, start == 0)
    solver = newton_solver(config.eta)
    with jax.enable_x64(True):
        objective = np.full(p, np.nan)
        info.gap_estimate = np.where(done, 0.0, np.inf)
        for step in bar:
            if done.all():  # resumed from the last step's checkpoint
                break
            cols = _live_columns(done, config.compact, width)
            where = slice(None) if cols is None else cols
            part, live = theta[:, where], ~done[where]
            th32, before = part.astype(np.float32), len(stream.seconds)
            value, reg_grad, reg_diag = (
                a[..., where] for a in _regulariser_terms(theta, c)
            )
            loss, gx, curv = stream.gradient(th32, c, vecs, cols, config.keep_active)
            f0 = value + loss
            grad = np.where(live[None, :], reg_grad + gx, 0.0)
            system = _system(stream, th32, f0, grad, curv, c, (reg_grad, reg_diag),
                             cols, vecs)  # fmt: skip
            it = Iterate(part, None)
            update, (cg, _) = solver.update(
                Iterate(grad, None), solver.init(it), it, system=system,
                max_cg=config.cg_cap(step),
            )  # fmt: skip
            theta[:, where] = part + update.theta
            info.steps += 1
            its = int(cg.cg_iterations)
            info.cg_iterations.append(its)
            info.line_passes.append(len(stream.seconds) - before - 1 - its)
            info.columns.append(int(part.shape[1]))
            gap = cg.decrement / np.maximum(np.abs(f0), 1e-300)
            objective[where] = f0
            # a stopped template carried along keeps its last step's estimate
            info.gap_estimate[where] = np.where(live, gap, info.gap_estimate[where])
            done[where] |= live & (gap <= config.gap_tol)
            bar.set_postfix(
                objective=f"{np.nansum(objective):.6g}",
                gap=f"{gap[live & ~done[where]].max(initial=0):.1e}",
            )
            if checkpoint is not None:
                _save(checkpoint, key, theta, done, info, stream)
            if done.all():
                break
        bar.close()
        loss, _, _ = stream.gradient(theta.astype(np.float32), c)
        info.objective = _regulariser_terms(theta, c)[0] + loss
        theta = theta.astype(np.float32)
    info.pass_seconds = stream.seconds
    return Templates(w=theta[:-1], b=theta[-1]), info


def _live_columns(done: np.ndarray, compact: bool, width: int) -> np.ndarray | None:
    """The templates a Newton step carries: None (all p) while every template
    is going, without compaction, or where the ones going need as many columns
    as all; else the ones not done, padded with repeats of the first to a
    multiple of ``width`` (the columns of one kernel call)."""
    todo = np.flatnonzero(~done)
    calls = -(-len(todo) // width)
    if not compact or calls * width >= len(done):
        return None
    return np.concatenate([todo, np.full(calls * width - len(todo), todo[0])])


def _save(path, key, theta, done, info, stream) -> None:
    """Write the state after a Newton step to ``path`` (atomically)."""
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, key=np.array(key), theta=theta, done=done,
                 cg=np.array(info.cg_iterations, np.int64),
                 columns=np.array(info.columns, np.int64),
                 line=np.array(info.line_passes, np.int64),
                 seconds=np.array(stream.seconds))  # fmt: skip


def _resume(path, key, theta, done, info, stream, reduce) -> int:
    """Load the state saved in ``path`` into theta, done, info and stream (in
    place) when it is this fit's; the step to go on from (0: none). Every process
    must hold the same step, or all start afresh."""
    steps = 0
    if path is not None and Path(path).is_file():
        heads = npz_headers(path)  # the shapes before anything is inflated
        same = "theta" in heads and heads["theta"].shape == theta.shape
        z = load_npz(path) if same else {}
        if same and str(z["key"]) == key:
            theta[...], done[...] = z["theta"], z["done"]
            info.cg_iterations = [int(v) for v in z["cg"]]
            info.columns = [int(v) for v in z.get("columns", [])]
            info.line_passes = [int(v) for v in z.get("line", [])]
            stream.seconds = [float(v) for v in z["seconds"]]
            steps = len(info.cg_iterations)
        else:
            log.warning("%s: a checkpoint of another fit; starting afresh", path)
    both = reduce(np.array([steps, steps * steps], np.float64))
    k = reduce(np.ones(1))[0]
    if both[0] * both[0] != k * both[1]:  # not the same step everywhere
        steps = 0
    if steps == 0:
        theta[...], done[...] = 0.0, False
        info.cg_iterations, info.columns, stream.seconds = [], [], []
        info.line_passes = []
    else:
        log.info("resuming the streamed fit at step %d from %s", steps, path)
    info.steps = steps
    return steps


def _regulariser(theta, c):
    """(p,) the objective's term without frames: its regulariser at theta (q, p)."""
    empty = jnp.zeros((0, theta.shape[1]), theta.dtype)
    return margin_objectives(theta, empty, empty, c)


@jit
def _regulariser_derivatives(theta, c):
    """The regulariser's value (p,), gradient (q, p) and Hessian diagonal (q, p)
    at theta (q, p), by autodiff. Its Hessian is that diagonal (``0.5
    ||theta||^2`` per template), so its product with v is ``diagonal * v``."""
    value, vjp = jax.vjp(lambda th: _regulariser(th, c), theta)
    grad = jax.grad(lambda th: jnp.sum(_regulariser(th, c)))
    diag = jax.jvp(grad, (theta,), (jnp.ones_like(theta),))[1]
    return value, vjp(jnp.ones_like(value))[0], diag


def _regulariser_terms(theta: np.ndarray, c: float) -> tuple[np.ndarray, ...]:
    """:func:`_regulariser_derivatives` at theta (q, p) float64 as numpy arrays
    (one program per fit: it is called with every column)."""
    with jax.enable_x64(True):
        out = _regulariser_derivatives(jax.device_put(np.asarray(theta, np.float64)), c)
        return tuple(np.asarray(a, np.float64) for a in out)


def _spectral_basis(stream, rank: int, first: bool) -> np.ndarray:
    """The leading ``rank`` eigenvectors (q, k) float32 of ``Xa^T Xa`` over
    every frame (one pass). Every process takes the first process's (``first``
    marks it), so that all precondition alike even where their eigen-solvers
    round differently."""
    gram = stream.gram()
    vals, vecs = np.linalg.eigh(gram)
    vecs = np.ascontiguousarray(vecs[:, ::-1][:, : min(rank, len(vals))])
    if stream.reduce(np.ones(1))[0] == 1:  # one process, whichever its rows
        return vecs.astype(np.float32)
    return stream.reduce(vecs if first else np.zeros_like(vecs)).astype(np.float32)


def _system(stream, th32, f0, grad, curv, c, reg, cols=None,
            vecs=None) -> NewtonSystem:  # fmt: skip
    """The Newton system at theta of the templates ``cols`` (None: all) with every
    sum over frames a pass, for ``newton_solver``'s CG and exact line search run
    by ``host_loop`` in float64 numpy.

    ``th32`` (q, b): theta's columns in float32; ``f0`` (b,) their objective,
    ``grad`` (q, b) its gradient and ``curv`` the gradient pass's
    :func:`~rhythmic_jax.solvers.precondition.curvature_sums`; ``reg``: the
    regulariser's gradient and Hessian diagonal (q, b); ``vecs``: the spectral
    basis (None: Jacobi). A Hessian product is a CG pass plus ``diag * v``; the
    objective along a step is a :func:`_line_pass` plus the regulariser's
    quadratic, the last pass's sums kept (the search's last iteration and its
    final value are at the same step lengths)."""
    reg_grad, reg_diag = reg

    def hvp(v):
        return reg_diag * v + stream.hessian(th32, v.astype(np.float32), c, cols), None

    def line(s):
        slope, curve = np.sum(reg_grad * s, axis=0), np.sum(reg_diag * s * s, axis=0)
        s32, last = s.astype(np.float32), {}

        def along(t):  # (1, b) -> phi(t) - phi(0) (b,), phi'(t), phi''(t) (1, b)
            if t.tobytes() not in last:
                sums = stream.line(th32, s32, t, c, cols)
                last.clear()
                last[t.tobytes()] = sums
            change, d1, d2 = last[t.tobytes()]
            reg = t * slope + 0.5 * t * t * curve
            return change[0] + reg[0], d1 + slope + t * curve, d2 + curve

        return along

    lam = reg_diag if vecs is None else np.mean(reg_diag, axis=0, keepdims=True)
    basis = None if vecs is None else np.asarray(vecs, np.float64)
    precond = diagonal_preconditioner(basis, curv, lam)
    return NewtonSystem(grad, hvp, precond, 1.0, np.float64, host_loop, f0, line)


def stream_errors(frames, labels, periods, params: Templates, rows=None,
                  block_rows=8192, reduce=lambda tree: tree) -> np.ndarray:  # fmt: skip
    """(k,) training error of every period over the streamed frames."""
    start, stop = rows or (0, frames.n)
    periods = tuple(int(t) for t in periods)
    stream = Passes(frames, start, stop, np.asarray(labels, np.int32), periods,
                     max(1, min(block_rows, frames.n)), reduce)  # fmt: skip
    theta = np.concatenate([params.w, params.b[None]]).astype(np.float32)
    wrong = stream.wrong(theta)
    n = reduce(np.array([stop - start], np.float64))[0]
    return wrong / n
