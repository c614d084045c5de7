"""A Newton solve's settings and account: the step-cap line says how far a
capped solve got and what setting accepts it; a bad setting is refused."""

from __future__ import annotations

import numpy as np
import pytest

from rhythmic_jax.errors import InputError
from rhythmic_jax.solvers.newton_config import (
    FAST,
    FitWarning,
    NewtonConfig,
    NewtonInfo,
    step_cap_line,
)


def info(gaps, capped: int) -> NewtonInfo:
    gaps = np.asarray(gaps, np.float64)
    return NewtonInfo(
        steps=2, cg_iterations=(3, 4), columns=(8, 8),
        objective=np.ones_like(gaps), gap_estimate=gaps, capped=capped,
    )  # fmt: skip


def test_no_line_when_every_template_stopped_on_its_own():
    assert step_cap_line(info([1e-9, 2e-8], 0), 1e-7, 50) is None


def test_the_line_names_the_count_the_largest_gap_and_a_setting_above_it():
    line = step_cap_line(info([1e-9, 3.2e-5, 3e-4], 2), 1e-7, 2)
    assert line.startswith(
        "the solver stopped at its cap of 2 Newton steps with 2 of 3 templates "
        "short of the target gap 1e-07 (largest estimated relative gap 3.0e-04)"
    )
    assert "{opt:gap} 5e-04 accepts this solve" in line  # 1, 2 or 5 above 3e-4
    assert str(FitWarning(line)) == line.replace("{opt:gap}", "gap")


@pytest.mark.parametrize(("largest", "setting"), [(1e-3, "1e-03"), (1.5e-2, "2e-02"),
                                                  (0.9, "5e-01")])  # fmt: skip
def test_the_setting_offered_is_the_next_1_2_or_5_at_most_a_half(largest, setting):
    line = step_cap_line(info([largest], 1), 1e-7, 9)
    assert f"{{opt:gap}} {setting} accepts" in line


def test_a_gap_that_is_not_finite_says_the_solve_did_not_settle():
    line = step_cap_line(info([np.inf, 1e-9], 1), 1e-7, 5)
    assert "(a gap estimate not finite: the solve did not settle)" in line
    assert "{opt:gap}" not in line


def test_fast_is_for_a_tenth_of_a_percent_and_bad_dtypes_are_refused():
    assert (FAST.gap_tol, FAST.max_cg, FAST.cg_start) == (1e-3, 8, 3)
    assert FAST.hessian_dtype == "auto" and not FAST.exact_gradient
    assert NewtonConfig().gap_tol == 1e-7
    with pytest.raises(InputError, match="hessian_dtype 'float16': use one of"):
        NewtonConfig(hessian_dtype="float16")
