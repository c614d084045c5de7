"""Compact binary codes per place: ITQ fitted with faiss, applied in JAX.

Iterative quantisation (Gong et al., TPAMI 2013) maps a descriptor ``x`` (d,) to
``bits`` signs of a learned projection,

    code(x) = [(x - mu) A^T > 0]          A: (bits, d) = PCA then rotation,

and compares two codes by the number of bits they share, ``bits - hamming``. The
projection is fitted once with faiss (``ITQTransform`` with PCA, exactly the
transform of :class:`rhythmic_jax.eval.baselines.ITQ`) and then applied with a JAX
matrix product, so queries need no faiss; the codes equal faiss's ``IndexLSH``
codes bit for bit. Codes are stored packed, 8 bits a byte, least significant bit
first (faiss's layout).

Storage (float32 transform): ``n * ceil(bits / 8) + (bits * d + d) * 4`` bytes:
a per-place part and a fixed part (the mean and the projection).

Shapes: ``n`` places, ``b`` queries, ``d`` features, ``bits`` code length.
"""

from __future__ import annotations

import contextlib
import functools
import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.jit_options import jit
from rhythmic_jax.map.config import INT8, codes_setting
from rhythmic_jax.map.scalar_codes import ScalarCodeBook
from rhythmic_jax.validate import check_features

__all__ = [
    "CodeBook",
    "CodeTransform",
    "check_bits",
    "check_codes",
    "code_bytes",
    "code_similarity",
    "codebook_from_arrays",
    "fit_codebook",
    "fit_codes",
    "one_thread",
    "pack_bits",
    "unpack_bits",
]

_F32 = 4


def code_bytes(n: int, d: int, bits: int) -> dict[str, int]:
    """Storage of ``n`` codes of ``bits`` bits over d-dim descriptors, in bytes.

    ``{"fixed": (bits * d + d) * 4, "per_place": n * ceil(bits / 8), "total": sum}``
    (the same total as :func:`rhythmic_jax.eval.baselines.itq_storage_bytes`).
    """
    fixed = (int(bits) * int(d) + int(d)) * _F32
    per_place = int(n) * math.ceil(int(bits) / 8)
    return {"fixed": fixed, "per_place": per_place, "total": fixed + per_place}


def check_bits(bits, d: int, name: str = "codes", n: int | None = None) -> int:
    """``bits`` as an int in ``[1, d]`` (PCA cannot add dimensions) and, with the
    ``n`` frames ITQ is fitted on, at most ``n`` (their PCA has no more axes:
    faiss would stop in ``PCAMatrix::prepare_Ab``); else one line."""
    ok = isinstance(bits, int | np.integer) and not isinstance(bits, bool)
    if not ok or bits < 1:
        raise InputError(
            f"{name} must be a number of bits in [1, d={d}] (ITQ projects the "
            f"{d}-d descriptors to that many dimensions), got {bits!r}"
        )
    if bits > d:
        raise InputError(
            f"{{opt:{name}}} {bits}: at most d={d} bits (a number of bits in "
            f"[1, d={d}]: ITQ projects the {d}-d frames the map is fitted on, "
            "embedded where it has an embedding, to that many dimensions)"
        )
    if n is not None and bits > n:
        raise InputError(
            f"{{opt:{name}}} {bits}: at most {n} bits on {n} places (ITQ's PCA "
            f"of {n} frames has {n} axes); give {n} bits or fewer, or int8"
        )
    return int(bits)


def pack_bits(bits: np.ndarray) -> np.ndarray:
    """(..., bits) bool -> (..., ceil(bits/8)) uint8, least significant bit first."""
    return np.packbits(np.asarray(bits, bool), axis=-1, bitorder="little")


def unpack_bits(packed: np.ndarray, bits: int) -> np.ndarray:
    """(..., ceil(bits/8)) uint8 -> (..., bits) bool; inverse of :func:`pack_bits`."""
    out = np.unpackbits(np.asarray(packed, np.uint8), axis=-1, bitorder="little")
    return out[..., :bits].astype(bool)


@jit
def _encode(mean: jax.Array, projection: jax.Array, x: jax.Array) -> jax.Array:
    return jnp.matmul(x - mean[None, :], projection.T, precision="highest") > 0


@jit
def _similarity(mean, projection, ref_signs, x) -> jax.Array:
    """:func:`code_similarity` of x's codes, (b, d) -> (b, n), in one program."""
    return _agreements(_encode(mean, projection, x), ref_signs)


@jit
def _agreements(q_bits: jax.Array, ref_signs: jax.Array) -> jax.Array:
    signs = jnp.where(q_bits, 1.0, -1.0).astype(ref_signs.dtype)
    return 0.5 * (
        ref_signs.shape[1] + jnp.matmul(signs, ref_signs.T, precision="highest")
    )


def code_similarity(q_bits, ref_bits) -> jax.Array:
    """Bits shared by every query and reference code: (b, bits), (n, bits) -> (b, n).

    ``bits - hamming(q, r)``, computed as ``(bits + s_q . s_r) / 2`` with the codes
    as ±1 vectors (one matrix product; exact in float32 below 2**24 bits).
    """
    q_bits, ref_bits = jnp.asarray(q_bits, bool), jnp.asarray(ref_bits, bool)
    if q_bits.ndim != 2 or ref_bits.ndim != 2 or q_bits.shape[1] != ref_bits.shape[1]:
        raise InputError(
            f"codes must be (b, bits) and (n, bits) with the same bits, got "
            f"{q_bits.shape} and {ref_bits.shape}"
        )
    return _agreements(q_bits, jnp.where(ref_bits, 1.0, -1.0).astype(jnp.float32))


@dataclass(frozen=True)
class CodeTransform:
    """A fitted ITQ transform: ``code(x) = (x - mean) @ projection.T > 0``.

    Attributes:
      mean: (d,) float32, the mean of the frames it was fitted on.
      projection: (bits, d) float32, PCA to ``bits`` dims then the ITQ rotation.
    """

    mean: np.ndarray
    projection: np.ndarray

    @property
    def bits(self) -> int:
        return int(self.projection.shape[0])

    @property
    def d(self) -> int:
        return int(self.projection.shape[1])

    def encode(self, x) -> np.ndarray | jax.Array:
        """(b, d) descriptors -> (b, bits) bool codes (a jitted matrix product).

        Inside a trace (``jax.jit``, ``jax.vmap``) x is taken as it is and the
        codes stay traced, so a map with codes decodes under ``jax.jit`` with
        the eager answer; else x is checked and the codes come to the host."""
        if isinstance(x, jax.core.Tracer) or isinstance(self.mean, jax.core.Tracer):
            return _encode(self.mean, self.projection, x)
        x = check_features(x, "descriptors to encode", d=self.d)
        return np.asarray(_encode(self.mean, self.projection, jnp.asarray(x)))


@contextlib.contextmanager
def one_thread():
    """faiss's OpenMP and the BLAS on one thread within the block; the caller's
    thread counts are restored after it (:func:`fit_codes`)."""
    import faiss
    from threadpoolctl import threadpool_limits

    threads = faiss.omp_get_max_threads()
    try:
        with threadpool_limits(limits=1):
            faiss.omp_set_num_threads(1)
            yield
    finally:
        faiss.omp_set_num_threads(threads)


def fit_codes(x, bits: int) -> CodeTransform:
    """Fit ITQ with ``bits`` bits on frames x (n, d) through faiss ``ITQTransform``.

    faiss centres the frames, keeps their ``bits`` leading principal directions and
    runs 50 ITQ rotation iterations from a fixed seed. The fit runs on one thread
    (faiss's OpenMP and its BLAS), whatever the caller set, and restores their
    counts: the fit amplifies the rounding of a multi-threaded BLAS, so fits on
    one and on two threads gave different codes, and a figure made under other
    thread settings could not be reproduced.
    """
    import faiss  # deferred: queries of a fitted transform need only JAX

    x = np.ascontiguousarray(check_features(x, "frames for the codes"), np.float32)
    if len(x) < 2:
        raise InputError(f"codes need at least 2 frames to fit ITQ, got {len(x)}")
    bits = check_bits(bits, x.shape[1], n=len(x))  # before faiss, which aborts
    itq = faiss.ITQTransform(x.shape[1], bits, True)
    with one_thread():
        itq.train(x)
    mean = faiss.vector_to_array(itq.mean).astype(np.float32)
    proj = faiss.vector_to_array(itq.pca_then_itq.A).reshape(bits, x.shape[1])
    return CodeTransform(mean=mean, projection=proj.astype(np.float32))


@dataclass(frozen=True)
class CodeBook:
    """One code per place and the transform that made them.

    Attributes:
      transform: the fitted :class:`CodeTransform`.
      codes: (n, bits) bool, the code of place i in row i.
    """

    transform: CodeTransform
    codes: np.ndarray

    kind = "itq"

    @classmethod
    def fit(cls, x, bits: int, fit_on=None) -> CodeBook:
        """Codes of the places x (n, d); ITQ fitted on ``fit_on`` (default x)."""
        transform = fit_codes(x if fit_on is None else fit_on, bits)
        return cls(transform, transform.encode(x))

    @property
    def bits(self) -> int:
        return self.transform.bits

    def similarity(self, q) -> jax.Array:
        """Bits each query (b, d) shares with each place: (b, n) float32 (inside a
        trace, q is taken as it is). Encoding and comparing run as one program on
        the book's arrays, put on the device once per book."""
        traced = (self.codes, self.transform.mean, q)
        if any(isinstance(a, jax.core.Tracer) for a in traced):
            return code_similarity(self.transform.encode(q), self.codes)
        q = check_features(q, "descriptors to encode", d=self.transform.d)
        return _similarity(*self._on_device, jnp.asarray(q, jnp.float32))

    @functools.cached_property
    def _on_device(self) -> tuple[jax.Array, ...]:
        """The mean, projection and the codes as ±1 signs, on the device once per
        book: building the signs and copying the codes on every call cost four
        times the comparison itself."""
        # 1.4 against 0.27 ms a query for 2,356 codes of 256 bits on a CPU
        signs = np.where(np.asarray(self.codes, bool), 1.0, -1.0).astype(np.float32)
        arrays = (self.transform.mean, self.transform.projection, signs)
        return tuple(jax.device_put(np.asarray(a, np.float32)) for a in arrays)

    def storage(self) -> dict[str, int]:
        """:func:`code_bytes` of this book."""
        return code_bytes(len(self.codes), self.transform.d, self.bits)

    def arrays(self) -> dict[str, np.ndarray]:
        """What a map folder stores: mean, projection and the packed codes."""
        return {
            "codes_mean": self.transform.mean,
            "codes_projection": self.transform.projection,
            "codes_packed": pack_bits(self.codes),
        }

    @classmethod
    def from_arrays(cls, arrays: dict, n: int, d: int, bits: int) -> CodeBook:
        """Inverse of :meth:`arrays`; shapes checked against n, d and bits."""
        mean, proj = arrays["codes_mean"], arrays["codes_projection"]
        packed = arrays["codes_packed"]
        want = ((d,), (bits, d), (n, math.ceil(bits / 8)))
        if (mean.shape, proj.shape, packed.shape) != want:
            raise InputError(
                f"codes of shapes {mean.shape}, {proj.shape}, {packed.shape} do not "
                f"fit n={n}, d={d}, bits={bits}"
            )
        transform = CodeTransform(mean.astype(np.float32), proj.astype(np.float32))
        return cls(transform, unpack_bits(packed, bits))


# pytrees of their arrays (nothing static: kind is a class name)
jax.tree_util.register_dataclass(CodeTransform, ["mean", "projection"], [])
jax.tree_util.register_dataclass(CodeBook, ["transform", "codes"], [])


def check_codes(codes, d: int | None = None) -> int | str:
    """A map's ``codes`` setting (:func:`rhythmic_jax.map.config.codes_setting`), its
    bits in [1, d] when d is given."""
    codes = codes_setting(codes)
    return codes if d is None or codes == INT8 else check_bits(codes, d)


def fit_codebook(x, codes) -> CodeBook | ScalarCodeBook:
    """The codes of places x (n, d) for a ``codes`` setting (:func:`check_codes`)."""
    codes = check_codes(codes, np.shape(x)[1])
    return ScalarCodeBook.fit(x) if codes == INT8 else CodeBook.fit(x, codes)


def codebook_from_arrays(arrays: dict, n: int, d: int, codes):
    """A stored codebook of ``n`` places over d dims (:meth:`CodeBook.arrays`)."""
    codes = check_codes(codes)
    if codes == INT8:
        return ScalarCodeBook.from_arrays(arrays, n, d)
    return CodeBook.from_arrays(arrays, n, d, codes)
