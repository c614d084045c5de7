"""Templates stored in fewer bytes: float16, or int8 with a scale per template.

A template is a column ``(w_j, b_j)`` of ``d + 1`` numbers. ``float16`` halves
the map; ``int8`` stores ``round(theta_j / s_j)`` with ``s_j = max |theta_j| /
127`` (one float32 scale per template), a quarter of the map plus 4 bytes per
template. Queries are scored with the stored values turned back into float32
(:func:`dequantize`), so a map's accuracy is that of what it stores
(``reports/scale.md`` measures each dtype's self-query accuracy).

Names: d features, p templates. :data:`DTYPES` is read without numpy (the
command line offers it); the functions import numpy when they run.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from rhythmic_jax.errors import InputError

if TYPE_CHECKING:
    import numpy as np

__all__ = ["DTYPES", "dequantize", "quantize", "requantize", "template_bytes"]

DTYPES = ("float32", "float16", "int8")


def _check(dtype: str) -> str:
    if dtype not in DTYPES:
        raise InputError(f"dtype must be one of {DTYPES}, got {dtype!r}")
    return dtype


def quantize(w: np.ndarray, b: np.ndarray, dtype: str) -> dict[str, np.ndarray]:
    """Stored arrays of templates w (d, p), b (p,): ``w``, ``b`` in ``dtype``,
    and for int8 the (p,) float32 ``scale``."""
    import numpy as np

    w, b = np.asarray(w, np.float32), np.asarray(b, np.float32)
    if _check(dtype) != "int8":
        return {"w": w.astype(dtype), "b": b.astype(dtype)}
    top = np.maximum(np.abs(w).max(axis=0), np.abs(b))
    scale = np.where(top > 0, top / 127.0, 1.0).astype(np.float32)
    q = lambda v: np.clip(np.rint(v / scale), -127, 127).astype(np.int8)  # noqa: E731
    return {"w": q(w), "b": q(b), "scale": scale}


def dequantize(arrays: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """float32 ``w`` (d, p), ``b`` (p,) from :func:`quantize`'s arrays."""
    import numpy as np

    w, b = np.asarray(arrays["w"]), np.asarray(arrays["b"])
    if w.dtype == np.int8:
        scale = np.asarray(arrays["scale"], np.float32)
        return w.astype(np.float32) * scale, b.astype(np.float32) * scale
    return w.astype(np.float32), b.astype(np.float32)


def requantize(arrays: dict[str, np.ndarray], dtype: str):
    """``(stored, (w, b))``: the values of :func:`quantize`'s ``arrays`` stored
    again as ``dtype``, and the float32 values of that."""
    stored = quantize(*dequantize(arrays), dtype)
    return stored, dequantize(stored)


def template_bytes(p: int, d: int, dtype: str) -> int:
    """Bytes of p templates of d + 1 numbers in ``dtype`` (int8: plus a float32
    scale per template)."""
    import numpy as np

    size = np.dtype(_check(dtype)).itemsize
    return p * (d + 1) * size + (4 * p if dtype == "int8" else 0)
