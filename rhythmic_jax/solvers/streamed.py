"""Newton-CG over frames read in blocks: a fit whose memory does not grow with n.

:func:`rhythmic_jax.solvers.newton.newton_fit` keeps every frame's margins, (n, p)
float64: 5.8 GB for 10^6 frames and 721 templates. Here nothing of size n is
kept: every quantity the Newton step needs is a sum over frames, so each is one
*pass* over the blocks (:class:`rhythmic_jax.io.frame_files.Frames`), recomputing
a block's margins ``Xa_b theta`` from the current templates as it goes:

- the gradient pass: objective, gradient ``lam theta - Xa^T (y h)`` and the
  Jacobi preconditioner ``lam + (Xa^2)^T D`` (the active set D of the step);
- one pass per CG iteration: ``Xa^T D Xa v`` with D recomputed per block;
- two line-search passes: ``phi'(t)`` and its piece's slope at a grid of
  step lengths, then at a finer grid inside the bracket found; the step is
  Newton's on the piece at the bracket's left end, kept inside the bracket
  (exact once the bracket holds one piece).

The objective and stopping rule are :mod:`rhythmic_jax.solvers.newton`'s (a template
stops once its Newton decrement is below ``gap_tol`` times its objective).
Every pass's sums go through ``reduce``
(:func:`rhythmic_jax.solvers.distributed.allreduce`
when each process streams its own rows), so K processes take the same steps.

Names: n frames, d features, q = d + 1, p templates, B rows per block.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax.io.frame_files import Frames
from rhythmic_jax.objective import Templates, targets
from rhythmic_jax.periods import period_offsets
from rhythmic_jax.progress import bar as progress_bar

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
    """

    gap_tol: float = 1e-6
    eta: float = 0.1
    max_iter: int = 40
    max_cg: int = 50
    cg_start: int | None = None
    block_rows: int = 8192

    def cg_cap(self, step: int) -> int:
        """CG iterations allowed in Newton step ``step`` (0: the ridge step)."""
        if self.cg_start is None:
            return self.max_cg
        return min(self.max_cg, self.cg_start + max(step - 1, 0))


FAST_STREAM = StreamConfig(gap_tol=1e-3, max_cg=8, cg_start=3)


@dataclass
class StreamInfo:
    """What a streamed solve did: steps, CG passes per step, seconds per pass."""

    steps: int = 0
    cg_iterations: list[int] = field(default_factory=list)
    pass_seconds: list[float] = field(default_factory=list)
    objective: np.ndarray | None = None


def _block(x: np.ndarray, rows: int):
    """A block padded to ``rows``: design (rows, q) float32 with bias 0 on padding."""
    m = len(x)
    xa = np.zeros((rows, x.shape[1] + 1), np.float32)
    xa[:m, :-1] = x
    xa[:m, -1] = 1.0
    return jnp.asarray(xa)


@partial(jax.jit, static_argnames=("periods",))
def _y(labels, periods):
    """Targets (B, p) with 0 on padding rows (label -1)."""
    return targets(labels, periods) * (labels >= 0)[:, None]


@partial(jax.jit, static_argnames=("periods",))
def _grad_pass(xa, labels, theta, periods):
    """Sums of one block: ``Xa^T (y h)`` (q, p), ``sum h^2`` (p,), ``(Xa^2)^T D``."""
    y = _y(labels, periods)
    h = jnp.maximum(0.0, 1.0 - y * (xa @ theta)) * (y != 0)
    return xa.T @ (y * h), jnp.sum(h * h, axis=0), (xa * xa).T @ (h > 0).astype(h.dtype)


@partial(jax.jit, static_argnames=("periods",))
def _hess_pass(xa, labels, theta, v, periods):
    """``Xa^T D Xa v`` (q, p) over one block, D the active set at theta."""
    y = _y(labels, periods)
    both = xa @ jnp.concatenate([theta, v], axis=1)
    p = theta.shape[1]
    mask = ((1.0 - y * both[:, :p]) > 0) & (y != 0)
    return xa.T @ (mask * both[:, p:])


@partial(jax.jit, static_argnames=("periods",))
def _line_pass(xa, labels, theta, s, ts, periods):
    """At step lengths ts (K, p): ``sum act yu slack``, ``sum act yu^2`` and
    ``sum act slack^2`` (K, p) each, ``slack = 1 - y (m + t u)``."""
    y = _y(labels, periods)
    both = xa @ jnp.concatenate([theta, s], axis=1)
    p = theta.shape[1]
    yu, slack0, live = y * both[:, p:], 1.0 - y * both[:, :p], y != 0

    def at(t):
        slack = slack0 - t[None, :] * yu
        act = (slack > 0) & live
        g = jnp.sum(jnp.where(act, yu * slack, 0.0), axis=0)
        h = jnp.sum(jnp.where(act, yu * yu, 0.0), axis=0)
        v = jnp.sum(jnp.where(act, slack * slack, 0.0), axis=0)
        return g, h, v

    return jax.lax.map(at, ts)


class _Stream:
    """Passes over this process's rows ``start .. stop``, summed by ``reduce``."""

    def __init__(self, frames, start, stop, labels, periods, rows, reduce):
        self.frames, self.start, self.stop = frames, start, stop
        self.labels, self.periods, self.rows = labels, periods, rows
        self.reduce, self.seconds = reduce, []

    def run(self, kernel, *args):
        t0 = time.perf_counter()
        total = None
        for lo in range(self.start, self.stop, self.rows):
            hi = min(self.stop, lo + self.rows)
            xa = _block(self.frames.read(lo, hi), self.rows)
            lab = np.full(self.rows, -1, np.int32)
            lab[: hi - lo] = self.labels[lo - self.start : hi - self.start]
            part = kernel(xa, jnp.asarray(lab), *args, periods=self.periods)
            part = jax.tree.map(lambda a: np.asarray(a, np.float64), part)
            total = part if total is None else jax.tree.map(np.add, total, part)
        if total is None:  # a process with no rows still joins the reduction
            total = self._zeros(kernel, *args)
        total = self.reduce(total)
        self.seconds.append(time.perf_counter() - t0)
        return total

    def _zeros(self, kernel, *args):
        xa = jnp.zeros((self.rows, self.frames.d + 1), jnp.float32)
        lab = jnp.full(self.rows, -1, jnp.int32)
        part = kernel(xa, lab, *args, periods=self.periods)
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
) -> tuple[Templates, StreamInfo]:
    """Minimise the joint squared-hinge objective with frames read in blocks.

    Args:
      frames: the frames on disk; labels: (stop - start,) places of this
        process's rows; periods: candidate periods (p = sum); c: C.
      rows: this process's ``(start, stop)`` (default: all frames).
      reduce: sums a tree of arrays over processes (default: one process).

    Returns:
      Templates ``w`` (d, p), ``b`` (p,) float32 (numpy) and a :class:`StreamInfo`.
    """
    start, stop = rows or (0, frames.n)
    periods = tuple(int(t) for t in periods)
    p, q = sum(periods), frames.d + 1
    block = max(1, min(config.block_rows, frames.n))
    stream = _Stream(frames, start, stop, np.asarray(labels, np.int32), periods,
                     block, reduce)  # fmt: skip
    lam = 0.5 / c
    theta = np.zeros((q, p))
    done = np.zeros(p, bool)
    info = StreamInfo()
    bar = progress_bar(range(config.max_iter), show=progress, desc="newton (streamed)")
    for step in bar:
        th32 = jnp.asarray(theta, jnp.float32)
        gx, hh, diag = stream.run(_grad_pass, th32)
        f0 = 0.5 * np.sum(theta * theta, axis=0) + c * hh
        grad = lam * theta - gx
        grad[:, done] = 0.0
        precond = lam + diag
        s, its = _cg(stream, th32, -grad, precond, lam, config, config.cg_cap(step))
        dec = c * np.sum(-grad * s, axis=0)
        t = _line_search(stream, th32, theta, s, c, grad)
        theta = theta + t[None, :] * s
        info.steps += 1
        info.cg_iterations.append(its)
        gap = dec / np.maximum(np.abs(f0), 1e-300)
        done |= gap <= config.gap_tol
        bar.set_postfix(
            objective=f"{f0.sum():.6g}", gap=f"{gap[~done].max(initial=0):.1e}"
        )
        if done.all():
            break
    bar.close()
    _, hh, _ = stream.run(_grad_pass, jnp.asarray(theta, jnp.float32))
    info.objective = 0.5 * np.sum(theta * theta, axis=0) + c * hh
    info.pass_seconds = stream.seconds
    theta = theta.astype(np.float32)
    return Templates(w=theta[:-1], b=theta[-1]), info


def _cg(stream, th32, r0, precond, lam, config, cap) -> tuple[np.ndarray, int]:
    """Jacobi-preconditioned CG for ``(lam I + Xa^T D Xa) s = r0``, per column."""
    target = config.eta * np.linalg.norm(r0, axis=0)
    s, r = np.zeros_like(r0), r0.copy()
    z = r / precond
    d, rz = z.copy(), np.sum(r * z, axis=0)
    its = 0
    while its < cap:
        on = np.linalg.norm(r, axis=0) > target
        if not on.any():
            break
        ad = stream.run(_hess_pass, th32, jnp.asarray(d, jnp.float32)) + lam * d
        dad = np.sum(d * ad, axis=0)
        step = np.where(on, rz / np.where(dad > 0, dad, 1.0), 0.0)
        s, r = s + step * d, r - step * ad
        z = r / precond
        rz_new = np.sum(r * z, axis=0)
        beta = rz_new / np.where(rz > 0, rz, 1.0)
        d = np.where(on, z + beta * d, d)
        rz = np.where(on, rz_new, rz)
        its += 1
    return s, its


def _line_search(stream, th32, theta, s, c, grad) -> np.ndarray:
    """Step length (p,) along s: two passes of ``phi'`` on grids (see module)."""
    b = np.sum(theta * s, axis=0)
    cc = np.sum(s * s, axis=0)
    lo = np.zeros_like(b)
    g_lo = 2 * c * np.sum(grad * s, axis=0)  # phi'(0)
    hi = np.full_like(b, np.inf)
    grid = np.repeat(np.asarray(_GRID)[:, None], len(b), axis=1)
    h_lo = None
    for _ in range(2):
        gs, hs, _ = stream.run(_line_pass, th32, jnp.asarray(s, jnp.float32),
                               jnp.asarray(grid, jnp.float32))  # fmt: skip
        slope = b[None] + grid * cc[None] - 2 * c * gs  # phi'(t) at the grid
        curv = cc[None] + 2 * c * hs
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
    # Newton on the piece right of lo (exact if the root is on it), inside the bracket
    curv0 = cc + 2 * c * (h_lo if h_lo is not None else 0.0)
    t = lo - g_lo / np.maximum(curv0, 1e-300)
    t = np.clip(t, lo, np.where(np.isfinite(hi), hi, t))
    return np.where(g_lo < 0, t, lo)


@partial(jax.jit, static_argnames=("periods",))
def _wrong_pass(xa, labels, w, periods):
    """(k,) frames of a block whose argmax phase is wrong, per period."""
    s = xa @ w
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
