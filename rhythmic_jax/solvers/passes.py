"""Sums over frames read from disk in blocks, one *pass* each.

A fit whose frames do not fit in memory (:mod:`rhythmic_jax.solvers.streamed`)
gets every sum over frames a Newton step needs from a pass: :class:`Passes`
reads this process's rows block by block
(:class:`rhythmic_jax.io.frame_files.Frames`), pads each to one shape (zero rows
with bias 0 and label -1, which add nothing), runs a jitted kernel on it, adds
the blocks' results in float64 and sums them over processes with ``reduce``
(:func:`rhythmic_jax.solvers.distributed.allreduce`). The kernels are autodiff of
the loss term of :func:`rhythmic_jax.solvers.objective.margin_objectives` (the objective
without its regulariser) at a block's margins ``Xa_b theta``, recomputed from the
templates as the block is read:

- :meth:`Passes.gram`: ``Xa^T Xa`` (q, q), for the preconditioner's basis;
- :meth:`Passes.gradient`: the loss, its gradient ``sum_b Xa_b^T dL/dm_b`` and
  :func:`~rhythmic_jax.solvers.precondition.curvature_sums` of its curvature h;
- :meth:`Passes.hessian`: ``sum_b Xa_b^T (h_b * Xa_b v)``, the linearised
  gradient applied to ``Xa_b v``; when h takes one value wherever it is not 0
  (the squared hinge: 2C on the active set), a gradient pass with ``keep``
  keeps where it is not 0 as bits (38 MB for 10^6 frames and 304 templates)
  and a Hessian pass makes one product with the frames instead of two;
- :meth:`Passes.line`: the loss along a step and its first two derivatives;
- :meth:`Passes.wrong`: each period's wrong phases.

A pass may carry some templates only (``cols``), in kernel calls of one width,
so that each kernel compiles for two shapes at most: every column, and that
width.

Names: B rows per block, q = d + 1, p templates, g periods.
"""

from __future__ import annotations

import time
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax.jit_options import jit
from rhythmic_jax.map.periods import period_offsets
from rhythmic_jax.solvers.objective import margin_objectives, targets
from rhythmic_jax.solvers.precondition import curvature_sums

__all__ = ["Passes"]


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
    no parameters (the fit counts the regulariser once); padding rows (label
    -1) weigh 0. ``cols`` (b,): the templates m holds (None: all p)."""
    y = targets(jnp.maximum(labels, 0), periods)
    if cols is not None:
        y = y[:, cols]
    empty = jnp.zeros((0, m.shape[1]), m.dtype)
    return margin_objectives(empty, m, y, c, (labels >= 0).astype(m.dtype))


def _loss_grad(labels, periods, c, cols=None):
    """The gradient of a block's summed loss in its margins, ``m -> dL/dm``."""
    return jax.grad(lambda m: jnp.sum(_block_loss(m, labels, periods, c, cols)))


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
    gx = jnp.matmul(xa.T, dm, precision="highest")
    return (loss, gx, curvature_sums(xa, h, vecs)), h


@partial(jit, static_argnames=("periods",))
def _grad_pass(xa, labels, theta, c, vecs=None, *, periods, cols=None):
    """Sums of one block: the loss (p,), its gradient in theta ``Xa^T dL/dm``
    (q, p) and what the preconditioner needs of the loss's Hessian
    (:func:`~rhythmic_jax.solvers.precondition.curvature_sums` of ``h`` in the
    basis ``vecs``), ``h`` the loss's curvature at the margins (the Hessian in m
    is diagonal). ``cols`` (b,): theta (q, b) holds
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


_LINE_PARTS = 4  # row chunks of a line pass: float64 temporaries, a quarter each


@partial(jit, static_argnames=("periods",))
def _line_pass(xa, labels, theta, s, t, c, periods, cols=None):
    """The block's loss along the step, ``phi_b(t) = L_b(m + t Xa s)`` per
    template, at the step lengths t (1, p): ``phi_b(t) - phi_b(0)``, ``phi_b'(t)``
    and ``phi_b''(t)``, (1, p) each.

    In the margins: with ``u = Xa s``, ``phi_b'(t) = sum_i g_i u_i`` and
    ``phi_b''(t) = sum_i (H u)_i u_i``, g and H u the loss's gradient at
    ``m + t u`` and its product with u (one ``jax.jvp`` of the gradient), summed
    over the block's frames per template; 1.5x cheaper than differentiating
    ``phi_b`` in t twice. The margins are float32 products, then taken to t's
    dtype (float64 in a fit): ``phi_b`` is then piecewise quadratic in t to
    float64 rounding, and the exact line search's Newton iterations stop on its
    minimiser instead of wandering in float32's rounding of ``m + t u``. The
    rows go in ``_LINE_PARTS`` chunks (padded with rows of label -1), so the
    float64 temporaries take no more memory than the float32 ones of the other
    passes."""
    rows = -(-xa.shape[0] // _LINE_PARTS)
    pad = rows * _LINE_PARTS - xa.shape[0]
    xs = jnp.pad(xa, ((0, pad), (0, 0))).reshape(_LINE_PARTS, rows, -1)
    ls = jnp.pad(labels, (0, pad), constant_values=-1).reshape(_LINE_PARTS, rows)
    both = jnp.concatenate([theta, s], axis=1)
    p = theta.shape[1]

    def part(chunk):
        xa, labels = chunk
        mu = jnp.matmul(xa, both, precision="highest").astype(t.dtype)
        m, u = mu[:, :p], mu[:, p:]
        g, hu = jax.jvp(_loss_grad(labels, periods, c, cols), (m + t * u,), (u,))
        change = _block_loss(m + t * u, labels, periods, c, cols) - _block_loss(
            m, labels, periods, c, cols
        )
        return change, jnp.sum(g * u, axis=0), jnp.sum(hu * u, axis=0)

    return tuple(jnp.sum(a, axis=0, keepdims=True) for a in jax.lax.map(part, (xs, ls)))


@partial(jit, static_argnames=("periods",))
def _wrong_pass(xa, labels, w, periods):
    """(g,) frames of a block whose argmax phase is wrong, per period."""
    s = jnp.matmul(xa, w, precision="highest")
    out = []
    for off, t in zip(period_offsets(periods), periods, strict=True):
        pred = jnp.argmax(s[:, off : off + t], axis=1)
        out.append(jnp.sum((pred != labels % t) & (labels >= 0)))
    return jnp.stack(out)


class Passes:
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

    def gram(self) -> np.ndarray:
        """``Xa^T Xa`` (q, q) over every frame."""
        return self.run(_gram_pass)

    def gradient(self, theta, c, vecs=None, cols=None, keep=False):
        """The loss (b,), its gradient in theta (q, b) and the curvature sums
        in the basis ``vecs`` (None: Jacobi's) at theta (q, b) float32 of the
        templates ``cols`` (None: all). ``keep``: keep where the curvature is
        not 0 for the Hessian passes that follow (when it takes one value)."""
        if keep:
            return self.run(_grad_keep, theta, c, vecs, split=1, bits="write",
                            cols=cols)  # fmt: skip
        return self.run(_grad_pass, theta, c, vecs, split=1, cols=cols)

    def hessian(self, theta, v, c, cols=None) -> np.ndarray:
        """The loss's Hessian at theta (q, b) applied to v (q, b), both float32:
        from the kept curvature where the last gradient pass kept one value."""
        if self.top is not None:
            top = np.asarray(self.top, np.float32)
            return self.run(_hess_kept, v, top, split=2, bits="read", cols=cols)
        return self.run(_hess_pass, theta, v, c, split=2, cols=cols)

    def line(self, theta, s, t, c, cols=None):
        """The loss along the step s (q, b) from theta (q, b), both float32, at
        step lengths t (1, b): :func:`_line_pass`'s sums."""
        return self.run(_line_pass, theta, s, t, c, split=3, cols=cols)

    def wrong(self, w) -> np.ndarray:
        """(g,) frames whose argmax phase is wrong, per period, for the
        templates w (q, p) float32 (bias last)."""
        return self.run(_wrong_pass, w, split=1)

    def run(self, kernel, *args, split: int = 0, bits: str | None = None,
            cols=None):  # fmt: skip
        """Sum ``kernel`` over the blocks. The first ``split`` arguments hold
        the templates on their last axis (cut into the calls of ``cols``); the
        others are the same for every call. Every kernel is called as
        ``kernel(xa (B, q), labels (B,), *args, periods=, cols=)``. ``bits``:
        "write" keeps the kernel's second output (where the curvature is not 0,
        packed to bits (B, ceil(p / 8)) uint8, its largest value (p,) and whether
        it takes that one value wherever it is not 0) as ``bits`` and ``top``;
        "read" passes the kept bits to the kernel in place of the labels.
        ``cols`` (b,): the templates the arguments hold (None: all)."""
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
        kept bits), the calls' columns side by side."""
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
