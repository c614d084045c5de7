"""Power-of-two buckets of query rows: a batch padded where it lies, cut on the host.

XLA compiles a program per input shape; a batch of b queries padded to
:func:`bucket` ``(b)`` rows (the next power of two from :data:`MIN_BUCKET` on)
shares its program with every batch of that bucket. :func:`pad_rows` pads a
numpy batch on the host (no program) and :func:`head` cuts the (b,) results
where they lie, so no shape-specific program runs around a bucketed one on a
CPU.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax.jit_options import jit

__all__ = ["MIN_BUCKET", "bucket", "head", "in_host_memory", "pad_rows"]

MIN_BUCKET = 16
"""The smallest bucket: batches of 1-16 queries share one program."""


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
