"""When a job compiles its descriptor network: :class:`CompilePolicy` and the
frame counts from which compiling pays.

The policy is what a command gives (``--compile``, ``--compile-min-frames``: its
fields' metadata declare the two options, :mod:`rhythmic_jax.app.options`);
:mod:`rhythmic_jax.frames.compiled` decides with it (its ``plan``) and runs the
network. This module imports nothing heavy (no torch, no numpy, none of the
compiled runner's files and processes): the command line states these numbers
in ``--help``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from rhythmic_jax.errors import InputError
from rhythmic_jax.validate import int_option

__all__ = [
    "AUTO",
    "BUILD_MIN_FRAMES",
    "BUILD_SECONDS",
    "COMPILE_MODES",
    "LOAD_MIN_FRAMES",
    "LOAD_SECONDS",
    "CompilePolicy",
]

COMPILE_MODES = ("auto", "always", "never")
# Measured on the 2-core reference machine (scripts/bench_frames.py end-to-end):
# loading a ready package and its first call cost about LOAD_SECONDS, building one about
# BUILD_SECONDS; EfficientNet-Lite0 (224x112) saves about 6 ms a frame compiled.
LOAD_SECONDS = 0.2
BUILD_SECONDS = 60.0
LOAD_MIN_FRAMES = 64
BUILD_MIN_FRAMES = 10_000


@dataclass(frozen=True)
class CompilePolicy:
    """When a job compiles its descriptor network.

    Attributes:
      mode: ``"auto"`` (compile when the job is large enough, below),
        ``"always"`` or ``"never"`` (the eager reference).
      min_frames: in ``auto``, compile from this many frames on; None: from
        :data:`LOAD_MIN_FRAMES` when the package is ready on disk, from
        :data:`BUILD_MIN_FRAMES` when it must be built first.
    """

    mode: str = field(default="auto", metadata={
        "help": "when a network descriptor (efficientnet_lite0, vgg16_fc7) runs "
        "compiled for this CPU (see the main --help)",
        "choices": COMPILE_MODES, "dest": "compile"})  # fmt: skip
    min_frames: int | None = field(default=None, metadata={
        "help": "with --compile auto, compile from N frames on (built or not)",
        "show_default": f"{LOAD_MIN_FRAMES}", "metavar": "N", "domain": int_option(0),
        "dest": "compile_min_frames"})  # fmt: skip

    def __post_init__(self):
        if self.mode not in COMPILE_MODES:
            raise InputError(
                f"{{opt:compile}} {self.mode!r}: use one of {COMPILE_MODES}"
            )
        if self.min_frames is not None and (
            not isinstance(self.min_frames, int) or self.min_frames < 0
        ):
            raise InputError(
                "{opt:compile_min_frames} must be a count >= 0, "
                f"got {self.min_frames!r}"
            )


AUTO = CompilePolicy()
