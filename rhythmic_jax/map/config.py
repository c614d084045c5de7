"""How a map is built: :class:`MapConfig` and the words its settings take.

Everything here is checked when a configuration is made, before any frame is
read: the solver, decode, dtype, codes, fusion weight, gap, penalty, threshold
and layout. The vocabularies (:data:`SOLVERS`, :data:`DECODERS`,
:data:`DTYPES`) are written once, here; the command line offers them and the
modules that act on them import them from here. What a configuration means for
``n`` places of ``d`` features (candidate periods, the penalty, the memory a fit
needs) is :func:`rhythmic_jax.fitting.fit_plan.plan`.

No JAX and no numpy: ``import rhythmic_jax.map.config`` and a default
:class:`MapConfig` are cheap (integer maths), so the command line builds its
parser from them at once; a check imports numpy only for a value that is not
a Python number.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field

from rhythmic_jax.errors import InputError
from rhythmic_jax.map.groups import parse_layout
from rhythmic_jax.map.quantize import DTYPES
from rhythmic_jax.validate import (
    Domain,
    check_number,
    int_option,
    is_int,
    number_option,
)

__all__ = [
    "DECODERS",
    "DTYPES",
    "INT8",
    "SOLVERS",
    "MapConfig",
    "check_weight",
    "codes_setting",
]

SOLVERS = ("newton", "lbfgs")
DECODERS = ("hard", "soft", "topm")
INT8 = "int8"  # the codes setting of a byte per dimension


def codes_setting(codes) -> int | str:
    """A map's ``codes`` setting: a number of ITQ bits >= 1 or ``"int8"`` (8-bit
    scalar codes of every dimension); :func:`rhythmic_jax.map.codes.check_codes`
    also holds the bits to a dimension."""
    if codes == INT8:
        return INT8
    if not is_int(codes) or codes < 1:
        raise InputError(
            f"codes must be a number of ITQ bits >= 1 or {INT8!r} (a byte per "
            f"dimension), got {codes!r}"
        )
    return int(codes)


def check_weight(weight) -> float:
    """The map's share ``w`` of a fused score as a float in [0, 1], else one
    line; a map's stored weight traced with the map as it is."""
    ok = isinstance(weight, int | float) and not isinstance(weight, bool)
    if not ok:
        import numpy as np

        ok = isinstance(weight, np.floating)
        jax = sys.modules.get("jax")
        if not ok and jax is not None and isinstance(weight, jax.core.Tracer):
            return weight  # a map's stored weight traced with it: checked when made
    if not ok or not 0.0 <= float(weight) <= 1.0:
        raise InputError(f"fusion weight must be a number in [0, 1], got {weight!r}")
    return float(weight)


@dataclass(frozen=True)
class MapConfig:
    """How a map is built.

    Attributes:
      r: number of periods kept (paper: 2; 3 and 5 in Fig. 4).
      level: candidates start at ``level * ceil(N ** (1/r))`` (the paper's
        "T = level * sqrt N").
      count: number of candidate periods trained (paper: 7).
      c: SVM penalty; None means ``log N``.
      solver: "newton" (exact, fastest) or "lbfgs" (optax, full batch).
      gap: where the Newton solver stops: the estimated relative objective gap
        of every template (1e-7: the optimum; 5e-4 keeps it within 0.1 % in
        about half the time, with the same periods chosen on Nordland).
      decode: default decode for :meth:`RhythmicMap.predict`: hard | soft | topm.
      top: phases per period kept by the top-m decode (``m`` in maps saved
        before it was named ``top``).
      threshold: confidence below which a query is "no match" (None: never).
      descriptor: name of the descriptor the features came from.
      descriptor_settings: its settings (compared when a map is queried).
      dtype: how templates are stored: float32, float16, or int8 with a
        scale per template (:mod:`rhythmic_jax.map.quantize`); queries are scored
        with the stored values.
      codes: also store a code per place (a hybrid map,
        :mod:`rhythmic_jax.decoding.fusion`): a number of ITQ bits
        (:mod:`rhythmic_jax.map.codes`), or "int8" for a byte per dimension
        (:mod:`rhythmic_jax.map.scalar_codes`); None for the map alone.
      fusion: the map's share ``w`` of the fused score (codes: ``1 - w``).
      layout: how frames are labelled (:mod:`rhythmic_jax.map.groups`): "periods"
        (the paper: co-prime periods chosen by training error), "periods:T1,T2",
        "mixed" or "mixed:B1,..,Br" (mixed-radix digits, most significant first:
        the first digit classifies contiguous segments), "hierarchical",
        "hierarchical:SEG" or "hierarchical:SEG:T1,T2" (a segment classifier and
        co-prime fine periods). Sizes left out are chosen for the storage of a
        periods map of the same ``r`` and ``level``.

    ``decode``, ``threshold`` and ``fusion`` are the defaults of a decode,
    which takes each as an argument; a fitted map carries them as leaves, not
    in its compiled key (:data:`rhythmic_jax.map.pytree.DECODE_SETTINGS`).

    The metadata of the fields ``fit`` offers declare its options
    (:mod:`rhythmic_jax.app.options`). ``rhythmic-jax fit ref.npy --out
    route.map`` uses the defaults; on Nordland summer (3576 frames,
    patch-normalised 64x32) they give periods near 60 and a self-query accuracy
    of about 0.93.
    """

    r: int = field(default=2, metadata={
        "help": "number of periods", "domain": int_option(2)})  # fmt: skip
    level: int = field(default=1, metadata={
        "help": "period level c (c*N^(1/r))", "domain": int_option(1)})  # fmt: skip
    count: int = field(default=7, metadata={
        "help": "candidate periods (each is fitted once to choose among them)",
        "domain": int_option(2, 64)})  # fmt: skip
    c: float | None = field(default=None, metadata={
        "help": "SVM penalty", "show_default": "log N",
        "domain": number_option(0)})  # fmt: skip
    solver: str = field(default="newton", metadata={
        "help": "how the SVMs are solved (newton: Newton-CG to --gap)",
        "choices": SOLVERS})  # fmt: skip
    gap: float = field(default=1e-7, metadata={
        "help": "stop the solver at this estimated relative objective gap; 1e-3 "
        "stops within about 0.1 %%, sooner", "show_default": "the optimum",
        "domain": number_option(0, 1)})  # fmt: skip
    decode: str = "hard"
    top: int = 3
    threshold: float | None = None
    descriptor: str = "features"
    descriptor_settings: dict = field(default_factory=dict, hash=False)
    dtype: str = field(default="float32", metadata={
        "help": "how the map stores its templates (int8: a scale per template)",
        "choices": DTYPES})  # fmt: skip
    codes: int | str | None = field(default=None, metadata={
        "help": "also store a code per place: BITS-bit ITQ (1 <= BITS <= d), or int8 "
        "(a byte per dimension: d bytes a place, best on an --embedding); queries "
        "fuse the map's place scores with the code similarities",
        "metavar": "BITS|int8", "domain": Domain(True, 1, words=(INT8,))})  # fmt: skip
    fusion: float = 0.5

    layout: str = field(default="periods", metadata={
        "help": "how frames are labelled: periods (chosen by training error), "
        "periods:T1,T2, mixed or mixed:B1,..,Br (mixed-radix digits, most "
        "significant first: it classifies contiguous segments), hierarchical, "
        "hierarchical:SEG or hierarchical:SEG:T1,T2 (segments of SEG frames plus "
        "co-prime fine periods); sizes left out match the storage of --r/--level"
    })  # fmt: skip

    def __post_init__(self):
        parse_layout(self.layout)
        if self.dtype not in DTYPES:
            raise InputError(f"dtype must be one of {DTYPES}, got {self.dtype!r}")
        if self.codes is not None:
            codes_setting(self.codes)
        check_weight(self.fusion)
        if self.solver not in SOLVERS:
            raise InputError(f"solver must be one of {SOLVERS}, got {self.solver!r}")
        if self.decode not in DECODERS:
            raise InputError(f"decode must be one of {DECODERS}, got {self.decode!r}")
        if not (isinstance(self.gap, int | float) and 0 < self.gap < 1):
            raise InputError(f"gap must be in (0, 1), got {self.gap!r}")
        if self.c is not None and not self.c > 0:
            raise InputError(f"c must be positive, got {self.c}")
        if self.threshold is not None:
            check_number(self.threshold, "threshold")
