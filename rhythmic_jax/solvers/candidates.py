"""Stop the templates of candidate periods that can no longer be chosen.

A map trains every template of every candidate period in one solve, then keeps
the ``r`` pairwise co-prime periods of least summed training error
(:func:`rhythmic_jax.map.periods.choose_periods`). Each template's solve is its own
(the objective is a sum over templates), so stopping a candidate's templates
early changes nothing for the others: if the stopped candidate would have lost
anyway, the chosen periods and their templates are those of the full solve.

:class:`DropLosers` is the :func:`rhythmic_jax.solvers.newton.newton_fit`
``stop`` hook that does so. From step ``after`` on it reads every candidate's
training error off the solve's margins (``Xa theta``, the frames' scores) and
stops a candidate when every admissible set of ``r`` periods holding it is
worse than the best set by more than the errors may still move: ``slack`` (a
fraction of the frames) per period, for each set.

How far errors move after a few Newton steps is data's business: on Nordland
(3576 frames, 7 candidates 60-66, ``FAST``) one moves by up to 19 frames
(0.5 %) between the fifth step and the end, 14 from the sixth, while every
other pair of periods ends 5-25 frames behind the chosen pair, so no candidate
can be stopped safely before the last steps (``reports/solver_work.md``).

Names: n frames, p templates (the candidates' periods summed), k candidates.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from rhythmic_jax.map.periods import pairwise_coprime, period_offsets
from rhythmic_jax.solvers.objective import period_errors

__all__ = ["DropLosers", "losing_candidates"]


def losing_candidates(
    candidates: Sequence[int], errors: Sequence[float], n: int, r: int, slack: float
) -> tuple[int, ...]:
    """Candidates in no admissible set (``r`` pairwise co-prime periods with
    product >= n) whose summed error is within ``2 r slack`` of the best set's:
    each of the ``2 r`` errors compared may still move by ``slack``."""
    err = {int(t): float(e) for t, e in zip(candidates, errors, strict=True)}
    best_with = dict.fromkeys(err, math.inf)
    for combo in itertools.combinations(sorted(err), r):
        if math.prod(combo) < n or not pairwise_coprime(combo):
            continue
        total = sum(err[t] for t in combo)
        for t in combo:
            best_with[t] = min(best_with[t], total)
    best = min(best_with.values())
    return tuple(t for t in err if best_with[t] > best + 2 * r * slack)


@dataclass(frozen=True, eq=False)
class DropLosers:
    """``stop(step, margins) -> (p,) bool`` for :func:`newton_fit`: the columns
    of the candidates :func:`losing_candidates` names, from step ``after`` on.

    Attributes:
      labels: (n,) place of every frame.
      candidates: the candidate periods, in the columns' order.
      places: the number of places (the product the periods must reach).
      r: periods chosen.
      slack: how far a candidate's training error (a fraction of the frames)
        may still move after step ``after``.
      after: first step (0: the ridge step) at which candidates may stop.
      dropped: filled in as the solve runs: (step, candidates stopped).
    """

    labels: np.ndarray
    candidates: tuple[int, ...]
    places: int
    r: int
    slack: float = 0.01
    after: int = 4
    dropped: list = None  # type: ignore[assignment]

    def __post_init__(self):
        object.__setattr__(self, "dropped", [])

    def errors(self, margins) -> np.ndarray:
        """(k,) training error of every candidate from margins (n, p)."""
        return np.asarray(period_errors(margins, self.labels, self.candidates))

    def __call__(self, step: int, margins) -> np.ndarray:
        stop = np.zeros(sum(self.candidates), bool)
        if step < self.after:
            return stop
        lose = losing_candidates(
            self.candidates, self.errors(margins), self.places, self.r, self.slack
        )
        new = [t for t in lose if all(t not in d for _, d in self.dropped)]
        if new:
            self.dropped.append((step, tuple(new)))
        offs = period_offsets(self.candidates)
        for t, o in zip(self.candidates, offs, strict=True):
            if t in lose:
                stop[o : o + t] = True
        return stop
