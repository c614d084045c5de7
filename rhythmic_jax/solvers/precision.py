"""Which reduced precisions this machine multiplies natively.

The Newton solver can run its conjugate-gradient products with bfloat16 inputs
(:func:`rhythmic_jax.solvers.newton_cg.derivatives`). That halves their time
only where XLA's CPU kernels use the processor's bfloat16 dot instructions
(x86's AVX512-BF16 or AMX); elsewhere the same product is emulated and slower
than float32, so ``"auto"`` picks bfloat16 only where the CPU says it has them.
"""

from __future__ import annotations

import functools
import platform

from rhythmic_jax.errors import InputError

__all__ = [
    "HESSIAN_DTYPES",
    "check_hessian_dtype",
    "native_bfloat16",
    "resolve_hessian_dtype",
]

HESSIAN_DTYPES = ("float32", "bfloat16", "auto")
_BF16_FLAGS = frozenset({"avx512_bf16", "amx_bf16"})


def _cpu_flags(text: str) -> frozenset[str]:
    """The x86 feature flags of a /proc/cpuinfo text (its first ``flags`` line)."""
    for line in text.splitlines():
        key, _, value = line.partition(":")
        if key.strip() == "flags":
            return frozenset(value.split())
    return frozenset()


@functools.lru_cache(maxsize=1)
def native_bfloat16() -> bool:
    """True where JAX runs on an x86 CPU with bfloat16 dot instructions
    (``avx512_bf16`` or ``amx_bf16`` in /proc/cpuinfo)."""
    import jax

    if jax.default_backend() != "cpu" or platform.machine() not in ("x86_64", "AMD64"):
        return False
    try:
        with open("/proc/cpuinfo") as fh:
            flags = _cpu_flags(fh.read())
    except OSError:
        return False
    return bool(flags & _BF16_FLAGS)


def check_hessian_dtype(name: str) -> None:
    """Refuse a setting that is not one of :data:`HESSIAN_DTYPES` (InputError);
    it asks nothing of the machine, so it is safe on import."""
    if name not in HESSIAN_DTYPES:
        raise InputError(f"hessian_dtype {name!r}: use one of {HESSIAN_DTYPES}")


def resolve_hessian_dtype(name: str) -> str | None:
    """The dtype of CG's products for a setting: ``"float32"`` -> None (the
    design's), ``"bfloat16"``, or ``"auto"`` -> bfloat16 where
    :func:`native_bfloat16`, else None."""
    check_hessian_dtype(name)
    if name == "auto":
        return "bfloat16" if native_bfloat16() else None
    return None if name == "float32" else name
