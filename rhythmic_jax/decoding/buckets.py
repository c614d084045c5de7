"""Power-of-two buckets of query rows: a batch padded where it lies, cut on the host.

XLA compiles a program per input shape; a batch of b queries padded to
:func:`bucket` ``(b)`` rows (the next power of two from :data:`MIN_BUCKET` on)
shares its program with every batch of that bucket. :func:`pad_rows` pads a
numpy batch on the host (no program) and :func:`head` cuts the (b,) results
where they lie, so no shape-specific program runs around a bucketed one on a
CPU.

A batch larger than :data:`CHUNK` rows is decoded by :func:`over_chunks`, inside
its one jitted program: a loop over chunks of :data:`CHUNK` rows of the
uploaded (bucket, d) batch, each chunk's results written into (bucket, ...)
outputs on the device. The loop runs only over the chunks that hold queries
(their count is an argument, not a shape), there is no host round trip per
chunk, and a bucket of chunks is one program. The buckets above
:data:`CHUNK` are whole numbers of chunks, as both are powers of two.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax.jit_options import jit

__all__ = [
    "CHUNK",
    "MIN_BUCKET",
    "bucket",
    "chunk_count",
    "head",
    "in_host_memory",
    "over_chunks",
    "pad_rows",
]

MIN_BUCKET = 16
"""The smallest bucket: batches of 1-16 queries share one program."""


CHUNK = 8192
"""Rows a large batch is decoded by at a time (a power of two): a program holds
one chunk's scores, CHUNK x p float32 (32 MiB for p = 1024 templates; the soft
and top-m decodes score places in batches of 256 queries within it), never the
(b, p) scores of the whole batch, and its queries."""


def bucket(b: int) -> int:
    """Rows a batch of ``b`` queries is padded to: the smallest power of two
    ``>= max(b, MIN_BUCKET)``."""
    return max(MIN_BUCKET, 1 << max(int(b) - 1, 0).bit_length())


@functools.partial(jit, static_argnames=("rows",))
def _pad_device(x: jax.Array, rows: int) -> jax.Array:
    return jnp.pad(x, ((0, rows - x.shape[0]),) + ((0, 0),) * (x.ndim - 1))


def pad_rows(x) -> tuple[jax.Array | np.ndarray, int]:
    """``x`` (b, ...) with zero rows appended up to :func:`bucket` ``(b)``, and b.

    A numpy array is padded on the host (no program is compiled; the jitted
    call that takes it copies it to the device once); a JAX array on its device
    (a small program per input shape)."""
    if not isinstance(x, jax.Array):
        x = np.asarray(x)
    b = x.shape[0]
    rows = bucket(b)
    if rows == b:
        return x, b
    if isinstance(x, jax.Array):
        return _pad_device(x, rows), b
    out = np.zeros((rows,) + x.shape[1:], x.dtype)
    out[:b] = x
    return out, b


def in_host_memory(a) -> np.ndarray | None:
    """``a`` as a numpy array where it lies in host memory already (a numpy
    array, or a JAX array on a CPU device: a view, no copy and no program);
    None for a tracer or an array on another device."""
    if isinstance(a, np.ndarray):
        return a
    if isinstance(a, jax.core.Tracer) or not isinstance(a, jax.Array):
        return None
    if all(d.platform == "cpu" for d in a.devices()):
        return np.asarray(a)
    return None


def head(tree, b: int):
    """The first ``b`` rows of every array of ``tree``, cut where it lies: in
    host memory a view (on a CPU device the results are there already; cutting
    them with XLA would compile a program per b), on another device a slice
    there (the results stay on the device until the caller asks for them)."""

    def cut(a):
        host = in_host_memory(a)
        a = a if host is None else host
        return a if a.shape[0] == b else a[:b]

    return jax.tree.map(cut, tree)


def chunk_count(b: int, chunk: int | None = None) -> int:
    """Chunks of ``chunk`` rows (default :data:`CHUNK`) that hold ``b`` queries:
    ``ceil(b / chunk)``, at least 1."""
    chunk = CHUNK if chunk is None else chunk
    return max(1, -(-int(b) // chunk))


def over_chunks(body, params, x, count, chunk: int, history: int = 0):
    """``body`` over the chunks of queries x (rows, d), inside a trace.

    ``body(params, window, start)`` decodes the rows ``start : start + c`` of x
    from ``window``, x's rows ``start - history : start + c`` (rows before row
    0 are zero: a sequence decode masks them by ``start``), and returns a
    pytree of (c, ...) arrays. With ``rows <= chunk`` that is one call on every
    row (c = rows, start 0); above, ``rows`` is a whole number of chunks (c =
    ``chunk``) and a loop over the first ``count`` of them (a traced int32:
    the batch's :func:`chunk_count`, so a bucket compiles once) writes their
    results into (rows, ...) outputs; the rows of chunks past ``count`` stay
    zero, for :func:`head` to cut.
    """
    rows = x.shape[0]
    if history:
        x = jnp.pad(x, ((history, 0),) + ((0, 0),) * (x.ndim - 1))
    if rows <= chunk:
        return body(params, x, 0)
    if rows % chunk:
        raise ValueError(f"{rows} rows are not a whole number of {chunk}-row chunks")

    def piece(i):
        start = i * chunk
        window = jax.lax.dynamic_slice_in_dim(x, start, chunk + history, axis=0)
        return body(params, window, start)

    shapes = jax.eval_shape(piece, jnp.int32(0))
    init = jax.tree.map(lambda s: jnp.zeros((rows,) + s.shape[1:], s.dtype), shapes)

    def step(i, acc):
        return jax.tree.map(
            lambda a, o: jax.lax.dynamic_update_slice_in_dim(a, o, i * chunk, 0),
            acc,
            piece(i),
        )

    return jax.lax.fori_loop(0, count, step, init)
