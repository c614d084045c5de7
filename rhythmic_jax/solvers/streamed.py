"""Newton-CG over frames read in blocks: a fit whose memory does not grow with n.

:func:`rhythmic_jax.solvers.newton.newton_fit` keeps every frame's margins, (n, p)
float64: 5.8 GB for 10^6 frames and 721 templates. Here nothing of size n is
kept but a checkpoint of the state after every Newton step (optional). The
objective is the one of every fit,
:func:`rhythmic_jax.objective.margin_objectives`, which is its regulariser plus a
sum over frames, so it splits into the regulariser (theta alone, no frames) and
one term per block of frames (:class:`rhythmic_jax.io.frame_files.Frames`) at the
block's margins ``Xa_b theta``, recomputed from the current templates as the
block is read. Everything the Newton step needs comes from autodiff of those
terms, summed over the blocks in float64, one *pass* each:

- once per fit, a pass for ``Xa^T Xa`` (q, q), whose leading eigenvectors V
  (``StreamConfig.spectral_rank``) are CG's preconditioning basis;
- the gradient pass: the objective, its gradient ``g = d/dtheta + sum_b Xa_b^T
  d/dm_b`` and what the preconditioner needs of the Hessian: its diagonal in V,
  ``1 + sum_b ((Xa_b V)^2)^T h_b``, and its trace outside V (``h_b`` the loss's
  curvature at the margins); or with no basis, its diagonal in theta (Jacobi);
- one pass per CG iteration: ``H v = v + sum_b Xa_b^T (h_b * Xa_b v)``, the
  linearised gradient (``jax.linearize``) applied to ``Xa_b v``; when h takes
  one value wherever it is not 0 (the squared hinge: 2C on the active set), the
  gradient pass keeps where it is not 0 as bits (``keep_active``: 38 MB for
  10^6 frames and 304 templates) and a CG pass makes one product with the
  frames instead of two;
- two line-search passes: ``phi'(t)`` and ``phi''(t)`` along the step at a grid
  of step lengths (``jax.jvp`` of the blocks' gradient in their margins along
  the step's margins), then at a finer grid inside
  the bracket found; the step is Newton's on the piece at the bracket's left
  end, kept inside the bracket (exact once the bracket holds one piece).

The step itself is the optax transformation
:func:`rhythmic_jax.solvers.newton_cg.newton_cg`, handed the summed system
(:class:`~rhythmic_jax.solvers.newton_cg.NewtonSystem`, CG in float64 on the
host, one pass per product). The stopping rule is
:mod:`rhythmic_jax.solvers.newton`'s (a template stops once its Newton decrement
is below ``gap_tol`` times its objective); once a template stops, the passes
carry only the templates still going (``StreamConfig.compact``). Every pass's
sums go through
``reduce`` (:func:`rhythmic_jax.solvers.distributed.allreduce` when each process
streams its own rows), so K processes take the same steps.

Names: n frames, d features, q = d + 1, p templates, B rows per block.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax.io.atomic import atomic_path
from rhythmic_jax.io.frame_files import Frames
from rhythmic_jax.objective import Templates, margin_objectives, targets
from rhythmic_jax.periods import period_offsets
from rhythmic_jax.progress import bar as progress_bar
from rhythmic_jax.solvers.newton_cg import (
    Iterate,
    NewtonSystem,
    bucket,
    host_loop,
    newton_cg,
)
from rhythmic_jax.solvers.precondition import in_basis, outside_norms

__all__ = [
    "FAST_STREAM",
    "StreamConfig",
    "StreamInfo",
    "stream_errors",
    "streamed_newton_fit",
]

log = logging.getLogger(__name__)
_GRID = (0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 2.0, 4.0)  # first line-search pass


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
        still going (padded to a power of two, so few shapes compile): a
        template that needs more steps than the others no longer costs a pass
        over every template's columns.
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
    """What a streamed solve did: steps, CG passes per step, templates each step
    carried (padding included), seconds per pass, the final objective (p,) and
    each template's last Newton decrement relative to its objective (p,): the
    estimated gap before its last step (a template stops at ``gap_tol``)."""

    steps: int = 0
    cg_iterations: list[int] = field(default_factory=list)
    columns: list[int] = field(default_factory=list)
    pass_seconds: list[float] = field(default_factory=list)
    objective: np.ndarray | None = None
    gap_estimate: np.ndarray | None = None


def _block(x: np.ndarray, rows: int):
    """A block padded to ``rows``: design (rows, q) float32 with bias 0 on padding."""
    m = len(x)
    xa = np.zeros((rows, x.shape[1] + 1), np.float32)
    xa[:m, :-1] = x
    xa[:m, -1] = 1.0
    return jnp.asarray(xa)


def _block_loss(m, labels, periods, c, cols=None):
    """(b,) the loss term of one block at its margins m (B, b): the objective
    :func:`~rhythmic_jax.objective.margin_objectives` of the block's frames with
    no parameters (the regulariser is counted once, in :func:`_regulariser`);
    padding rows (label -1) weigh 0. ``cols`` (b,): the templates m holds
    (None: all p)."""
    y = targets(jnp.maximum(labels, 0), periods)
    if cols is not None:
        y = y[:, cols]
    empty = jnp.zeros((0, m.shape[1]), m.dtype)
    return margin_objectives(empty, m, y, c, (labels >= 0).astype(m.dtype))


def _regulariser(theta, c):
    """(p,) the objective's term without frames: its regulariser at theta (q, p)."""
    empty = jnp.zeros((0, theta.shape[1]), theta.dtype)
    return margin_objectives(theta, empty, empty, c)


def _loss_grad(labels, periods, c, cols=None):
    """The gradient of a block's summed loss in its margins, ``m -> dL/dm``."""
    return jax.grad(lambda m: jnp.sum(_block_loss(m, labels, periods, c, cols)))


def _curvature(xa, h, vecs):
    """What the preconditioner needs of the loss's Hessian ``Xa^T diag(h) Xa``
    over one block (h (B, p) the curvature at the margins): its diagonal (q, p)
    when ``vecs`` is None; else its diagonal in the basis ``vecs`` (q, k) (k,
    p) and its trace outside that basis (p,)."""
    if vecs is None:
        return jnp.matmul((xa * xa).T, h, precision="highest")
    lead = jnp.matmul(xa, vecs, precision="highest")
    return jnp.matmul((lead * lead).T, h, precision="highest"), jnp.matmul(
        outside_norms(xa, lead), h, precision="highest"
    )


@partial(jax.jit, static_argnames=("periods",))
def _gram_pass(xa, labels, periods):
    """``Xa^T Xa`` (q, q) of one block (padding rows are zero)."""
    del labels, periods
    return jnp.matmul(xa.T, xa, precision="highest")


def _block_sums(xa, labels, theta, c, vecs, periods, cols):
    """:func:`_grad_pass`'s sums of one block, and the loss's curvature h (B, p)
    at its margins."""
    m = jnp.matmul(xa, theta, precision="highest")
    grad = _loss_grad(labels, periods, c, cols)
    dm, h = jax.jvp(grad, (m,), (jnp.ones_like(m),))
    loss = _block_loss(m, labels, periods, c, cols)
    return (loss, jnp.matmul(xa.T, dm, precision="highest"), _curvature(xa, h, vecs)), h


@partial(jax.jit, static_argnames=("periods",))
def _grad_pass(xa, labels, theta, c, vecs=None, *, periods, cols=None):
    """Sums of one block: the loss (p,), its gradient in theta ``Xa^T dL/dm``
    (q, p) and :func:`_curvature` (the Hessian's diagonal in theta, ``(Xa^2)^T
    h`` (q, p), or in the basis ``vecs``), ``h`` the loss's curvature at the
    margins (the Hessian in m is diagonal). ``cols`` (b,): theta (q, b) holds
    these templates only, and so do the sums."""
    return _block_sums(xa, labels, theta, c, vecs, periods, cols)[0]


@partial(jax.jit, static_argnames=("periods",))
def _grad_keep(xa, labels, theta, c, vecs=None, *, periods, cols=None):
    """:func:`_grad_pass`'s sums, and what a CG pass needs of the curvature h
    (B, p) at the block's margins: where it is not 0, packed to bits (B,
    ceil(p / 8)) uint8, its largest value per template (p,), and whether it takes
    that one value wherever it is not 0 (the squared hinge's does: 2C)."""
    sums, h = _block_sums(xa, labels, theta, c, vecs, periods, cols)
    on, top = h > 0, jnp.max(h, axis=0)
    flat = jnp.all(jnp.where(on, h == top[None, :], True))
    return sums, (jnp.packbits(on, axis=1), top, flat)


@partial(jax.jit, static_argnames=("periods",))
def _hess_kept(xa, bits, v, top, periods, cols=None):
    """:func:`_hess_pass` from the kept curvature (bits times its one value
    ``top`` (p,)): one product with the frames fewer. The bits are of v's
    columns (``cols`` only names them)."""
    del periods, cols
    on = jnp.unpackbits(bits, axis=1, count=v.shape[1]).astype(v.dtype)
    return jnp.matmul(
        xa.T,
        on * top[None, :] * jnp.matmul(xa, v, precision="highest"),
        precision="highest",
    )


@partial(jax.jit, static_argnames=("periods",))
def _hess_pass(xa, labels, theta, v, c, periods, cols=None):
    """``Xa^T (h * Xa v)`` (q, p) over one block: the loss's Hessian in theta
    applied to v, by linearising its gradient at the block's margins."""
    both = jnp.matmul(xa, jnp.concatenate([theta, v], axis=1), precision="highest")
    p = theta.shape[1]
    _, hessian = jax.linearize(_loss_grad(labels, periods, c, cols), both[:, :p])
    return jnp.matmul(xa.T, hessian(both[:, p:]), precision="highest")


@partial(jax.jit, static_argnames=("periods",))
def _line_pass(xa, labels, theta, s, ts, c, periods, cols=None):
    """The block's loss along the step, ``phi_b(t) = L_b(m + t Xa s)`` per
    template: ``phi_b'`` and ``phi_b''`` (K, p) at the step lengths ts (K, p).

    In the margins: with ``u = Xa s``, ``phi_b'(t) = sum_i g_i u_i`` and
    ``phi_b''(t) = sum_i (H u)_i u_i``, g and H u the loss's gradient at
    ``m + t u`` and its product with u (one ``jax.jvp`` of the gradient), summed
    over the block's frames per template; 1.5x cheaper than differentiating
    ``phi_b`` in t twice."""
    both = jnp.matmul(xa, jnp.concatenate([theta, s], axis=1), precision="highest")
    p = theta.shape[1]
    m, u = both[:, :p], both[:, p:]
    grad = _loss_grad(labels, periods, c, cols)

    def at(t):
        g, hu = jax.jvp(grad, (m + t[None, :] * u,), (u,))
        return jnp.sum(g * u, axis=0), jnp.sum(hu * u, axis=0)

    return jax.lax.map(at, ts)


class _Stream:
    """Passes over this process's rows ``start .. stop``, summed by ``reduce``."""

    def __init__(self, frames, start, stop, labels, periods, rows, reduce,
                 keep=False):  # fmt: skip
        self.frames, self.start, self.stop = frames, start, stop
        self.labels, self.periods, self.rows = labels, periods, rows
        self.reduce, self.seconds = reduce, []
        # where every row's curvature is not 0 at the current theta, one bit per
        # template of the last gradient pass, and its one value there (None:
        # recompute it in CG passes)
        self.bits = self._bit_rows(sum(periods)) if keep else None
        self.top = None

    def _bit_rows(self, templates: int) -> np.ndarray:
        """Zeroed bits of this process's rows for ``templates`` columns."""
        return np.zeros((self.stop - self.start, -(-templates // 8)), np.uint8)

    def run(self, kernel, *args, bits: str | None = None, cols=None):
        """Sum ``kernel`` over the blocks. ``bits``: "write" keeps the kernel's
        second output (:func:`_grad_keep`'s); "read" passes the kept bits to the
        kernel in place of the labels. ``cols`` (b,): the templates the
        arguments hold (None: all)."""
        t0 = time.perf_counter()
        total, tops, flat = None, [], True
        extra = {} if cols is None else {"cols": jnp.asarray(cols, jnp.int32)}
        if bits == "write":
            width = len(cols) if cols is not None else sum(self.periods)
            if self.bits.shape[1] != -(-width // 8):
                self.bits = self._bit_rows(width)
        for lo in range(self.start, self.stop, self.rows):
            hi = min(self.stop, lo + self.rows)
            xa = _block(self.frames.read(lo, hi), self.rows)
            here = slice(lo - self.start, hi - self.start)
            if bits == "read":
                side = np.zeros((self.rows, self.bits.shape[1]), np.uint8)
                side[: hi - lo] = self.bits[here]
            else:
                side = np.full(self.rows, -1, np.int32)
                side[: hi - lo] = self.labels[here]
            part = kernel(xa, jnp.asarray(side), *args, periods=self.periods, **extra)
            if bits == "write":
                part, (packed, top, ok) = part
                self.bits[here] = np.asarray(packed)[: hi - lo]
                tops.append(np.asarray(top, np.float64))
                flat &= bool(ok)
            part = jax.tree.map(lambda a: np.asarray(a, np.float64), part)
            total = part if total is None else jax.tree.map(np.add, total, part)
        if total is None:  # a process with no rows still joins the reduction
            total = self._zeros(kernel, *args, bits=bits, **extra)
        total = self.reduce(total)
        if bits == "write":
            self.top = self._one_value(tops, flat, width)
        self.seconds.append(time.perf_counter() - t0)
        return total

    def _one_value(self, tops, flat, p):
        """The curvature's one nonzero value per template (p columns) over every
        block of every process, or None where it takes more than one."""
        tops = np.stack(tops) if tops else np.zeros((0, p))
        top = tops.max(axis=0, initial=0.0)
        flat &= bool(np.all((tops == 0) | (tops == top[None, :])))
        s = self.reduce(np.stack([top, top * top, top > 0, np.full(p, not flat)]))
        count = np.maximum(s[2], 1)
        if s[3].any() or not np.allclose(s[0] * s[0], count * s[1], rtol=0):
            return None
        return s[0] / count

    def _zeros(self, kernel, *args, bits=None, **extra):
        xa = jnp.zeros((self.rows, self.frames.d + 1), jnp.float32)
        if bits == "read":
            side = jnp.zeros((self.rows, self.bits.shape[1]), jnp.uint8)
        else:
            side = jnp.full(self.rows, -1, jnp.int32)
        part = kernel(xa, side, *args, periods=self.periods, **extra)
        if bits == "write":
            part = part[0]
        return jax.tree.map(lambda a: np.zeros(a.shape), part)


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
    stream = _Stream(frames, start, stop, np.asarray(labels, np.int32), periods,
                     block, reduce, config.keep_active)  # fmt: skip
    tx = newton_cg(config.eta, config.max_cg)
    done = np.zeros(p, bool)
    info = StreamInfo()
    start_theta = np.zeros((q, p))
    # what the steps depend on (not the block size or the step cap)
    key = " ".join(map(repr, (frames.n, q, start, stop, periods, c, config.gap_tol,
                              config.eta, config.max_cg, config.cg_start,
                              config.spectral_rank)))  # fmt: skip
    first = _resume(checkpoint, key, start_theta, done, info, stream, reduce)
    bar = progress_bar(range(first, config.max_iter), show=progress,
                       desc="newton (streamed)")  # fmt: skip
    vecs = None
    if config.spectral_rank > 0 and not done.all():
        vecs = _spectral_basis(stream, config.spectral_rank, start == 0)
    with jax.enable_x64(True):
        params = Iterate(jnp.asarray(start_theta, jnp.float64), None)
        state = tx.init(params)
        state = state._replace(count=jnp.asarray(first, state.count.dtype))
        objective = np.full(p, np.nan)
        info.gap_estimate = np.where(done, 0.0, np.inf)
        for step in bar:
            if done.all():  # resumed from the last step's checkpoint
                break
            cols = _live_columns(done, config.compact)
            theta = params.theta
            part = theta if cols is None else theta[:, cols]
            live = ~done if cols is None else ~done[cols]
            th32 = part.astype(jnp.float32)
            if config.keep_active:
                loss, gx, curv = stream.run(
                    _grad_keep, th32, c, vecs, bits="write", cols=cols
                )
            else:
                loss, gx, curv = stream.run(_grad_pass, th32, c, vecs, cols=cols)
            f0, reg_grad = _value_and_grad(part, c)
            f0 = np.asarray(f0) + loss
            grad = jnp.where(live[None, :], reg_grad + gx, 0.0)
            system = _system(stream, part, th32, grad, curv, c, cols, vecs)
            cap = config.cg_cap(step)
            updates, state = tx.update(
                Iterate(grad, None), state, Iterate(part, None), system=system,
                max_cg=cap,
            )  # fmt: skip
            t = _line_search(stream, th32, part, updates.theta, c, grad, cols)
            part = part + t[None, :] * updates.theta
            theta = part if cols is None else theta.at[:, cols].set(part)
            params = Iterate(theta, None)
            info.steps += 1
            info.cg_iterations.append(int(state.cg_iterations))
            info.columns.append(int(part.shape[1]))
            gap = np.asarray(state.decrement) / np.maximum(np.abs(f0), 1e-300)
            where = slice(None) if cols is None else cols
            objective[where] = f0
            info.gap_estimate[where] = gap
            done[where] |= live & (gap <= config.gap_tol)
            bar.set_postfix(
                objective=f"{np.nansum(objective):.6g}",
                gap=f"{gap[live & ~done[where]].max(initial=0):.1e}",
            )
            if checkpoint is not None:
                _save(checkpoint, key, np.asarray(params.theta), done, info, stream)
            if done.all():
                break
        bar.close()
        theta = params.theta
        loss, _, _ = stream.run(_grad_pass, theta.astype(jnp.float32), c)
        info.objective = np.asarray(_value_and_grad(theta, c)[0]) + loss
        theta = np.asarray(theta, np.float32)
    info.pass_seconds = stream.seconds
    return Templates(w=theta[:-1], b=theta[-1]), info


def _live_columns(done: np.ndarray, compact: bool) -> np.ndarray | None:
    """The templates a Newton step carries: None (all p) while every template
    is going or without compaction; else the ones not done, padded with
    repeats of the first to :func:`rhythmic_jax.solvers.newton_cg.bucket`'s width."""
    todo = np.flatnonzero(~done)
    if not compact or len(todo) == len(done):
        return None
    width = bucket(len(todo), len(done))
    return np.concatenate([todo, np.full(width - len(todo), todo[0])])


def _save(path, key, theta, done, info, stream) -> None:
    """Write the state after a Newton step to ``path`` (atomically)."""
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, key=np.array(key), theta=theta, done=done,
                 cg=np.array(info.cg_iterations, np.int64),
                 columns=np.array(info.columns, np.int64),
                 seconds=np.array(stream.seconds))  # fmt: skip


def _resume(path, key, theta, done, info, stream, reduce) -> int:
    """Load the state saved in ``path`` into theta, done, info and stream (in
    place) when it is this fit's; the step to go on from (0: none). Every process
    must hold the same step, or all start afresh."""
    steps = 0
    if path is not None and Path(path).is_file():
        with np.load(path, allow_pickle=False) as z:
            if str(z["key"]) == key and z["theta"].shape == theta.shape:
                theta[...], done[...] = z["theta"], z["done"]
                info.cg_iterations = [int(v) for v in z["cg"]]
                if "columns" in z:
                    info.columns = [int(v) for v in z["columns"]]
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
    else:
        log.info("resuming the streamed fit at step %d from %s", steps, path)
    info.steps = steps
    return steps


def _value_and_grad(theta, c):
    """The regulariser's value (p,) and gradient (q, p) at theta (float64)."""
    value, vjp = jax.vjp(lambda th: _regulariser(th, c), theta)
    return value, vjp(jnp.ones_like(value))[0]


def _spectral_basis(stream, rank: int, first: bool) -> np.ndarray:
    """The leading ``rank`` eigenvectors (q, k) float32 of ``Xa^T Xa`` over
    every frame (one pass). Every process takes the first process's (``first``
    marks it), so that all precondition alike even where their eigen-solvers
    round differently."""
    gram = stream.run(_gram_pass)
    vals, vecs = np.linalg.eigh(gram)
    vecs = np.ascontiguousarray(vecs[:, ::-1][:, : min(rank, len(vals))])
    if stream.reduce(np.ones(1))[0] == 1:  # one process, whichever its rows
        return vecs.astype(np.float32)
    return stream.reduce(vecs if first else np.zeros_like(vecs)).astype(np.float32)


def _preconditioner(lam, curv, vecs):
    """An approximate inverse of ``lam I + Xa^T diag(h_j) Xa`` for every template
    j, from :func:`_curvature`'s sums: its diagonal (Jacobi) when ``vecs`` is
    None; else the diagonal in the basis ``vecs`` (q, k) and, outside it, the
    mean of the trace left over the q - k other directions."""
    if vecs is None:
        diag = lam + curv
        return lambda r: r / diag
    inside, rest = curv
    q, k = vecs.shape
    diag = lam + jnp.asarray(inside)
    tail = lam + jnp.asarray(rest)[None, :] / max(q - k, 1)
    return in_basis(jnp.asarray(vecs, jnp.float64), lambda coef: coef / diag, tail)


def _system(stream, theta, th32, grad, curv, c, cols=None, vecs=None) -> NewtonSystem:
    """The Newton system at theta for :func:`newton_cg`: products are passes over
    the blocks (plus the regulariser's Hessian, by autodiff), preconditioned by
    :func:`_preconditioner` from the gradient pass's curvature sums ``curv``;
    CG in float64 on the host. ``cols``: the templates theta (q, b) holds
    (None: all); ``vecs``: the spectral basis (None: Jacobi)."""

    def reg_hvp(v):
        return jax.jvp(
            jax.grad(lambda th: jnp.sum(_regulariser(th, c))), (theta,), (v,)
        )

    reg_diag = reg_hvp(jnp.ones_like(theta))[1]
    lam = reg_diag if vecs is None else jnp.mean(reg_diag, axis=0, keepdims=True)

    def hvp(v):
        v32 = v.astype(jnp.float32)
        if stream.top is not None:  # the curvature kept by the gradient pass
            top = jnp.asarray(stream.top, jnp.float32)
            loss = stream.run(_hess_kept, v32, top, bits="read", cols=cols)
        else:
            loss = stream.run(_hess_pass, th32, v32, c, cols=cols)
        return reg_hvp(v)[1] + loss, None

    precond = _preconditioner(lam, curv, vecs)
    return NewtonSystem(grad, hvp, precond, 1.0, jnp.float64, host_loop)


def _line_search(stream, th32, theta, s, c, grad, cols=None) -> np.ndarray:
    """Step length (p,) along s: two passes of ``phi'`` on grids (see module).

    ``phi(t)`` is the objective along the step: the regulariser's part, a
    quadratic in t (its slope at 0 and curvature by ``jax.jvp``), plus the
    blocks' (:func:`_line_pass`)."""

    def reg(t):
        return _regulariser(theta + t[None, :] * s, c)

    def reg_slope(t):
        return jax.jvp(reg, (t,), (jnp.ones_like(t),))[1]

    zero = jnp.zeros(theta.shape[1], theta.dtype)
    b, cc = (np.asarray(v) for v in jax.jvp(reg_slope, (zero,), (jnp.ones_like(zero),)))
    s = np.asarray(s)
    lo = np.zeros_like(b)
    g_lo = np.sum(np.asarray(grad) * s, axis=0)  # phi'(0)
    hi = np.full_like(b, np.inf)
    grid = np.repeat(np.asarray(_GRID)[:, None], len(b), axis=1)
    h_lo = None
    for _ in range(2):
        gs, hs = stream.run(_line_pass, th32, jnp.asarray(s, jnp.float32),
                            jnp.asarray(grid, jnp.float32), c, cols=cols)  # fmt: skip
        slope = b[None] + grid * cc[None] + gs  # phi'(t) at the grid
        curv = cc[None] + hs
        left = slope < 0
        t_lo = np.where(left, grid, -np.inf).max(axis=0)
        i_lo = np.where(left, grid, -np.inf).argmax(axis=0)
        better = left.any(axis=0) & (t_lo > lo)
        cols = np.arange(len(b))
        lo = np.where(better, t_lo, lo)
        g_lo = np.where(better, slope[i_lo, cols], g_lo)
        h_new = curv[i_lo, cols]
        h_lo = h_new if h_lo is None else np.where(better, h_new, h_lo)
        t_hi = np.where(~left, grid, np.inf).min(axis=0)
        hi = np.minimum(hi, t_hi)
        top = np.where(np.isfinite(hi), hi, 2 * lo + 8.0)
        grid = lo[None] + (top - lo)[None] * (np.arange(1, 9)[:, None] / 9.0)
    # Newton on the piece right of lo (exact if the root is on it), inside the
    # bracket; h_lo is phi'' there (the regulariser's cc included)
    t = lo - g_lo / np.maximum(h_lo, 1e-300)
    t = np.clip(t, lo, np.where(np.isfinite(hi), hi, t))
    return np.where(g_lo < 0, t, lo)


@partial(jax.jit, static_argnames=("periods",))
def _wrong_pass(xa, labels, w, periods):
    """(k,) frames of a block whose argmax phase is wrong, per period."""
    s = jnp.matmul(xa, w, precision="highest")
    out = []
    for off, t in zip(period_offsets(periods), periods, strict=True):
        pred = jnp.argmax(s[:, off : off + t], axis=1)
        out.append(jnp.sum((pred != labels % t) & (labels >= 0)))
    return jnp.stack(out)


def stream_errors(frames, labels, periods, params: Templates, rows=None,
                  block_rows=8192, reduce=lambda tree: tree) -> np.ndarray:  # fmt: skip
    """(k,) training error of every period over the streamed frames."""
    start, stop = rows or (0, frames.n)
    periods = tuple(int(t) for t in periods)
    stream = _Stream(frames, start, stop, np.asarray(labels, np.int32), periods,
                     max(1, min(block_rows, frames.n)), reduce)  # fmt: skip
    theta = jnp.asarray(np.concatenate([params.w, params.b[None]]), jnp.float32)
    wrong = stream.run(_wrong_pass, theta)
    n = reduce(np.array([stop - start], np.float64))[0]
    return wrong / n
