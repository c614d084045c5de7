"""The span-of-frames substitution keeps margins and norms exactly."""

from __future__ import annotations

import numpy as np
import pytest

from rhythmic_jax.solvers.span import lift, row_factor


@pytest.mark.parametrize("repeat", [False, True])
def test_substitution_keeps_margins_and_norms(repeat):
    rng = np.random.default_rng(0)
    x = rng.normal(size=(40, 300)).astype(np.float32)
    if repeat:  # a stopped train: identical frames make X X^T singular
        x[10:15] = x[9]
    factor = row_factor(x)
    np.testing.assert_allclose(
        factor @ factor.T,
        x.astype(np.float64) @ x.T.astype(np.float64),
        rtol=0,
        atol=1e-6 * 300,
    )
    assert np.allclose(factor, np.tril(factor))
    beta = rng.normal(size=(40, 7))
    w = lift(x, factor, beta)
    assert w.shape == (300, 7)
    tol = 1e-3 if repeat else 1e-6  # repeats: the jitter's sqrt(eps) private part
    np.testing.assert_allclose(
        x.astype(np.float64) @ w, factor @ beta, rtol=tol, atol=tol
    )
    if not repeat:
        np.testing.assert_allclose(np.sum(w * w, 0), np.sum(beta * beta, 0), rtol=1e-8)


def test_nan_frames_are_refused():
    x = np.ones((3, 5))
    x[1, 2] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        row_factor(x)


def test_one_rule_chooses_the_span_for_every_solver():
    from rhythmic_jax.solvers.memory import fit_bytes
    from rhythmic_jax.solvers.span import in_span

    assert in_span(10, 21) and not in_span(10, 20) and not in_span(100, 50)
    assert "span" in fit_bytes(10, 21, 5) and "span" not in fit_bytes(10, 20, 5)
