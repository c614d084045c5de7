"""The exact solver against scikit-learn's liblinear on the same objective."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.svm import LinearSVC

from rhythmic_jax.newton import NewtonConfig, newton_fit
from rhythmic_jax.objective import (
    default_c,
    period_errors,
    period_offsets,
    scores,
    targets,
)
from rhythmic_jax.periods import candidate_periods


def liblinear_objective(w, b, x, y, c):
    """liblinear's primal: 0.5 (||w||^2 + b^2) + C sum max(0, 1 - y (x w + b))^2.

    With intercept_scaling=1 liblinear appends a constant-1 feature whose weight
    is the intercept and is regularised like the others: the same objective as
    ``rhythmic_jax.objective.classifier_objective`` with C passed unchanged.
    """
    margin = y * (x @ w + b)
    return 0.5 * (w @ w + b * b) + c * np.sum(np.maximum(0.0, 1.0 - margin) ** 2)


def synthetic(n=120, d=40, seed=0):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, d)).astype(np.float32)
    return x / np.linalg.norm(x, axis=1, keepdims=True)


@pytest.mark.parametrize("form", ["gram", "primal"])
@pytest.mark.parametrize("shape", [(80, 200), (150, 30)])
def test_matches_liblinear_on_synthetic(form, shape):
    x = synthetic(*shape)
    periods = (5, 6, 7)
    y = np.asarray(targets(np.arange(len(x)), periods))
    c = default_c(len(x))
    params, info = newton_fit(x, y, c, NewtonConfig(form=form), progress=False)
    assert info.form == form
    for j in range(y.shape[1]):
        svc = LinearSVC(C=c, loss="squared_hinge", tol=1e-10, max_iter=100_000)
        svc.fit(x, y[:, j])
        ref = liblinear_objective(svc.coef_[0], svc.intercept_[0], x, y[:, j], c)
        ours = liblinear_objective(
            np.asarray(params.w[:, j], np.float64), float(params.b[j]), x, y[:, j], c
        )
        assert ours <= ref * (1 + 1e-5), (j, ours, ref)
        assert info.objective[j] == pytest.approx(ref, rel=1e-5)


def test_gram_and_primal_forms_agree():
    x = synthetic(100, 90)
    y = targets(np.arange(100), (9, 10, 11))
    c = 2.0
    pg, ig = newton_fit(x, y, c, NewtonConfig(form="gram"), progress=False)
    pp, ip = newton_fit(x, y, c, NewtonConfig(form="primal"), progress=False)
    np.testing.assert_allclose(ig.objective, ip.objective, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(pg.w), np.asarray(pp.w), atol=2e-3)


def test_auto_form_picks_the_cheaper_side():
    y = targets(np.arange(60), (7, 9))
    _, wide = newton_fit(synthetic(60, 200), y, 1.0, progress=False)
    _, tall = newton_fit(synthetic(60, 10), y, 1.0, progress=False)
    assert (wide.form, tall.form) == ("gram", "primal")


def test_bad_form_is_refused():
    with pytest.raises(ValueError, match="form"):
        newton_fit(
            synthetic(20, 5),
            targets(np.arange(20), (4, 5)),
            1.0,
            NewtonConfig(form="dual"),
            progress=False,
        )


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
