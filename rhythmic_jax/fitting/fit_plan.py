"""What a fit trains and keeps, decided once from a configuration and a shape.

:func:`plan` reads a :class:`~rhythmic_jax.map.config.MapConfig` for ``n`` places of
``d`` features (the dimension the templates see: an embedding's ``k`` when there
is one) and says, before any work, everything that shape settles:

- what is trained: ``count`` candidate periods from ``level * ceil(n ** (1/r))``
  up, of which ``r`` pairwise co-prime ones are kept by training error (the
  paper, Sec. III-B), or the fixed groups of a ``periods:T1,T2``, ``mixed`` or
  ``hierarchical`` layout (:func:`rhythmic_jax.map.groups.resolve_layout`), all kept;
- the penalty ``C`` (the config's, else ``log n``);
- that the codes fit ``d`` and the layout, and that ``r`` periods can cover ``n``.

The :class:`FitPlan` then bounds the memory the solve needs
(:meth:`FitPlan.check_memory`) and the bytes the map can take on disk
(:attr:`FitPlan.largest_bytes`), and after the solve picks what the map keeps
(:meth:`FitPlan.keep`). The in-memory fit (:meth:`rhythmic_jax.RhythmicMap.fit`),
the fit from files (:func:`rhythmic_jax.fitting.scale_fit.fit_map_files`) and the fit
job
(:func:`rhythmic_jax.app.jobs.fit`) share it.

Names: n places, d features, p templates trained, g groups trained (candidates).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.map.codes import check_bits
from rhythmic_jax.map.config import INT8, MapConfig
from rhythmic_jax.map.groups import Groups, parse_layout, resolve_layout
from rhythmic_jax.map.periods import (
    candidate_periods,
    choose_periods,
    period_offsets,
    storage_bytes,
)
from rhythmic_jax.map.quantize import dequantize, quantize
from rhythmic_jax.solvers.memory import check_memory
from rhythmic_jax.solvers.objective import default_c

__all__ = ["FitPlan", "Kept", "plan"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Kept:
    """The templates a map keeps and what choosing them measured.

    ``stored``: ``w`` (d, p_kept), ``b`` (p_kept,) in the map's dtype (and
    ``scale`` (p_kept,) for int8, :func:`rhythmic_jax.map.quantize.quantize`);
    ``params``: their float32 values ``(w, b)``, which queries use;
    ``candidate_errors`` (g,) per candidate period (empty for fixed groups);
    ``group_errors`` per kept group.
    """

    stored: dict[str, np.ndarray]
    params: tuple[np.ndarray, np.ndarray]
    groups: Groups
    n: int
    c: float
    candidates: tuple[int, ...]
    candidate_errors: tuple[float, ...]
    group_errors: tuple[float, ...]

    @property
    def periods(self) -> tuple[int, ...]:
        """The kept periods (empty for a mixed-radix or hierarchical layout)."""
        return self.groups.sizes if self.groups.kind == "periods" else ()


@dataclass(frozen=True)
class FitPlan:
    """A fit of ``n`` places of ``d`` features, settled before it starts.

    Attributes:
      n: places; d: features the templates see.
      r: periods kept among the candidates.
      candidates: periods trained, ``r`` of them kept by training error; empty
        when the layout fixes its groups.
      groups: the layout's fixed groups (all kept), or None when periods are
        chosen among the candidates.
      c: the SVM penalty.
    """

    n: int
    d: int
    r: int
    candidates: tuple[int, ...]
    groups: Groups | None
    c: float

    @property
    def trained(self) -> tuple[int, ...] | Groups:
        """What the targets are built from
        (:func:`rhythmic_jax.solvers.objective.targets`):
        the candidate periods, or the fixed groups."""
        return self.candidates if self.groups is None else self.groups

    @property
    def periods(self) -> tuple[int, ...]:
        """The trained groups' sizes: the candidates, or the fixed groups'."""
        return self.candidates if self.groups is None else self.groups.sizes

    @property
    def p(self) -> int:
        """Templates trained: ``sum(periods)``."""
        return sum(self.periods)

    @property
    def largest_bytes(self) -> int:
        """float32 bytes of the largest map this fit can keep: the templates of
        the ``r`` largest candidates, or of every fixed group."""
        kept = sorted(self.candidates)[-self.r :] if self.groups is None else ()
        return storage_bytes(kept or self.periods, self.d)

    def describe(self) -> str:
        """What is trained, in words (for the log)."""
        if self.groups is None:
            return f"{self.p} templates ({self.candidates})"
        return self.groups.describe()

    def check_memory(self, frames: int) -> int:
        """Bytes a full-batch solve over ``frames`` rows needs; refuses one that
        does not fit (:func:`rhythmic_jax.solvers.memory.check_memory`)."""
        return check_memory(frames, self.d, self.p)

    def keep(self, params, errors, dtype: str) -> Kept:
        """What the map keeps of trained ``params`` (``w`` (d, p), ``b`` (p,)),
        stored as ``dtype``, from training ``errors`` (g,) per trained group:
        the ``r`` candidates of least summed error that are pairwise co-prime
        with a product >= n (:func:`rhythmic_jax.map.periods.choose_periods`), or
        every fixed group."""
        w, b = np.asarray(params.w), np.asarray(params.b)
        errors = tuple(float(e) for e in errors)
        groups, cands, kept = self.groups, self.candidates, errors
        if groups is None:
            chosen = choose_periods(cands, errors, self.n, self.r)
            log.info("chose periods %s (errors %s)", chosen, np.round(errors, 4))
            offs = dict(zip(cands, period_offsets(cands), strict=True))
            cols = np.concatenate([np.arange(offs[t], offs[t] + t) for t in chosen])
            w, b = w[:, cols], b[cols]
            kept = tuple(errors[cands.index(t)] for t in chosen)
            groups = Groups("periods", tuple(int(t) for t in chosen))
        else:
            log.info("group training errors %s", np.round(errors, 4))
        stored = quantize(w, b, dtype)
        return Kept(
            stored, dequantize(stored), groups, self.n, self.c, cands,
            errors if cands else (), kept,
        )  # fmt: skip


def plan(config: MapConfig, n: int, d: int, frames: int | None = None) -> FitPlan:
    """The fit of ``config`` for ``n`` places of ``d`` features (see the module).

    Refuses (:class:`InputError`), before any work: codes of more bits than
    ``d`` or beside a layout other than periods, a layout whose sizes do not fit
    ``n``, and ``r``, ``level``, ``count`` that give no ``r`` pairwise co-prime
    candidates with a product >= n; with ``frames`` (the rows the fit will
    solve over), also a solve that does not fit in memory
    (:meth:`FitPlan.check_memory`).
    """
    if config.codes not in (None, INT8):  # a setting the config checked
        check_bits(config.codes, d, n=n)  # ITQ is fitted on one frame a place
    spec = parse_layout(config.layout)
    if config.codes is not None and spec.kind != "periods":
        raise InputError(
            f"codes fuse with the place scores of a periods layout, not "
            f"{config.layout!r}"
        )
    groups, cands = None, ()
    if spec.kind != "periods" or spec.sizes:
        groups = resolve_layout(spec, n, config.r, config.level)
    else:
        cands = candidate_periods(n, config.r, config.level, config.count)
        choose_periods(cands, [0.0] * len(cands), n, config.r)  # impossible r: now
    c = config.c if config.c is not None else default_c(n)
    made = FitPlan(int(n), int(d), int(config.r), cands, groups, float(c))
    if frames is not None:
        check_memory(frames, made.d, made.p)
    return made
