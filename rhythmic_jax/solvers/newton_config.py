"""What a Newton solve is asked and what it answers: :class:`NewtonConfig` (and
``FAST``, the setting for a 0.1 % gap), :class:`NewtonInfo`, and the one line
(:func:`step_cap_line`, :class:`FitWarning`) that says a solve stopped short.

The solve itself is :func:`rhythmic_jax.solvers.newton.newton_fit`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rhythmic_jax.solvers.precision import check_hessian_dtype

__all__ = ["FAST", "FitWarning", "NewtonConfig", "NewtonInfo", "step_cap_line"]


@dataclass(frozen=True)
class NewtonConfig:
    """Settings of :func:`rhythmic_jax.solvers.newton.newton_fit`.

    The default solves to the optimum (estimated relative gap <= 1e-7, CG to a
    tenth of the gradient): objectives within 1e-5 of liblinear at a tight
    tolerance and the same training errors (``tests/solvers/test_newton.py``).
    ``FAST`` (estimated gap <= 1e-3 before a template's last step, 3 CG
    iterations in the first step after the ridge start, one more each step up
    to 8) is for a 0.1 % gap: ``scripts/bench_solver.py joint`` times it against
    LinearSVC and measures its true gap (``reports/solver.md``).

    Attributes:
      gap_tol: a template stops once its estimated gap (the Newton decrement) is
        at most ``gap_tol`` times its objective; it takes that last step.
      eta: CG forcing term: CG stops for a template when its residual is below
        ``eta`` times its gradient (both scaled by 1 / (2C)).
      max_iter: most Newton steps.
      max_cg: most CG iterations per Newton step.
      cg_start: if set, the first step after the ridge step allows this many CG
        iterations and each later step one more, up to ``max_cg``: early steps,
        while the active set still moves, gain little from accurate solves.
      rank: leading eigenvectors of ``Xa^T Xa`` in the preconditioner.
      power_iters: subspace iterations that find them.
      block: of those, the first ``block`` preconditioned exactly per template.
      compact: run later steps on the templates not yet stopped only.
      span: when frames are much wider than they are many (d > 2n), solve in
        their n-dimensional span (:mod:`rhythmic_jax.solvers.span`): the same
        optimum with products of n instead of d per frame. Below 2n the
        reduction's (n, d) x (d, n) product costs more than the smaller
        products save (measured: ``reports/span.md``).
      seed: PRNG seed of the subspace iteration's random start (the optimum
        does not depend on it, only the preconditioner's quality).
      exact_gradient: sum each step's gradient over frames in float64 (the
        optimum then does not move with the order of the sum, e.g. frames split
        over processes); False sums in float32, a cheaper product (no float64
        accumulation) exact to ~1e-6 relative: enough for ``FAST``'s 1e-3
        gap.
      hessian_dtype: the inputs of CG's products: ``"float32"``, ``"bfloat16"``
        (rounded to 8 bits of mantissa, summed in float32: half the time where
        the CPU multiplies bfloat16 natively, emulated and slower elsewhere) or
        ``"auto"`` (bfloat16 where native,
        :func:`rhythmic_jax.solvers.precision.native_bfloat16`). Only the
        Newton directions see it; gradients, margins and the line search keep
        their dtypes. ``FAST`` takes ``"auto"``: its 1e-3 gap does not see
        CG's ~1e-3 error in the directions, which the exact line search
        absorbs (its steps, true gap and time: ``reports/solver.md``).
    """

    gap_tol: float = 1e-7
    eta: float = 0.1
    max_iter: int = 50
    max_cg: int = 200
    cg_start: int | None = None
    rank: int = 512
    power_iters: int = 3
    block: int = 32
    compact: bool = True
    span: bool = True
    seed: int = 0
    exact_gradient: bool = True
    hessian_dtype: str = "float32"

    def __post_init__(self):
        check_hessian_dtype(self.hessian_dtype)


FAST = NewtonConfig(
    gap_tol=1e-3, max_cg=8, cg_start=3, exact_gradient=False, hessian_dtype="auto"
)


@dataclass(frozen=True)
class NewtonInfo:
    """What a solve did.

    Attributes:
      steps: Newton steps taken.
      cg_iterations: CG iterations of each step.
      columns: templates (gathered columns, padding included) of each step.
      objective: (p,) objective of each template at the end (float64).
      gap_estimate: (p,) each template's last Newton decrement relative to its
        objective: the estimated gap before its last step.
      capped: templates still short of ``gap_tol`` when the solve reached
        ``max_iter`` steps (0: every template stopped on its own).
    """

    steps: int
    cg_iterations: tuple[int, ...]
    columns: tuple[int, ...]
    objective: np.ndarray
    gap_estimate: np.ndarray
    capped: int = 0


class FitWarning(UserWarning):
    """A fit that ended but not as asked (a solve stopped at its step cap, an
    embedding that generalises worse than the raw descriptors): one line.
    ``{opt:NAME}`` in it names a setting as :class:`rhythmic_jax.errors.InputError`
    does (``str``: the parameter's name; :meth:`as_flag`: the command-line flag)."""

    def __init__(self, message: str):
        from rhythmic_jax.errors import InputError

        self.line = InputError(message)
        super().__init__(str(self.line))

    def as_flag(self) -> str:
        return self.line.as_flag()


def step_cap_line(info: NewtonInfo, gap_tol: float, max_iter: int) -> str | None:
    """One line saying that a solve stopped at its step cap (None when it did
    not): how many templates, the largest gap reached, the target, what to do."""
    if not info.capped:
        return None
    gap = np.asarray(info.gap_estimate, np.float64)
    short = gap[gap > gap_tol]
    reached = float(np.max(short, initial=gap_tol))
    head = (
        f"the solver stopped at its cap of {max_iter} Newton steps with "
        f"{info.capped} of {gap.size} templates short of the target gap "
        f"{gap_tol:.0e}"
    )
    if not np.isfinite(reached):
        return (
            f"{head} (a gap estimate not finite: the solve did not settle): the map "
            "may place frames poorly; check the frames' scale (features of order one)"
        )
    return (
        f"{head} (largest estimated relative gap {reached:.1e}): the map is usable "
        f"but its templates are not at the optimum; {{opt:gap}} "
        f"{_round_up(reached):.0e} accepts this solve and stops there sooner "
        "(frames with no structure for the templates to find, random ones say, "
        "may never reach the target)"
    )


def _round_up(gap: float) -> float:
    """The smallest 1, 2 or 5 times a power of ten at or above ``gap``."""
    if not np.isfinite(gap) or gap <= 0:
        return 1e-3
    exp = np.floor(np.log10(gap))
    for m in (1.0, 2.0, 5.0, 10.0):
        if m * 10**exp >= gap:
            return float(min(m * 10**exp, 0.5))
    return 0.5
