"""Fit a map from descriptor files: in memory or streamed, on one or K processes.

:func:`fit_map_files` is what ``rhythmic-jax fit`` runs for ``.npy`` files and
folders of ``.npy`` shards. Each process takes its contiguous block of frames
(:func:`rhythmic_jax.solvers.distributed.row_block`; one process: all of them). It
fits in memory (:func:`rhythmic_jax.solvers.distributed.fit_newton`, the exact Newton
solver on global arrays) when the solver's arrays fit in the memory bound, and
otherwise streams its frames from disk in blocks sized to the bound
(:func:`rhythmic_jax.solvers.streamed.streamed_newton_fit`, sums reduced over the
processes). Either way every process ends with the same templates, training
errors and periods.

Names: n frames, d features, p templates (sum of the candidate periods).
"""

from __future__ import annotations

import logging
import os
import warnings
from collections.abc import Sequence
from pathlib import Path

import jax
import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.fitting.fit_map import check_length, fit
from rhythmic_jax.fitting.fit_plan import plan
from rhythmic_jax.io.frame_files import open_frames
from rhythmic_jax.map.config import MapConfig
from rhythmic_jax.map.groups import parse_layout
from rhythmic_jax.map.pytree import Map
from rhythmic_jax.solvers.distributed import allreduce, fit_newton, row_block
from rhythmic_jax.solvers.memory import available_memory, fit_bytes
from rhythmic_jax.solvers.newton import (
    FitWarning,
    NewtonConfig,
    NewtonInfo,
    step_cap_line,
)
from rhythmic_jax.solvers.streamed import (
    StreamConfig,
    stream_errors,
    streamed_newton_fit,
)
from rhythmic_jax.validate import check_fit_scale, parse_bytes, scale_sums

__all__ = ["block_rows_for", "fit_map_files", "parse_bytes", "resident_bytes"]

log = logging.getLogger(__name__)
SLACK = 160 * 2**20  # compilation and the runtime's buffers, beside the blocks


def resident_bytes() -> int:
    """This process's resident memory now (``/proc/self/statm``)."""
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def block_rows_for(
    memory: int, d: int, p: int, base: int | None = None, rank: int = 256
) -> int:
    """Rows per block that keep a streamed fit under ``memory`` bytes.

    A pass holds per row its features read and as the float32 design (``8 q``),
    its projection on the preconditioner's ``rank`` eigenvectors (``8 k``, k =
    min(rank, q)) and about fifteen float32 (p,) rows (margins of the templates
    and of the step, targets, hinge, active set, slacks: ``60 p``); the solver
    keeps about fifteen float64 (q, p) arrays (``120 q p``) and, while it finds
    the eigenvectors, ``Xa^T Xa`` with its eigen-solve (``32 q^2``). ``base``:
    resident bytes before the fit (default: now).
    """
    q = d + 1
    k = min(rank, q)
    solver = 120 * q * p + (32 * q * q if k else 0)
    base = resident_bytes() if base is None else base
    room = memory - base - SLACK - solver
    rows = room // (8 * q + 8 * k + 60 * p)
    if rows < 64:
        raise InputError(
            f"{{opt:memory}} {memory:,} bytes is too small to stream {d}-d frames for "
            f"{p} templates: {base:,} bytes are in use already and the solver "
            f"needs {solver + SLACK:,} more besides the blocks"
        )
    return int(min(rows, 65536))


def fit_map_files(
    config: MapConfig,
    sources: Sequence[str],
    *,
    memory: int | None = None,
    stream: bool = False,
    progress: bool = True,
    checkpoint: str | os.PathLike | None = None,
) -> tuple[Map, dict]:
    """A map fitted as ``config`` says on the frames of files.

    Args:
      sources: ``.npy`` files or shard folders, one traversal each (the same
        places, frame for frame: place of a frame = its row in its traversal).
      memory: bytes this process may use (default: what the machine has free).
      stream: stream even when an in-memory fit would fit.
      checkpoint: a folder where a streamed fit keeps its state after every
        Newton step (one file per process), so that the same fit run again goes
        on from there; the caller removes it once the map is saved.

    Returns:
      ``(map, run)``: the :class:`~rhythmic_jax.map.pytree.Map` (the same on
      every process), and how it ran: ``mode`` (memory or stream), ``rows`` of
      this process, ``block_rows``, solver ``steps`` and ``pass_seconds``
      (streamed).
    """
    traversals = [open_frames(s) for s in sources]
    n_place, d = traversals[0].shape
    for src, t in zip(sources, traversals, strict=True):
        if t.shape != (n_place, d):
            raise InputError(
                f"{src}: {t.n} frames of {t.d}-d, but {sources[0]} has {n_place} of "
                f"{d}-d; traversals of one route must match frame for frame"
            )
    frames = open_frames(sources)
    labels_all = np.tile(np.arange(n_place), len(sources))
    k, i = jax.process_count(), jax.process_index()
    start, stop = row_block(frames.n, k, i)
    labels = labels_all[start:stop]
    _check_layout(config.layout)
    fit_plan = plan(config, n_place, d)
    cands, c, p = fit_plan.periods, fit_plan.c, fit_plan.p
    limit = available_memory() if memory is None else memory
    need = sum(fit_bytes(-(-frames.n // k), d, p).values())
    in_memory = not stream and resident_bytes() + need + SLACK <= limit
    # every process must take the same path
    in_memory = allreduce(np.array([float(not in_memory)]))[0] == 0
    run = {"mode": "memory" if in_memory else "stream", "rows": stop - start}
    if in_memory and k == 1:  # the one-process fit of frames held whole
        x = frames.read(0, frames.n)
        return fit(x, config, labels=labels_all, progress=progress), run
    _check_scale(frames, start, stop)  # as the in-memory fit does, before the solve
    if in_memory:
        solver = NewtonConfig(gap_tol=config.gap, span=False)
        params, errors, info = fit_newton(
            frames.read(start, stop), labels, frames.n, cands, c, solver, progress
        )
        run["steps"] = info.steps
        _say_capped(info.gap_estimate, info.steps, solver.max_iter, config.gap)
    else:
        bits = (stop - start) * -(-p // 8)  # the kept active sets, one bit each
        keep = bits <= limit // 8
        rows = block_rows_for(limit - bits if keep else limit, d, p)
        if k > 1:  # the same block size and choice on every process
            rows = _min_over_processes(rows)
            keep = _min_over_processes(int(keep)) == 1
        fast = config.gap >= 1e-4  # FAST's CG caps for a loose gap
        solver = StreamConfig(
            gap_tol=config.gap,
            block_rows=rows,
            max_cg=8 if fast else 50,
            cg_start=3 if fast else None,
            keep_active=keep,
        )
        state = (
            None if checkpoint is None else Path(checkpoint) / f"stream-{i}-of-{k}.npz"
        )
        params, info = streamed_newton_fit(
            frames, labels, cands, c, solver, (start, stop), allreduce, progress, state
        )
        errors = stream_errors(
            frames, labels, cands, params, (start, stop), rows, allreduce
        )
        _say_capped(info.gap_estimate, info.steps, solver.max_iter, config.gap)
        run.update(block_rows=rows, steps=info.steps, passes=len(info.pass_seconds))
        run.update(kept_active_bytes=bits if keep else 0, cg=info.cg_iterations)
        run.update(line=info.line_passes)
        run.update(pass_seconds=info.pass_seconds)
        run["pass_median_s"] = float(np.median(info.pass_seconds))
    kept = fit_plan.keep(params, np.asarray(errors), config.dtype)
    log.info("fit from files: %s", {k: v for k, v in run.items() if k[0] != "p"})
    return Map.build(kept, d, config), run


def _say_capped(gap, steps: int, max_iter: int, gap_tol: float) -> None:
    """The fit's warning when its solve stopped at the step cap
    (:func:`rhythmic_jax.solvers.newton.step_cap_line`), as the in-memory fit's."""
    gap = np.asarray(gap if gap is not None else [], np.float64)
    capped = int(np.sum(gap > gap_tol)) if steps >= max_iter else 0
    info = NewtonInfo(steps, (), (), np.zeros(gap.size), gap, capped)
    line = step_cap_line(info, gap_tol, max_iter)
    if line is not None:
        warnings.warn(FitWarning(line), stacklevel=3)


def _check_layout(layout: str) -> None:
    """Refuse a layout other than periods: only the in-memory fit of one process
    trains mixed-radix and hierarchical groups."""
    if parse_layout(layout).kind != "periods":
        raise InputError(
            f"{{opt:layout}} {layout!r} needs an in-memory fit of one "
            "process; streamed and multi-process fits take periods or periods:T1,.."
        )


def _check_scale(frames, start: int, stop: int, block: int = 65536) -> None:
    """:func:`rhythmic_jax.validate.check_fit_scale` of every frame: this
    process's rows ``[start, stop)`` read once in blocks, their sums and largest
    ``|feature|`` combined over the processes, so all refuse alike."""
    sums, largest = np.zeros(frames.d + 2), 0.0
    for lo in range(start, stop, block):
        x = frames.read(lo, min(lo + block, stop))
        sums += scale_sums(x)
        largest = max(largest, float(np.abs(x).max(initial=0.0)))
    k = jax.process_count()
    onehot = np.zeros(k)
    onehot[jax.process_index()] = largest
    total = allreduce(sums)
    check_fit_scale(total, float(allreduce(onehot).max()))
    check_length(total)


def _min_over_processes(value: int) -> int:
    """The least of ``value`` over the processes."""
    k = jax.process_count()
    onehot = np.zeros(k)
    onehot[jax.process_index()] = value
    return int(allreduce(onehot).min())
