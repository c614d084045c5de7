"""How much memory a full-batch fit needs, and a guard that refuses one too large.

:func:`fit_bytes` adds up the solver's arrays (:mod:`rhythmic_jax.solvers.newton`, and
:mod:`rhythmic_jax.solvers.span` for wide frames) and XLA's compiling of them;
:func:`check_memory` compares the sum with what the machine has free and, when it
does not fit, refuses before any work with the bytes needed and the streaming path
named
(:func:`rhythmic_jax.solvers.resumable.memmap_batches` with
:func:`rhythmic_jax.solvers.resumable.train_run`).

Names: n frames, d features, p templates (sum of the candidate periods).
"""

from __future__ import annotations

import ctypes
import gc
import os
import threading
import time
from collections.abc import Callable

from rhythmic_jax.errors import InputError
from rhythmic_jax.io.reader import available_memory
from rhythmic_jax.solvers.span import in_span

__all__ = [
    "COMPILE_BYTES",
    "SCRATCH_BYTES",
    "available_memory",
    "check_memory",
    "fit_bytes",
    "peak_growth",
]


# XLA's working memory for compiling the fit's functions for a new shape (the
# Newton step, once per fit on its column groups, the spectral setup, the start
# and finish), measured with the allocator trimmed in a process whose runtime a
# fit of another shape had loaded: the first fit of a shape grew it by 122-182 MB
# more than a refit of the same frames, on six tall, square and wide shapes
# (reports/memory.md). It does not follow n, d or p.
COMPILE_BYTES = 192 * 2**20

# What a fit touches whatever its size: the threads' stacks and scratch, the
# allocator's arenas, the small arrays of the period choice. Fits of 120 x 512
# (6.4 MB of arrays) peaked at 5.4-7.9 MB on an idle machine; on a busy one (two
# other processes on its two cores) refits of 400 x 1024 (30 MB of arrays) grew
# the process by up to 55.7 MB, 18 MB beyond the arrays and their quarter.
SCRATCH_BYTES = 24 * 2**20


def fit_bytes(n: int, d: int, p: int, itemsize: int = 4) -> dict[str, int]:
    """Peak bytes a full-batch fit adds to a process
    (:func:`rhythmic_jax.solvers.newton.newton_fit`), by named part.

    With q = d + 1, k = min(512, q) leading eigenvectors and a b = min(32, k)
    block, the solver holds:

    - ``features``: the frames as given, ``n d itemsize``;
    - ``design``: a float32 copy of the frames and the design matrix ``[x, 1]``
      in float32, ``4 n d + 4 n q``, and the float64 design each Newton step's
      gradient is summed with (``8 n q``);
    - ``system``: ``Xa^T Xa`` in float32 (``4 q^2``), the subspace iteration's
      (q, k) bases and eigenvectors (``12 q k``), the frames in the eigenvectors
      ``Xa V`` (``4 n k``) and the (n, b^2) float32 outer products of their first
      b coordinates that build the per-template blocks (``4 n b^2``, n x 1024);
    - ``templates``: per template, about eleven float64 and float32 (n,) columns
      (targets, margins and their update, hinge, mask, CG's margins, the line
      search's slacks: ``80 n``), seven (q,) columns (theta, gradient, step, CG's
      residual, direction and products: ``56 q``), the preconditioner's diagonal
      and block (``4 k + 4 b^2``);
    - ``results``: after the solve, the float32 targets, the float64 final
      margins and the float32 scores of the period choice (``16 n p``), made
      while the allocator still holds the solver's freed buffers;
    - ``compile``: :data:`COMPILE_BYTES`, XLA compiling the fit's functions for
      this shape (a process that fitted this shape before compiles nothing).

    Wide frames (d > 2n) are solved in their span (:mod:`rhythmic_jax.solvers.span`):
    ``span`` counts a float64 copy of the frames, ``X X^T``, its shifted copy and
    its Cholesky factor in float64 (``8 n d + 24 n^2``) and the lifted weights
    (``8 n p + 12 d p``); the other parts are those of an (n, n) problem.

    The arrays' sum (every part but ``compile``) bounds what XLA's compiled Newton
    step holds (its arguments, results and temporaries); ``allocator`` adds a
    quarter of it for what the process holds beyond the arrays (freed buffers the
    allocator keeps) and :data:`SCRATCH_BYTES` (the threads' scratch). Measured
    with the allocator trimmed before the fit (``malloc_trim``): reports/memory.md.
    """
    if in_span(n, d):
        reduced = fit_bytes(n, n, p, 4)
        parts = {
            "features": n * d * itemsize,
            "span": 8 * n * d + 24 * n * n + 8 * n * p + 12 * d * p,
            "design": reduced["features"] + reduced["design"],
            "system": reduced["system"],
            "templates": reduced["templates"],
            "results": reduced["results"],
        }
    else:
        q = d + 1
        k = min(512, q)
        b = min(32, k)
        parts = {
            "features": n * d * itemsize,
            "design": 4 * n * d + 12 * n * q,
            "system": 4 * q * q + 12 * q * k + 4 * n * k + 4 * n * b * b,
            "templates": (80 * n + 56 * q + 4 * k + 4 * b * b) * p,
            "results": 16 * n * p,
        }
    parts["allocator"] = sum(parts.values()) // 4 + SCRATCH_BYTES
    parts["compile"] = COMPILE_BYTES
    return parts


def _resident() -> int:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def peak_growth(work: Callable[[], object]) -> int:
    """Bytes ``work()`` adds to this process's resident memory at its peak.

    Measures what ``fit_bytes`` estimates (Linux, glibc): the memory glibc holds
    freed is handed back first (``malloc_trim``), since otherwise the allocator
    serves the work from it and the growth undercounts; a thread samples the
    resident set every millisecond while the work runs.
    """
    gc.collect()
    ctypes.CDLL("libc.so.6").malloc_trim(0)
    base, peak, done = _resident(), [0], threading.Event()

    def watch():
        while not done.is_set():
            peak[0] = max(peak[0], _resident())
            time.sleep(0.001)

    sampler = threading.Thread(target=watch)
    sampler.start()
    try:
        work()
    finally:
        done.set()
        sampler.join()
    return max(peak[0], _resident()) - base


def _gib(v: float) -> str:
    return f"{v / 2**30:.2f} GiB" if v >= 2**30 else f"{v / 2**20:.1f} MiB"


def check_memory(
    n: int, d: int, p: int, itemsize: int = 4, limit_bytes: int | None = None
) -> int:
    """Refuse (:class:`InputError`) a full-batch fit that would not fit in memory.

    Args:
      n: frames; d: features; p: templates trained (sum of the candidate periods).
      itemsize: bytes per feature value.
      limit_bytes: the memory to fit in (default :func:`available_memory`).

    Returns:
      The bytes needed (:func:`fit_bytes`, summed), when they fit.
    """
    parts = fit_bytes(n, d, p, itemsize)
    need = sum(parts.values())
    limit = available_memory() if limit_bytes is None else int(limit_bytes)
    if need > limit:
        raise InputError(
            f"a full-batch fit of {n} frames x {d} features x {p} templates needs "
            f"about {need:,} bytes ({_gib(need)}: features {_gib(parts['features'])},"
            f" solver {_gib(need - parts['features'] - parts['compile'])}, compiling"
            f" {_gib(parts['compile'])}) but {limit:,} bytes "
            f"({_gib(limit)}) are available; stream the frames instead: save them to "
            "a .npy file and train with rhythmic_jax.solvers.resumable.train_run("
            "memmap_batches(path, labels, periods, batch_size, seed), ...)"
        )
    return need
