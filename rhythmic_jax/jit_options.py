"""Compile options of the library's jitted programs, chosen by the backend.

Every jitted program of the package is made with :func:`jit` (never ``jax.jit``
directly; a test scans the source), a drop-in for ``jax.jit`` that passes
:func:`compiler_options` for the backend the program compiles for, per program
through ``jax.jit(..., compiler_options=...)``. Nothing global changes: the user's
``XLA_FLAGS`` stay as they are and win over these options for any flag they name.

Why, on a GPU: XLA's GPU compiler autotunes every matrix product by compiling and
timing candidate Triton kernels (the Triton GEMM search and the fusion
autotuner). For this library's float32 products at ``precision="highest"`` that
search was most of every first call, and the warm programs were faster without
it: on an NVIDIA H100 it was most of a first fit's and a first predict's time,
with the same places in every setting (the measurements: ``docs/performance.md``,
section "On a GPU").

So a GPU program compiles with :data:`GPU_OPTIONS`, the quickest setting both cold
and warm. On the CPU (and any other backend) no option is passed: the CPU's
programs, and their keys in the persistent compile cache, stay XLA's own.

Overrides: ``RHYTHMIC_JAX_GPU_AUTOTUNE=1`` (or ``on``, ``true``, ``yes``) keeps
XLA's autotuner; :func:`set_gpu_autotune` does the same from Python for the
programs compiled after it; ``jit(fn, compiler_options={...})`` adds options to
one program. :func:`describe` states the setting (``rhythmic-jax info`` and the
log line at the start of a fit print it).

The module imports JAX only when a program is first called, so the command line
can state the setting (``describe``) without starting JAX.

A program called while another is being traced (inside ``jax.jit``,
``jax.grad``, ``jax.vmap``) is inlined into the outer one, and JAX takes
compiler options only on the outermost program, so there it runs without them.
XLA parses these names for every backend, so a program whose arguments live on
another backend than the default one compiles with them as well, harmlessly.
"""

from __future__ import annotations

import functools
import logging
import os
from collections.abc import Callable
from typing import Any

from rhythmic_jax.errors import InputError

__all__ = [
    "ENV",
    "GPU_OPTIONS",
    "compiler_options",
    "describe",
    "jit",
    "set_gpu_autotune",
]

log = logging.getLogger(__name__)

ENV = "RHYTHMIC_JAX_GPU_AUTOTUNE"
GPU_OPTIONS = {
    "xla_gpu_enable_triton_gemm": False,
    "xla_gpu_experimental_enable_fusion_autotuner": False,
}
GPU_PLATFORMS = ("gpu", "cuda", "rocm")
_ON = ("1", "on", "true", "yes")
_OFF = ("", "0", "off", "false", "no")
_override: bool | None = None  # set_gpu_autotune's setting; None: the environment's
_rejected: set[str] = set()  # platforms whose XLA refused an option name
_OWN = ("_fn", "_extra", "_kw", "_programs")  # _Jitted's own attributes


def set_gpu_autotune(on: bool | None = True) -> None:
    """Keep (``True``) or skip (``False``) XLA's GPU autotuner for the programs
    compiled from now on, whatever ``$RHYTHMIC_JAX_GPU_AUTOTUNE`` says; ``None``
    returns the choice to that variable. Programs compiled before keep theirs."""
    global _override
    if on is not None and not isinstance(on, bool):
        raise InputError(f"gpu_autotune must be True, False or None, not {on!r}")
    _override = on


def gpu_autotune() -> bool:
    """Whether XLA's GPU autotuner is kept: :func:`set_gpu_autotune`'s setting,
    else ``$RHYTHMIC_JAX_GPU_AUTOTUNE`` (off when unset)."""
    if _override is not None:
        return _override
    value = os.environ.get(ENV, "").strip().lower()
    if value not in _ON + _OFF:
        raise InputError(f"{ENV}={value!r}: use 1 (XLA's autotuner) or 0 (skip it)")
    return value in _ON


def _user_flags() -> set[str]:
    """The flag names the user's ``XLA_FLAGS`` sets (``--name=value`` or ``--name``)."""
    words = os.environ.get("XLA_FLAGS", "").split()
    return {w[2:].split("=", 1)[0] for w in words if w.startswith("--")}


def compiler_options(platform: str | None = None) -> dict[str, Any]:
    """The options a program compiles with on ``platform`` (``"cpu"``, ``"gpu"``,
    ``"cuda"``, ``"rocm"``, ``"tpu"``; default: the platform JAX runs on now).

    :data:`GPU_OPTIONS` on a GPU unless the autotuner is kept (see
    :func:`gpu_autotune`), less any flag the user's ``XLA_FLAGS`` names; ``{}``
    on every other platform."""
    platform = _platform() if platform is None else platform.lower()
    if platform not in GPU_PLATFORMS or gpu_autotune() or platform in _rejected:
        return {}
    user = _user_flags()
    return {k: v for k, v in GPU_OPTIONS.items() if k not in user}


def describe(platform: str | None = None) -> str:
    """One line stating the compile options: on ``platform`` when given, else
    for a GPU and for the other backends (without starting JAX's backends)."""
    if platform is not None:
        options = compiler_options(platform)
        shown = ", ".join(f"{k}={v}".lower() for k, v in options.items())
        return f"{platform}: {shown or 'XLA defaults'}"
    gpu = describe("gpu")
    if gpu == "gpu: XLA defaults":
        return f"{gpu} (XLA's autotuner kept); other backends: XLA defaults"
    return f"{gpu}; other backends: XLA defaults ({ENV}=1 keeps XLA's autotuner)"


def _platform() -> str:
    """The platform of JAX's default device (``jax.default_device`` included)."""
    import jax

    device = jax.config.jax_default_device
    if device is None:
        return jax.default_backend()
    return device if isinstance(device, str) else device.platform


def _traced(args: tuple, kwargs: dict) -> bool:
    import jax

    leaves = jax.tree_util.tree_leaves((args, kwargs))
    return any(isinstance(leaf, jax.core.Tracer) for leaf in leaves)


class _Jitted:
    """``jax.jit(fn, **kw)`` made once per set of compiler options, on first use:
    the backend JAX runs on is known only then (importing the package starts no
    backend). Attributes of a jitted function (``lower``, ``trace``,
    ``clear_cache``, ``_cache_size``) are those of the program for the current
    options."""

    def __init__(self, fn: Callable, extra: dict[str, Any], kw: dict[str, Any]):
        functools.update_wrapper(self, fn)
        self._fn, self._extra, self._kw = fn, extra, kw
        self._programs: dict[tuple, Callable] = {}

    def _program(self, options: dict[str, Any]) -> Callable:
        key = tuple(sorted(options.items()))
        program = self._programs.get(key)
        if program is None:
            import jax

            program = jax.jit(self._fn, compiler_options=options or None, **self._kw)
            self._programs[key] = program
        return program

    def _current(self) -> Callable:
        return self._program(compiler_options() | self._extra)

    def __call__(self, *args, **kwargs):
        if _traced(args, kwargs):  # inlined into the program being traced
            return self._program(self._extra)(*args, **kwargs)
        try:
            return self._current()(*args, **kwargs)
        except Exception as error:  # jax.errors.JaxRuntimeError
            if "No such compile option" not in str(error):
                raise
            # An XLA without one of these flag names: warn once, compile without.
            platform = _platform()
            if platform in _rejected or not compiler_options(platform):
                raise
            first = str(error).splitlines()[0]
            log.warning("XLA on %s refused a compile option (%s)", platform, first)
            _rejected.add(platform)
            return self._current()(*args, **kwargs)

    def __getattr__(self, name: str):
        if name.startswith("__") or name in _OWN:
            raise AttributeError(name)
        return getattr(self._current(), name)

    def __get__(self, obj, owner=None):  # a method: bind like a function
        return self if obj is None else functools.partial(self, obj)


def jit(fn: Callable | None = None, /, **kw) -> Any:
    """``jax.jit`` with :func:`compiler_options` for the backend it compiles for.

    Same arguments as ``jax.jit`` (``static_argnames``, ``donate_argnums``, ...);
    ``compiler_options`` given here are added to (and win over) the backend's.
    Use as ``jit(fn, ...)``, ``@jit`` or ``@functools.partial(jit, ...)``."""
    extra = dict(kw.pop("compiler_options", None) or {})
    if fn is None:
        return lambda f: _Jitted(f, extra, kw)
    return _Jitted(fn, extra, kw)
