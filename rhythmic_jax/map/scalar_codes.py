"""8-bit scalar codes per place: every dimension quantised on its own range.

The reference frames ``x`` (n, d) are stored as one byte per dimension,

    code[i, j] = floor(255 * clip((x[i, j] - vmin[j]) / vdiff[j], 0, 1))
    x'[i, j]   = vmin[j] + (code[i, j] + 0.5) / 255 * vdiff[j]

with ``vmin`` and ``vdiff`` the per-dimension minimum and range of the frames
(faiss's ``ScalarQuantizer`` ``QT_8bit`` with its min-max range: the codes equal
faiss's bit for bit, which the tests check). A query is compared with every
decoded reference by cosine similarity, in JAX, without decoding the whole
database in a separate step.

Where ITQ (:mod:`rhythmic_jax.map.codes`) keeps ``bits`` signs of a projection, these
codes keep every dimension: ``d`` bytes a place, a quarter of float32. On a
low-dimensional embedding (k = 64-256) that is what makes them worth their bytes.

Storage: ``n * d + 2 * d * 4`` bytes: a per-place part and a fixed part.

Shapes: ``n`` places, ``b`` queries, ``d`` features.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.jit_options import jit
from rhythmic_jax.validate import check_features

__all__ = ["ScalarCodeBook", "scalar_code_bytes"]

_F32 = 4
LEVELS = 255
# up to this many queries the codes are read by a fused multiply-and-sum a query
# at a time (10 against 140 ms for one query of 2,356 x 10,976 codes on a CPU,
# where making the codes float costs 30 ms); above, one product for the batch
FUSED_QUERIES = 4


def scalar_code_bytes(n: int, d: int) -> dict[str, int]:
    """Storage of ``n`` 8-bit codes of d-dim frames: ``{"fixed", "per_place",
    "total"}`` in bytes (the range ``vmin``, ``vdiff`` in float32 is fixed)."""
    fixed, per_place = 2 * int(d) * _F32, int(n) * int(d)
    return {"fixed": fixed, "per_place": per_place, "total": fixed + per_place}


@jit
def _cosine(q, codes, vmin, vdiff, inv_norm) -> jax.Array:
    """Cosine of queries (b, d) with the decoded codes (n, d) -> (b, n), the
    database never decoded: ``q . x'_i = (q * step) . code_i + q . (vmin +
    step / 2)`` with ``step = vdiff / 255``, over ``|x'_i|`` (``inv_norm`` (n,)
    holds ``1 / |x'_i|``). One product with the codes, as brute force's."""
    step = vdiff / LEVELS
    q = q / jnp.maximum(jnp.linalg.norm(q, axis=1, keepdims=True), 1e-12)
    qs = q * step[None, :]
    if q.shape[0] <= FUSED_QUERIES:  # one fused pass over the codes, no float copy
        # a query at a time: XLA reduces (n, d) rows fast, a (b, n, d) block slowly
        wide = codes.astype(jnp.float32)
        dots = jnp.stack([(wide * row[None, :]).sum(1) for row in qs])
    else:  # a batch: one product, the codes made float once for all its queries
        rows = (((1,), (1,)), ((), ()))  # q's features against each code's
        dots = jax.lax.dot_general(qs, codes.astype(jnp.float32), rows,
                                   precision=jax.lax.Precision.HIGHEST)  # fmt: skip
    dots = dots + jnp.matmul(q, vmin + 0.5 * step, precision="highest")[:, None]
    return dots * inv_norm[None, :]


def _inverse_norms(codes, vmin, vdiff, xp=jnp):
    """``1 / |x'_i|`` (n,) of the decoded codes, a block of rows at a time on
    the host (``xp`` numpy) or in one step inside a trace (``xp`` jax.numpy)."""
    step = vdiff / LEVELS
    if xp is jnp:
        ref = vmin[None, :] + (codes.astype(jnp.float32) + 0.5) * step[None, :]
        return 1.0 / jnp.maximum(jnp.linalg.norm(ref, axis=1), 1e-12)
    out = np.empty(len(codes), np.float32)
    for lo in range(0, len(codes), 8192):
        ref = vmin[None, :] + (codes[lo : lo + 8192] + np.float32(0.5)) * step[None, :]
        out[lo : lo + 8192] = 1.0 / np.maximum(np.linalg.norm(ref, axis=1), 1e-12)
    return out


@dataclass(frozen=True)
class ScalarCodeBook:
    """One 8-bit code per place and the range that made them.

    Attributes:
      vmin: (d,) float32, per-dimension minimum of the frames the range was fitted on.
      vdiff: (d,) float32, per-dimension range (max - min; 1 where it is 0).
      codes: (n, d) uint8, the code of place i in row i.
    """

    vmin: np.ndarray
    vdiff: np.ndarray
    codes: np.ndarray

    kind = "int8"

    @classmethod
    def fit(cls, x, fit_on=None) -> ScalarCodeBook:
        """Codes of the places x (n, d); the range fitted on ``fit_on`` (default x)."""
        x = np.asarray(check_features(x, "frames for the codes"), np.float32)
        f = x if fit_on is None else np.asarray(
            check_features(fit_on, "frames for the code range", d=x.shape[1]),
            np.float32,
        )  # fmt: skip
        vmin = f.min(axis=0)
        vdiff = f.max(axis=0) - vmin
        vdiff = np.where(vdiff > 0, vdiff, 1.0).astype(np.float32)
        u = np.clip((x - vmin[None, :]) / vdiff[None, :], 0.0, 1.0)
        return cls(vmin, vdiff, (LEVELS * u).astype(np.uint8))  # faiss's 8-bit codec

    @property
    def d(self) -> int:
        return int(self.codes.shape[1])

    @property
    def bits(self) -> int:
        """Bits a place: 8 per dimension."""
        return 8 * self.d

    def decode(self) -> np.ndarray:
        """(n, d) float32: the frames as the codes keep them."""
        return (
            self.vmin[None, :]
            + (self.codes + np.float32(0.5)) * (self.vdiff / LEVELS)[None, :]
        )

    def similarity(self, q) -> jax.Array:
        """Cosine of each query (b, d) with each decoded place: (b, n) float32
        (inside a trace, q is taken as it is). The places' norms are computed
        once per book (kept beside it), not per call."""
        if not isinstance(q, jax.core.Tracer):
            q = check_features(q, "queries for the codes", d=self.d)
        if isinstance(self.codes, jax.core.Tracer):  # the book itself traced
            book = (self.codes, self.vmin, self.vdiff,
                    _inverse_norms(self.codes, self.vmin, self.vdiff))  # fmt: skip
        else:
            book = self._on_device
        return _cosine(jnp.asarray(q, jnp.float32), *book)

    @functools.cached_property
    def _on_device(self) -> tuple[jax.Array, ...]:
        """The codes, range and places' ``1 / |x'_i|`` put on the device once
        per book: copying the codes to it on every call cost more than the
        product itself."""
        # 3.3 of 4.2 ms a query for 2,356 x 2,048 codes on a CPU
        codes, vmin, vdiff = (np.asarray(a)
                              for a in (self.codes, self.vmin, self.vdiff))  # fmt: skip
        inv = _inverse_norms(codes, vmin, vdiff, np)
        return tuple(jax.device_put(a) for a in (codes, vmin, vdiff, inv))

    def storage(self) -> dict[str, int]:
        """:func:`scalar_code_bytes` of this book."""
        return scalar_code_bytes(len(self.codes), self.d)

    def arrays(self) -> dict[str, np.ndarray]:
        """What a map folder stores: the range and the codes."""
        return {
            "codes_vmin": self.vmin,
            "codes_vdiff": self.vdiff,
            "codes_uint8": self.codes,
        }

    @classmethod
    def from_arrays(cls, arrays: dict, n: int, d: int) -> ScalarCodeBook:
        """Inverse of :meth:`arrays`; shapes checked against n and d."""
        vmin, vdiff = arrays["codes_vmin"], arrays["codes_vdiff"]
        codes = arrays["codes_uint8"]
        if (vmin.shape, vdiff.shape, codes.shape) != ((d,), (d,), (n, d)):
            raise InputError(
                f"8-bit codes of shapes {vmin.shape}, {vdiff.shape}, {codes.shape} "
                f"do not fit n={n}, d={d}"
            )
        if codes.dtype != np.uint8:
            raise InputError(f"8-bit codes stored as {codes.dtype}, not uint8")
        return cls(vmin.astype(np.float32), vdiff.astype(np.float32), codes)


# a pytree of its arrays (nothing static: kind is a class name)
jax.tree_util.register_dataclass(ScalarCodeBook, ["vmin", "vdiff", "codes"], [])
