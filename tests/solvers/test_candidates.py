"""Stopping losing candidates early keeps the chosen periods and their templates."""

from __future__ import annotations

import numpy as np
import pytest

from rhythmic_jax.map.periods import candidate_periods, choose_periods, period_offsets
from rhythmic_jax.solvers.candidates import DropLosers, losing_candidates
from rhythmic_jax.solvers.newton import FAST, NewtonConfig, newton_fit
from rhythmic_jax.solvers.objective import default_c, period_errors, scores, targets
from rhythmic_jax.solvers.precision import resolve_hessian_dtype


def test_losing_candidates_compare_whole_sets():
    cands = (20, 21, 22, 23)
    errors = (0.05, 0.0, 0.05, 0.0)  # {21, 23} is best; 20, 22 are 0.05 behind
    assert losing_candidates(cands, errors, 400, 2, slack=0.0) == (20, 22)
    assert losing_candidates(cands, errors, 400, 2, slack=0.01) == (20, 22)
    # 4 errors compared, each may move by 0.0125: 0.05 is within reach
    assert losing_candidates(cands, errors, 400, 2, slack=0.0125) == ()
    # {20, 22} share a factor: 20 and 22 tie with the best only as a pair
    assert losing_candidates(cands, (0.0, 0.05, 0.0, 0.05), 400, 2, 0.0) == ()
    # 20 reaches no n = 480 with any partner (20 x 23 = 460): it cannot win
    assert losing_candidates(cands, (0.0,) * 4, 480, 2, slack=1.0) == (20,)


def _two_rhythms(n=400, d=48, seed=0):
    """Frames whose looks repeat with periods 21 and 23: those two candidates
    fit well, the others do not."""
    rng = np.random.default_rng(seed)
    a = rng.standard_normal((21, d))
    b = rng.standard_normal((23, d))
    i = np.arange(n)
    x = a[i % 21] + b[i % 23] + 0.7 * rng.standard_normal((n, d))
    return (x / np.linalg.norm(x, axis=1, keepdims=True)).astype(np.float32)


@pytest.mark.slow  # compiles every width of two solves
@pytest.mark.parametrize("config", [FAST, NewtonConfig()], ids=["fast", "tight"])
def test_dropping_losers_keeps_the_choice_and_its_templates(config):
    x = _two_rhythms()
    n = len(x)
    cands = candidate_periods(n, 2, 1, 7)
    assert 21 in cands and 23 in cands
    labels = np.arange(n)
    y, c = targets(labels, cands), default_c(n)
    full, full_info = newton_fit(x, y, c, config)
    stop = DropLosers(labels, cands, n, 2, slack=0.01, after=2)
    part, info = newton_fit(x, y, c, config, stop=stop)
    assert stop.dropped, "some candidate is stopped"
    dropped = {t for _, ts in stop.dropped for t in ts}
    assert 21 not in dropped and 23 not in dropped
    assert sum(info.columns) < sum(full_info.columns)  # less work
    errs = lambda p: np.asarray(period_errors(scores(p, x), labels, cands))  # noqa: E731
    chosen = choose_periods(cands, errs(full), n, 2)
    assert chosen == choose_periods(cands, errs(part), n, 2) == (21, 23)
    offs = dict(zip(cands, period_offsets(cands), strict=True))
    cols = np.concatenate([np.arange(offs[t], offs[t] + t) for t in chosen])
    # the kept templates are the full solve's, up to the rounding of the products
    # in other widths: float32's, or bfloat16's where CG's products take it
    # (FAST on a CPU with bfloat16 dot instructions), where a float32 sum that
    # differs in its last bit can round a vector's element the other way
    rounded = resolve_hessian_dtype(config.hessian_dtype) is not None
    np.testing.assert_allclose(
        info.objective[cols], full_info.objective[cols],
        rtol=1e-4 if rounded else 1e-6,
    )  # fmt: skip
    np.testing.assert_allclose(
        np.asarray(part.w)[:, cols], np.asarray(full.w)[:, cols],
        atol=1e-2 if rounded else 1e-4,  # a 1e-3 gap leaves flat directions loose
    )  # fmt: skip
    # the stopped ones are not at their optimum: stopping saved work
    lost = np.concatenate([np.arange(offs[t], offs[t] + t) for t in dropped])
    assert np.all(info.objective[lost] >= full_info.objective[lost] * (1 - 1e-9))


def test_no_stop_before_after_and_nothing_lost_with_a_wide_slack():
    x = _two_rhythms(seed=1)
    n = len(x)
    cands = candidate_periods(n, 2, 1, 7)
    stop = DropLosers(np.arange(n), cands, n, 2, slack=1.0, after=0)
    assert not stop(0, np.zeros((n, sum(cands)))).any()
    late = DropLosers(np.arange(n), cands, n, 2, slack=0.0, after=5)
    assert not late(4, np.zeros((n, sum(cands)))).any()
