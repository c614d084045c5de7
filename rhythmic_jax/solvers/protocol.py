"""One solver protocol: ``solver.run(init_params, *args) -> Solution``.

Every way of fitting the templates has jaxopt's shape (``Solver.run(init_params,
*args)``): a frozen dataclass holds the settings, ``run`` takes the starting
templates (``None``: the solver's own start) and the data, and returns the
templates with what the solve did.

- :class:`Newton`: full batch, exact (optax Newton-CG,
  :mod:`rhythmic_jax.solvers.newton`); ``run(init, x, y, c)``.
- :class:`LBFGS`: full batch, optax L-BFGS from the ridge start
  (:mod:`rhythmic_jax.solvers.optax_loops`); ``run(init, x, y, c)``.
- :class:`Minibatch`: optax Adam over minibatches, resumable
  (:mod:`rhythmic_jax.solvers.resumable`); ``run(init, batches_for_epoch, c, n)``.
- :class:`Streamed`: Newton-CG over frames read from disk in blocks
  (:mod:`rhythmic_jax.solvers.streamed`); ``run(init, frames, labels, periods, c)``.

Shapes: x (n, d) frames, y (n, p) ±1 targets, templates w (d, p), b (p,).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple, Protocol

import numpy as np

from rhythmic_jax.solvers.newton import NewtonConfig, newton_fit
from rhythmic_jax.solvers.objective import Templates

__all__ = [
    "LBFGS",
    "Minibatch",
    "Newton",
    "Solution",
    "Solver",
    "Streamed",
    "solver_for",
]


class Solution(NamedTuple):
    """The fitted templates and the solver's record of the solve (its own type:
    :class:`~rhythmic_jax.solvers.newton.NewtonInfo`, an objective history, ...)."""

    params: Templates
    info: Any


class Solver(Protocol):
    """Anything with ``run(init_params, *args) -> Solution``."""

    def run(self, init_params: Templates | None, *args: Any) -> Solution: ...


@dataclass(frozen=True)
class Newton:
    """Exact full-batch solve: optax Newton-CG on the one objective.

    ``run(init, x, y, c, *, bias=None)``: x (n, d), y (n, p), c the penalty;
    ``init`` warm-starts it (``None``: zero, whose first step is the ridge
    solution); ``bias`` as :func:`~rhythmic_jax.solvers.newton.newton_fit`.
    """

    config: NewtonConfig = NewtonConfig()
    progress: bool = False

    def run(self, init_params, x, y, c, *, bias=None) -> Solution:
        params, info = newton_fit(
            x, y, c, self.config, self.progress, bias=bias, init=init_params
        )
        return Solution(params, info)


@dataclass(frozen=True)
class LBFGS:
    """Full-batch optax L-BFGS; ``run(init, x, y, c)``, ``init=None``: the ridge
    start. Its record is the objective after every step."""

    steps: int = 300
    tol: float = 1e-7
    progress: bool = False

    def run(self, init_params, x, y, c) -> Solution:
        from rhythmic_jax.solvers.optax_loops import fit_full_batch

        params, history = fit_full_batch(
            x, y, c, steps=self.steps, tol=self.tol, init=init_params,
            progress=self.progress,
        )  # fmt: skip
        return Solution(params, history)


@dataclass(frozen=True)
class Minibatch:
    """optax Adam over minibatches, checkpointed and resumable.

    ``run(init, batches_for_epoch, c, n)``: ``batches_for_epoch(epoch)`` yields
    ``(x (m, d), y (m, p))``; n frames per epoch; ``init`` is required (e.g.
    :func:`~rhythmic_jax.solvers.optax_loops.ridge_start` of a subset). The
    record holds the seconds spent in optimiser steps.
    """

    config: Any = None  # rhythmic_jax.solvers.resumable.RunConfig; None: defaults
    ckpt_dir: str | os.PathLike | None = None
    progress: bool = False

    def run(
        self,
        init_params: Templates,
        batches_for_epoch: Callable[[int], Iterable[tuple[Any, Any]]],
        c: float,
        n: int,
    ) -> Solution:
        from rhythmic_jax.solvers.resumable import RunConfig, train_run

        if init_params is None:
            raise ValueError("Minibatch.run needs starting templates")
        timings: dict[str, float] = {}
        params = train_run(
            batches_for_epoch, init_params, c, n, self.config or RunConfig(),
            self.ckpt_dir, self.progress, timings,
        )  # fmt: skip
        return Solution(params, timings)


@dataclass(frozen=True)
class Streamed:
    """Newton-CG with frames read from disk in blocks (memory bounded by a block).

    ``run(init, frames, labels, periods, c)`` with ``init=None`` (it starts from
    zero); ``config`` a :class:`~rhythmic_jax.solvers.streamed.StreamConfig`.
    """

    config: Any = None
    rows: tuple[int, int] | None = None
    reduce: Callable = field(default=lambda tree: tree)
    progress: bool = False

    def run(self, init_params, frames, labels, periods: Sequence[int], c) -> Solution:
        from rhythmic_jax.solvers.streamed import StreamConfig, streamed_newton_fit

        if init_params is not None:
            raise ValueError("Streamed.run starts from zero: pass init_params=None")
        params, info = streamed_newton_fit(
            frames, np.asarray(labels), periods, c, self.config or StreamConfig(),
            rows=self.rows, reduce=self.reduce, progress=self.progress,
        )  # fmt: skip
        return Solution(params, info)


def solver_for(name: str, gap_tol: float = NewtonConfig().gap_tol, progress=False):
    """The full-batch solver a map's settings name: "newton" or "lbfgs"."""
    if name == "newton":
        return Newton(NewtonConfig(gap_tol=gap_tol), progress)
    if name == "lbfgs":
        return LBFGS(progress=progress)
    raise ValueError(f"unknown solver {name!r}: 'newton' or 'lbfgs'")
