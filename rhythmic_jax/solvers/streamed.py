"""Newton-CG over frames read in blocks: a fit whose memory does not grow with n.

:func:`rhythmic_jax.solvers.newton.newton_fit` keeps every frame's margins, (n, p)
float64: 5.8 GB for 10^6 frames and 721 templates. Here nothing of size n is
kept but a checkpoint of the state after every Newton step (optional). The
objective is the one of every fit,
:func:`rhythmic_jax.solvers.objective.margin_objectives`, which is its regulariser plus
a
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

The step is :func:`rhythmic_jax.solvers.newton_cg.newton_cg`'s (preconditioned CG
stopping per template at ``||r|| <= eta ||g||``), run on the host in float64
numpy on the summed system
(:class:`~rhythmic_jax.solvers.newton_cg.NewtonSystem`, one pass per product),
as are the preconditioner and the line search between passes: the only
programs a fit compiles are the pass kernels and one for the regulariser's
derivatives (about ten, whatever the templates still going). The stopping rule
is :mod:`rhythmic_jax.solvers.newton`'s (a template stops once its Newton
decrement is below ``gap_tol`` times its objective); once a template stops, the
passes carry only the templates still going (``StreamConfig.compact``), in
kernel calls of one width
(:func:`rhythmic_jax.solvers.newton.chunk_width`, about p / 4), so each
kernel compiles for two shapes at most: every column, and that width. Every
pass's sums go through
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
from rhythmic_jax.jit_options import jit
from rhythmic_jax.map.periods import period_offsets
from rhythmic_jax.progress import bar as progress_bar
from rhythmic_jax.solvers.newton import chunk_width
from rhythmic_jax.solvers.newton_cg import NewtonSystem
from rhythmic_jax.solvers.objective import Templates, margin_objectives, targets
from rhythmic_jax.solvers.precondition import outside_norms

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
    return jax.device_put(xa)


def _block_loss(m, labels, periods, c, cols=None):
    """(b,) the loss term of one block at its margins m (B, b): the objective
    :func:`~rhythmic_jax.solvers.objective.margin_objectives` of the block's frames with
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


@partial(jit, static_argnames=("periods",))
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


@partial(jit, static_argnames=("periods",))
def _grad_pass(xa, labels, theta, c, vecs=None, *, periods, cols=None):
    """Sums of one block: the loss (p,), its gradient in theta ``Xa^T dL/dm``
    (q, p) and :func:`_curvature` (the Hessian's diagonal in theta, ``(Xa^2)^T
    h`` (q, p), or in the basis ``vecs``), ``h`` the loss's curvature at the
    margins (the Hessian in m is diagonal). ``cols`` (b,): theta (q, b) holds
    these templates only, and so do the sums."""
    return _block_sums(xa, labels, theta, c, vecs, periods, cols)[0]


@partial(jit, static_argnames=("periods",))
def _grad_keep(xa, labels, theta, c, vecs=None, *, periods, cols=None):
    """:func:`_grad_pass`'s sums, and what a CG pass needs of the curvature h
    (B, p) at the block's margins: where it is not 0, packed to bits (B,
    ceil(p / 8)) uint8, its largest value per template (p,), and whether it takes
    that one value wherever it is not 0 (the squared hinge's does: 2C)."""
    sums, h = _block_sums(xa, labels, theta, c, vecs, periods, cols)
    on, top = h > 0, jnp.max(h, axis=0)
    flat = jnp.all(jnp.where(on, h == top[None, :], True))
    return sums, (jnp.packbits(on, axis=1), top, flat)


@partial(jit, static_argnames=("periods",))
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


@partial(jit, static_argnames=("periods",))
def _hess_pass(xa, labels, theta, v, c, periods, cols=None):
    """``Xa^T (h * Xa v)`` (q, p) over one block: the loss's Hessian in theta
    applied to v, by linearising its gradient at the block's margins."""
    both = jnp.matmul(xa, jnp.concatenate([theta, v], axis=1), precision="highest")
    p = theta.shape[1]
    _, hessian = jax.linearize(_loss_grad(labels, periods, c, cols), both[:, :p])
    return jnp.matmul(xa.T, hessian(both[:, p:]), precision="highest")


@partial(jit, static_argnames=("periods",))
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
    """Passes over this process's rows ``start .. stop``, summed by ``reduce``.

    ``width``: the columns (templates) a kernel call carries when a pass is
    given columns; a pass over ``k * width`` columns makes k calls per block
    (None: one call, whatever the columns). Every compacted pass of a fit then
    has one shape, so each kernel compiles at most twice per fit (all p
    columns, and ``width``)."""

    def __init__(self, frames, start, stop, labels, periods, rows, reduce,
                 keep=False, width=None):  # fmt: skip
        self.frames, self.start, self.stop = frames, start, stop
        self.labels, self.periods, self.rows = labels, periods, rows
        self.reduce, self.seconds, self.width = reduce, [], width
        # where every row's curvature is not 0 at the current theta, one bit per
        # template of the last gradient pass, and its one value there (None:
        # recompute it in CG passes)
        self.bits = self._bit_rows(sum(periods)) if keep else None
        self.top = None

    def _bit_rows(self, templates: int) -> np.ndarray:
        """Zeroed bits of this process's rows for ``templates`` columns."""
        return np.zeros((self.stop - self.start, -(-templates // 8)), np.uint8)

    def _chunks(self, cols) -> list[tuple[jax.Array | None, slice]]:
        """The kernel calls of a pass over ``cols``: each call's columns (on the
        device; None: all) and where they sit in ``cols``."""
        if cols is None:
            return [(None, slice(None))]
        width = self.width or len(cols)
        if len(cols) % width:
            raise ValueError(f"{len(cols)} columns are not calls of {width}")
        return [
            (jax.device_put(np.asarray(cols[i : i + width], np.int32)),
             slice(i, i + width))
            for i in range(0, len(cols), width)
        ]  # fmt: skip

    def run(self, kernel, *args, split: int = 0, bits: str | None = None,
            cols=None):  # fmt: skip
        """Sum ``kernel`` over the blocks. The first ``split`` arguments hold
        the templates on their last axis (cut into the calls of ``cols``); the
        others are the same for every call. ``bits``: "write" keeps the
        kernel's second output (:func:`_grad_keep`'s); "read" passes the kept
        bits to the kernel in place of the labels. ``cols`` (b,): the templates
        the arguments hold (None: all)."""
        t0 = time.perf_counter()
        total, tops, flat = None, [], True
        calls = self._chunks(cols)
        shared = [_put(a) for a in args[split:]]
        cut = [[_put(np.asarray(a)[..., where]) for a in args[:split]]
               for _, where in calls]  # fmt: skip
        byte = [slice(None) if w.start is None else slice(w.start // 8, w.stop // 8)
                for _, w in calls]  # fmt: skip
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
            part = self._calls(kernel, xa, side, calls, cut, shared, byte, bits)
            if bits == "write":
                part, (packed, top, ok) = part
                self.bits[here] = packed[: hi - lo]
                tops.append(top)
                flat &= ok
            total = part if total is None else jax.tree.map(np.add, total, part)
        if total is None:  # a process with no rows still joins the reduction
            xa = _block(np.zeros((0, self.frames.d), np.float32), self.rows)
            if bits == "read":
                side = np.zeros((self.rows, self.bits.shape[1]), np.uint8)
            else:
                side = np.full(self.rows, -1, np.int32)
            part = self._calls(kernel, xa, side, calls, cut, shared, byte, bits)
            total = jax.tree.map(np.zeros_like, part[0] if bits == "write" else part)
        total = self.reduce(total)
        if bits == "write":
            self.top = self._one_value(tops, flat, width)
        self.seconds.append(time.perf_counter() - t0)
        return total

    def _calls(self, kernel, xa, side, calls, cut, shared, byte, bits):
        """One block's sums over every call of a pass, as numpy (float64 but
        :func:`_grad_keep`'s bits), the calls' columns side by side."""
        whole = None if bits == "read" else jax.device_put(side)
        outs = []
        for (where, _), mine, nbytes in zip(calls, cut, byte, strict=True):
            extra = {} if where is None else {"cols": where}
            # the bits of this call's columns, cut on the host (no program)
            part_side = jax.device_put(side[:, nbytes]) if whole is None else whole
            out = kernel(xa, part_side, *mine, *shared, periods=self.periods, **extra)
            if bits == "write":
                sums, (packed, top, ok) = out
                out = (_float64(sums), (np.asarray(packed), _float64(top), bool(ok)))
            else:
                out = _float64(out)
            outs.append(out)
        if len(outs) == 1:
            return outs[0]
        if bits == "write":
            sums = _side_by_side([o[0] for o in outs])
            packed, top = (_side_by_side([o[1][i] for o in outs]) for i in (0, 1))
            return sums, (packed, top, all(o[1][2] for o in outs))
        return _side_by_side(outs)

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


def _put(a):
    """An argument of a kernel on the device once per pass (numpy arrays; Python
    scalars stay weakly typed, as jit takes them)."""
    return jax.device_put(a) if isinstance(a, np.ndarray) else a


def _float64(tree):
    """Every array of a tree as a numpy float64 array."""
    return jax.tree.map(lambda a: np.asarray(a, np.float64), tree)


def _side_by_side(trees):
    """Trees of arrays with the templates on their last axis, joined along it."""
    return jax.tree.map(lambda *xs: np.concatenate(xs, axis=-1), *trees)


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
    stream = _Stream(frames, start, stop, np.asarray(labels, np.int32), periods,
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
    with jax.enable_x64(True):
        objective = np.full(p, np.nan)
        info.gap_estimate = np.where(done, 0.0, np.inf)
        for step in bar:
            if done.all():  # resumed from the last step's checkpoint
                break
            cols = _live_columns(done, config.compact, width)
            where = slice(None) if cols is None else cols
            part, live = theta[:, where], ~done[where]
            th32 = part.astype(np.float32)
            value, reg_grad, reg_diag = (
                a[..., where] for a in _regulariser_terms(theta, c)
            )
            if config.keep_active:
                loss, gx, curv = stream.run(
                    _grad_keep, th32, c, vecs, split=1, bits="write", cols=cols
                )
            else:
                loss, gx, curv = stream.run(_grad_pass, th32, c, vecs, split=1,
                                            cols=cols)  # fmt: skip
            f0 = value + loss
            grad = np.where(live[None, :], reg_grad + gx, 0.0)
            system = _system(stream, th32, grad, curv, c, reg_diag, cols, vecs)
            s, its = _newton_direction(system, config.eta, config.cg_cap(step))
            decrement = 0.5 * np.sum(-grad * s, axis=0)
            t = _line_search(stream, th32, s, c, grad, (reg_grad, reg_diag), cols)
            theta[:, where] = part + t[None, :] * s
            info.steps += 1
            info.cg_iterations.append(its)
            info.columns.append(int(part.shape[1]))
            gap = decrement / np.maximum(np.abs(f0), 1e-300)
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
        loss, _, _ = stream.run(_grad_pass, theta.astype(np.float32), c, split=1)
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
    mean of the trace left over the q - k other directions (as
    :func:`rhythmic_jax.solvers.precondition.in_basis`). numpy float64: it
    runs on the host between passes, no program of its own."""
    lam = np.asarray(lam, np.float64)
    if vecs is None:
        diag = lam + np.asarray(curv, np.float64)
        return lambda r: np.asarray(r, np.float64) / diag
    inside, rest = (np.asarray(a, np.float64) for a in curv)
    basis = np.asarray(vecs, np.float64)
    q, k = basis.shape
    diag = lam + inside
    tail = lam + rest[None, :] / max(q - k, 1)

    def apply(r):
        r = np.asarray(r, np.float64)
        coef = basis.T @ r
        return basis @ (coef / diag - coef / tail) + r / tail

    return apply


def _system(stream, th32, grad, curv, c, reg_diag, cols=None,
            vecs=None) -> NewtonSystem:  # fmt: skip
    """The Newton system at theta for :func:`_newton_direction`: products are
    passes over the blocks plus the regulariser's Hessian (its diagonal
    ``reg_diag`` (q, b)), preconditioned by :func:`_preconditioner` from the
    gradient pass's curvature sums ``curv``; float64 numpy on the host. ``th32``
    (q, b): theta's columns ``cols`` (None: all) in float32; ``vecs``: the
    spectral basis (None: Jacobi)."""
    lam = reg_diag if vecs is None else np.mean(reg_diag, axis=0, keepdims=True)

    def hvp(v):
        v32 = np.asarray(v, np.float32)
        if stream.top is not None:  # the curvature kept by the gradient pass
            top = np.asarray(stream.top, np.float32)
            loss = stream.run(_hess_kept, v32, top, split=2, bits="read", cols=cols)
        else:
            loss = stream.run(_hess_pass, th32, v32, c, split=2, cols=cols)
        return reg_diag * v + loss, None

    precond = _preconditioner(lam, curv, vecs)
    return NewtonSystem(grad, hvp, precond, 1.0, np.float64, None)


def _newton_direction(system: NewtonSystem, eta: float, max_iter: int):
    """The Newton step ``s`` (q, b) solving ``H s = -g`` by preconditioned CG
    from 0 (every column at once, column j stopping at ``||r_j|| <= eta
    ||g_j||``, as :func:`rhythmic_jax.solvers.newton_cg.newton_cg`'s), and the
    iterations (passes) it took. numpy float64 on the host: each iteration is
    one pass (``system.hvp``) and a few (q, b) operations, no program."""
    r = -np.asarray(system.grad, np.float64)
    target = eta * np.linalg.norm(r, axis=0, keepdims=True)
    z = system.precond(r)
    rz = np.sum(r * z, axis=0, keepdims=True)
    s, d, it = np.zeros_like(r), z, 0
    while it < max_iter:
        on = np.linalg.norm(r, axis=0, keepdims=True) > target
        if not on.any():
            break
        ad = np.asarray(system.hvp(d)[0], np.float64)
        dad = np.sum(d * ad, axis=0, keepdims=True)
        step = np.where(on, rz / np.where(dad > 0, dad, 1.0), 0.0)
        s, r = s + step * d, r - step * ad
        z = system.precond(r)
        rz_new = np.sum(r * z, axis=0, keepdims=True)
        beta = rz_new / np.where(rz > 0, rz, 1.0)
        d = np.where(on, z + beta * d, d)
        rz = np.where(on, rz_new, rz)
        it += 1
    return s, it


def _line_search(stream, th32, s, c, grad, reg, cols=None) -> np.ndarray:
    """Step length (p,) along s: two passes of ``phi'`` on grids (see module).

    ``phi(t)`` is the objective along the step: the regulariser's part, a
    quadratic in t (slope ``reg_grad . s`` at 0, curvature ``s . diag s`` from
    ``reg = (reg_grad, reg_diag)`` (q, b) of :func:`_regulariser_terms`), plus
    the blocks' (:func:`_line_pass`). numpy on the host between the passes."""
    reg_grad, reg_diag = (np.asarray(a, np.float64) for a in reg)
    s = np.asarray(s, np.float64)
    b = np.sum(reg_grad * s, axis=0)
    cc = np.sum(reg_diag * s * s, axis=0)
    s32 = s.astype(np.float32)
    lo = np.zeros_like(b)
    g_lo = np.sum(np.asarray(grad) * s, axis=0)  # phi'(0)
    hi = np.full_like(b, np.inf)
    grid = np.repeat(np.asarray(_GRID)[:, None], len(b), axis=1)
    h_lo = None
    idx = np.arange(len(b))
    for _ in range(2):
        gs, hs = stream.run(_line_pass, th32, s32, grid.astype(np.float32), c,
                            split=3, cols=cols)  # fmt: skip
        slope = b[None] + grid * cc[None] + gs  # phi'(t) at the grid
        curv = cc[None] + hs
        left = slope < 0
        t_lo = np.where(left, grid, -np.inf).max(axis=0)
        i_lo = np.where(left, grid, -np.inf).argmax(axis=0)
        better = left.any(axis=0) & (t_lo > lo)
        lo = np.where(better, t_lo, lo)
        g_lo = np.where(better, slope[i_lo, idx], g_lo)
        h_new = curv[i_lo, idx]
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


@partial(jit, static_argnames=("periods",))
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
    theta = np.concatenate([params.w, params.b[None]]).astype(np.float32)
    wrong = stream.run(_wrong_pass, theta, split=1)
    n = reduce(np.array([stop - start], np.float64))[0]
    return wrong / n
