"""Which CG product dtype a setting takes on this machine."""

from __future__ import annotations

import pytest

from rhythmic_jax.errors import InputError
from rhythmic_jax.solvers import precision
from rhythmic_jax.solvers.newton import FAST, NewtonConfig


def test_cpu_flags_read_from_a_cpuinfo_text():
    text = "processor\t: 0\nflags\t\t: fpu sse2 avx2 avx512_bf16\nbugs\t: x\n"
    assert precision._cpu_flags(text) == {"fpu", "sse2", "avx2", "avx512_bf16"}
    assert precision._cpu_flags("processor\t: 0\n") == frozenset()


def test_native_bfloat16_follows_this_machine_s_flags():
    import jax

    try:
        with open("/proc/cpuinfo") as fh:
            flags = precision._cpu_flags(fh.read())
    except OSError:
        pytest.skip("no /proc/cpuinfo on this machine")
    on_the_cpu = jax.default_backend() == "cpu"  # a GPU's products are not the CPU's
    expected = on_the_cpu and bool(flags & {"avx512_bf16", "amx_bf16"})
    assert precision.native_bfloat16() == expected


def test_hessian_dtype_settings_resolve_and_unknown_ones_are_refused():
    assert precision.resolve_hessian_dtype("float32") is None
    assert precision.resolve_hessian_dtype("bfloat16") == "bfloat16"
    auto = precision.resolve_hessian_dtype("auto")
    assert auto == ("bfloat16" if precision.native_bfloat16() else None)
    assert FAST.hessian_dtype == "auto" and NewtonConfig().hessian_dtype == "float32"
    with pytest.raises(InputError, match="hessian_dtype 'float16'"):
        NewtonConfig(hessian_dtype="float16")


def test_importing_the_solver_leaves_the_backend_for_jax_distributed():
    """Settings resolve when a fit runs, never on import: a process of a
    multi-process fit must call ``jax.distributed.initialize`` before XLA's
    backend starts."""
    import subprocess
    import sys

    code = (
        "import rhythmic_jax, rhythmic_jax.solvers.newton\n"
        "import rhythmic_jax.fitting.scale_fit\n"
        "from jax._src import xla_bridge\n"
        "print(xla_bridge.backends_are_initialized())\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    )
    assert out.stdout.split()[-1] == "False", out.stderr[-2000:]
