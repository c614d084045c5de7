"""The exact solver against scikit-learn's liblinear on the same objective."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from sklearn.svm import LinearSVC

from rhythmic_jax.map.periods import candidate_periods, period_offsets
from rhythmic_jax.solvers.newton import (
    FAST,
    NewtonConfig,
    _cg_cap,
    newton_fit,
)
from rhythmic_jax.solvers.objective import (
    default_c,
    period_errors,
    scores,
    targets,
)


def liblinear_objective(w, b, x, y, c):
    """liblinear's primal: 0.5 (||w||^2 + b^2) + C sum max(0, 1 - y (x w + b))^2.

    With intercept_scaling=1 liblinear appends a constant-1 feature whose weight
    is the intercept and is regularised like the others: the same objective as
    ``rhythmic_jax.solvers.objective.classifier_objective`` with C passed unchanged.
    """
    margin = y * (x @ w + b)
    return 0.5 * (w @ w + b * b) + c * np.sum(np.maximum(0.0, 1.0 - margin) ** 2)


def synthetic(n=120, d=40, seed=0):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, d)).astype(np.float32)
    return x / np.linalg.norm(x, axis=1, keepdims=True)


def liblinear_reference(x, y, c, tol=1e-10):
    """(p,) liblinear objectives of every column of y, fitted one by one."""
    out = []
    for j in range(y.shape[1]):
        svc = LinearSVC(C=c, loss="squared_hinge", tol=tol, max_iter=100_000)
        svc.fit(x, y[:, j])
        out.append(liblinear_objective(svc.coef_[0], svc.intercept_[0], x, y[:, j], c))
    return np.array(out)


def ours(params, x, y, c):
    w, b = np.asarray(params.w, np.float64), np.asarray(params.b, np.float64)
    return np.array(
        [liblinear_objective(w[:, j], b[j], x, y[:, j], c) for j in range(y.shape[1])]
    )


@pytest.mark.parametrize("shape", [(80, 200), (150, 30)])
def test_matches_liblinear_on_synthetic(shape):
    """Wide (d > n) and tall data; the tall one has fewer features than the rank."""
    x = synthetic(*shape)
    y = np.asarray(targets(np.arange(len(x)), (5, 6, 7)))
    c = default_c(len(x))
    params, info = newton_fit(x, y, c, progress=False)
    ref = liblinear_reference(x, y, c)
    got = ours(params, x, y, c)
    assert np.all(got <= ref * (1 + 1e-5)), (got - ref) / ref
    np.testing.assert_allclose(info.objective, ref, rtol=1e-5)
    assert np.all(info.gap_estimate <= NewtonConfig().gap_tol)


@pytest.mark.parametrize("hessian", ["float32", "bfloat16"])
def test_fast_setting_stays_within_its_gap(hessian):
    """FAST stops at an estimated 0.1 % gap: the true gap is below it, and above
    the tight solve's; with CG's products in float32 or bfloat16."""
    x = synthetic(300, 120, seed=3)
    y = np.asarray(targets(np.arange(300), (11, 12, 13)))
    c = default_c(300)
    config = dataclasses.replace(FAST, hessian_dtype=hessian)
    fast, info = newton_fit(x, y, c, config, progress=False)
    tight, _ = newton_fit(x, y, c, progress=False)
    ref = liblinear_reference(x, y, c)
    gap_fast = (ours(fast, x, y, c) - ref) / ref
    gap_tight = (ours(tight, x, y, c) - ref) / ref
    assert np.all(gap_fast <= FAST.gap_tol), gap_fast.max()
    assert np.all(info.gap_estimate <= FAST.gap_tol)
    assert gap_fast.max() > gap_tight.max()
    np.testing.assert_allclose(info.objective, ours(fast, x, y, c), rtol=1e-6)


def test_cg_cap_grows_from_cg_start():
    config = NewtonConfig(max_cg=8, cg_start=3)
    assert [_cg_cap(config, k) for k in range(9)] == [3, 3, 4, 5, 6, 7, 8, 8, 8]
    assert _cg_cap(NewtonConfig(max_cg=6), 5) == 6


def test_span_of_wide_frames_gives_the_primal_optimum():
    """d > 2n: the solve over the frames' span lands on the direct solve's optimum,
    repeated frames (a stopped train) included."""
    x = synthetic(90, 400, seed=7)
    x[20:24] = x[19]
    y = np.asarray(targets(np.arange(90), (9, 10, 11)))
    c = default_c(90)
    span, info = newton_fit(x, y, c, progress=False)
    direct, _ = newton_fit(x, y, c, NewtonConfig(span=False), progress=False)
    assert np.asarray(span.w).shape == (400, 30)
    f_span, f_direct = ours(span, x, y, c), ours(direct, x, y, c)
    np.testing.assert_allclose(f_span, f_direct, rtol=1e-6)
    np.testing.assert_allclose(info.objective, f_span, rtol=1e-6)
    np.testing.assert_allclose(
        x @ np.asarray(span.w), x @ np.asarray(direct.w), atol=2e-3
    )


def test_compaction_does_not_change_the_optimum():
    x = synthetic(100, 90)
    y = np.asarray(targets(np.arange(100), (9, 10, 11)))
    c = 2.0
    pc, ic = newton_fit(x, y, c, progress=False)
    pf, if_ = newton_fit(x, y, c, NewtonConfig(compact=False), progress=False)
    np.testing.assert_allclose(ic.objective, if_.objective, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(pc.w), np.asarray(pf.w), atol=2e-3)
    assert set(if_.columns) == {30} and min(ic.columns) < 30


def test_small_rank_and_block_reach_the_same_optimum():
    """The preconditioner changes the path, not the optimum."""
    x = synthetic(120, 60, seed=5)
    y = np.asarray(targets(np.arange(120), (7, 8)))
    _, full = newton_fit(x, y, 1.5, progress=False)
    _, small = newton_fit(
        x, y, 1.5, NewtonConfig(rank=8, block=4, power_iters=1), progress=False
    )
    np.testing.assert_allclose(small.objective, full.objective, rtol=1e-6)


def test_every_candidate_matches_linearsvc_on_nordland(nordland_patchnorm):
    """Real frames: per candidate, objective within 0.1 % and equal training error."""
    summer, _ = nordland_patchnorm
    x = summer[:200]
    n = len(x)
    cands = candidate_periods(n, 2, 1, 7)
    c = default_c(n)
    labels = np.arange(n)
    y = np.asarray(targets(labels, cands))
    params, info = newton_fit(x, y, c, progress=False)
    ours_err = np.asarray(period_errors(scores(params, x), labels, cands))
    for t, off, err in zip(cands, period_offsets(cands), ours_err, strict=True):
        svc = LinearSVC(C=c, loss="squared_hinge", tol=1e-6, max_iter=20_000)
        svc.fit(x, labels % t)
        ref = sum(
            liblinear_objective(svc.coef_[j], svc.intercept_[j], x, y[:, off + j], c)
            for j in range(t)
        )
        ours = float(np.sum(info.objective[off : off + t]))
        assert ours <= ref * 1.001, (t, ours, ref)
        assert abs(ours - ref) <= 1e-3 * ref, (t, ours, ref)
        svc_err = float(np.mean(svc.predict(x) != labels % t))
        assert round(float(err) * n) == round(svc_err * n), t
