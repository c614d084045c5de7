"""RhythmicMap as scikit-learn's own checks see it, and in its tools.

Every check ``check_estimator`` runs (``estimator_checks_generator``, as
``parametrize_with_checks`` makes them) runs on the estimator, each fit
compiling for its shape (about 40 s in all from a cold compile cache on 2
cores, 11 s warm); four checks that are not about the API (idempotence, one
feature, dtypes, the positive-only tag) run under the ``slow`` marker. The
checks feed features near 100 (``check_fit_idempotent``, ``check_n_features_in``,
``check_fit_check_is_fitted``), which ``scale="refuse"`` (the command line's
choice) refuses as unscaled; the estimator checked is the default
``RhythmicMap()``, whose ``scale="auto"`` standardizes them, and the refusal is
tested apart. No check is expected to fail
(``EXPECTED_FAILED`` is empty, and a check listed there that passed would fail
the run).
"""

from __future__ import annotations

import functools
import inspect
import pickle

import numpy as np
import pytest
from sklearn.base import clone
from sklearn.exceptions import NotFittedError
from sklearn.model_selection import GridSearchCV, KFold
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import Normalizer
from sklearn.utils.estimator_checks import estimator_checks_generator

import rhythmic_jax as rj
from rhythmic_jax import InputError, MapConfig, RhythmicMap

EXPECTED_FAILED: dict[str, str] = {}  # check name -> why it cannot apply
SLOW = {
    "check_fit_idempotent",
    "check_fit2d_1feature",
    "check_estimators_dtypes",
    "check_positive_only_tag_during_fit",
}


def _name(check) -> str:
    return (check.func if isinstance(check, functools.partial) else check).__name__


CHECKS = [
    pytest.param(
        estimator,
        check,
        id=_name(check),
        marks=[pytest.mark.slow] if _name(check) in SLOW else [],
    )
    for estimator, check in estimator_checks_generator(
        RhythmicMap(),
        legacy=True,
        expected_failed_checks=EXPECTED_FAILED,
        mark="xfail",
        xfail_strict=True,
    )
]


@pytest.mark.parametrize("estimator, check", CHECKS)
def test_scikit_learn_checks(estimator, check):
    check(estimator)


def test_the_checks_cover_the_api():
    """The core API checks are among those run by default."""
    core = {
        "check_estimator_cloneable", "check_estimator_repr",
        "check_get_params_invariance", "check_set_params",
        "check_no_attributes_set_in_init",
        "check_fit_check_is_fitted", "check_estimators_unfitted",
        "check_n_features_in", "check_n_features_in_after_fitting",
        "check_estimators_pickle", "check_estimators_nan_inf", "check_complex_data",
        "check_estimator_sparse_matrix", "check_estimator_sparse_array", "check_fit1d",
        "check_fit2d_predict1d", "check_dict_unchanged",
        "check_estimators_overwrite_params", "check_dont_overwrite_parameters",
    }  # fmt: skip
    default = {p.id for p in CHECKS if not p.marks}
    assert core <= default, core - default


def route(n=120, d=48, seed=0):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, d)).astype(np.float32)
    return x / np.linalg.norm(x, axis=1, keepdims=True)


def test_parameters_are_kept_as_given_and_clone_repr_work():
    est = RhythmicMap(r=3, level=2, method="soft", layout="nonsense", c=-1)
    assert est.get_params()["layout"] == "nonsense"  # checked by fit, not here
    assert (
        repr(est) == "RhythmicMap(c=-1, layout='nonsense', level=2, method='soft', r=3)"
    )
    twin = clone(est)
    assert twin is not est and twin.get_params() == est.get_params()
    with pytest.raises(InputError, match="layout 'nonsense'"):
        est.fit(route(), progress=False)
    assert est.set_params(layout="periods", c=None) is est
    assert est.config == MapConfig(r=3, level=2, decode="soft")
    twin = RhythmicMap.from_config(est.config, scale="auto")  # the default
    assert twin.get_params() == est.get_params()


def test_positional_arguments_are_refused_in_one_line():
    with pytest.raises(TypeError, match=r"by name.*RhythmicMap\(r=2") as err:
        RhythmicMap(2)
    assert "\n" not in str(err.value)
    with pytest.raises(TypeError, match="from_config"):
        RhythmicMap(MapConfig())
    params = inspect.signature(RhythmicMap).parameters  # what help() shows
    assert all(p.kind is p.KEYWORD_ONLY for p in params.values())
    assert set(params) == set(RhythmicMap().get_params())
    assert list(inspect.signature(RhythmicMap.predict).parameters)[:3] == [
        "self",
        "X",
        "method",
    ]


def test_before_a_fit_every_query_raises_not_fitted():
    est = RhythmicMap()
    for call in (est.predict, est.decode, est.scores, est.score, est.locate):
        with pytest.raises(NotFittedError, match="not fitted"):
            call(route(2, 4))
    with pytest.raises(InputError, match="not fitted"):  # the CLI's one line
        est.periods  # noqa: B018
    assert not hasattr(est, "n_features_in_") and est.map is None


def test_fitted_state_and_the_old_attribute_names():
    x = route()
    est = RhythmicMap().fit(x, progress=False)
    assert est.n_features_in_ == 48 and est.map_ is est.map is est.value
    assert (est.n, est.d, est.periods) == (120, 48, est.map_.periods)
    assert est.config is est.map_.config
    assert est.score(x) == np.mean(est.predict(x) == np.arange(120))
    back = pickle.loads(pickle.dumps(est))
    np.testing.assert_array_equal(back.predict(x), est.predict(x))
    with pytest.raises(ValueError, match="X has 5 features, but RhythmicMap is"):
        est.predict(x[:, :5])


def test_labels_with_gaps_name_their_places():
    """y are place labels: frames of a label share a place, predict answers
    with the label; the pure functions of ``map_`` with the place's row."""
    x = route(60, 48, seed=1)
    twice = np.concatenate([x, x + 0.01 * route(60, 48, seed=2)])
    y = np.tile(np.arange(60) * 10 + 5, 2)
    est = RhythmicMap().fit(twice, y, progress=False)
    assert est.n == 60
    assert est.score(x, y[:60]) > 0.95
    rows = rj.predict(est.map_, x)
    np.testing.assert_array_equal(
        est.predict(x), np.where(rows >= 0, 10 * rows + 5, -1)
    )
    with pytest.raises(InputError, match="place labels must be integers >= 0"):
        est.fit(twice, np.full(120, 0.5), progress=False)


def test_scale_refuses_unscaled_features_or_standardizes_them():
    x = 100 + route(80, 16, seed=3)
    with pytest.raises(InputError, match="features of order one"):
        RhythmicMap(scale="refuse").fit(x, progress=False)
    est = RhythmicMap(scale="standardize").fit(x, progress=False)
    z = (x - x.mean(0)) / x.std(0)
    want = RhythmicMap().fit(z, progress=False)
    np.testing.assert_array_equal(est.predict(x), want.predict(z))
    assert est.score(x) == want.score(z) > 0.5
    with pytest.raises(InputError, match="scale must be one of"):
        RhythmicMap(scale="minmax").fit(x, progress=False)
    auto = RhythmicMap(scale="auto")  # standardizes what refuse refuses, only
    np.testing.assert_array_equal(
        auto.fit(x, progress=False).predict(x), est.predict(x)
    )
    assert "scale_mean" in auto.extra
    z = route(80, 16, seed=3)
    np.testing.assert_array_equal(
        auto.fit(z, progress=False).map_.w,
        RhythmicMap(scale="refuse").fit(z, progress=False).map_.w,
    )
    assert "scale_mean" not in auto.extra


def test_query_rows_check_the_shape_and_standardize_where_the_fit_did():
    """A map's queries, one function: the shape in scikit-learn's words; the
    values checked and standardized where the fit kept a scale; else as given."""
    from rhythmic_jax.estimator_inputs import query_rows, standardize, standardized

    x = 100 + route(40, 8, seed=5)
    q = x[:3].copy()
    assert query_rows(q, 8, {}) is q
    scale = standardize(x)
    want = standardized(q, scale)
    got = query_rows(q, 8, scale)
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, want)
    with pytest.raises(InputError, match="expecting 8 features"):
        query_rows(x[:3, :5], 8, scale)
    with pytest.raises(InputError, match="Reshape your data"):
        query_rows(q[0], 8, {})
    bad = q.copy()
    bad[1, 2] = np.nan
    with pytest.raises(InputError, match="NaN"):
        query_rows(bad, 8, scale)


def test_standardized_map_survives_save_and_load(tmp_path):
    x = 50 + route(80, 16, seed=4)
    est = RhythmicMap(scale="standardize").fit(x, progress=False)
    est.save(tmp_path / "m.map")
    back = RhythmicMap.load(tmp_path / "m.map")
    assert back.scale == "standardize"
    np.testing.assert_array_equal(back.predict(x), est.predict(x))
    assert back.locate(x[7]) == est.locate(x[7]) == est.predict(x[7:8])[0]


@pytest.mark.parametrize(
    "bad, match",
    [
        (route(10, 4) + 1j, "Complex data not supported"),
        (np.zeros((3,)), "Reshape your data"),
        (np.zeros((10, 0)), r"0 feature\(s\)"),
    ],
)
def test_bad_input_is_refused_in_one_line(bad, match):
    with pytest.raises(InputError, match=match) as err:
        RhythmicMap().fit(bad, progress=False)
    assert "\n" not in str(err.value)


def test_sparse_input_is_refused_naming_it():
    from scipy import sparse

    x = route(30, 8)
    est = RhythmicMap().fit(x, progress=False)
    for kind in (sparse.csr_matrix, sparse.csr_array, sparse.coo_matrix):
        with pytest.raises(InputError, match="sparse input is not supported"):
            RhythmicMap().fit(kind(x), progress=False)
        with pytest.raises(InputError, match=r"sparse matrix .*toarray"):
            est.predict(kind(x))


def test_grid_search_picks_among_fits():
    """Two traversals of 80 places, each fold one traversal: GridSearchCV fits
    every setting and scores recall@1 of the held-out traversal."""
    x = route(80, 64, seed=5)
    rng = np.random.default_rng(6)
    two = np.concatenate([x, x + 0.02 * rng.normal(size=x.shape).astype("f4")])
    y = np.tile(np.arange(80), 2)
    grid = GridSearchCV(
        RhythmicMap(), {"level": [1, 2], "r": [2, 3]}, cv=KFold(2), error_score="raise"
    )
    grid.fit(two, y, progress=False)
    scores = grid.cv_results_["mean_test_score"]
    assert len(scores) == 4 and np.all(scores > 0.9)
    assert grid.best_estimator_.n == 80
    assert grid.score(x, np.arange(80)) == grid.best_estimator_.score(x, np.arange(80))


def test_pipeline_with_a_normalizer_fits_and_predicts():
    x = 3.0 * route(100, 32, seed=7) + 0.1
    pipe = make_pipeline(Normalizer(), RhythmicMap()).fit(x)
    want = RhythmicMap().fit(Normalizer().fit_transform(x), progress=False)
    np.testing.assert_array_equal(
        pipe.predict(x), want.predict(Normalizer().transform(x))
    )
    assert pipe.score(x) == pytest.approx(want.score(Normalizer().transform(x)))


@pytest.mark.slow
def test_grid_search_as_written_fits_every_setting():
    """``GridSearchCV(RhythmicMap(), grid).fit(X)`` with its default 5 folds and
    no labels: every setting fits (the held-out frames are no places of the
    map, so the scores say nothing; give y to compare settings)."""
    grid = GridSearchCV(
        RhythmicMap(), {"level": [1, 2], "r": [2, 3]}, error_score="raise"
    ).fit(route(200, 64, seed=8))
    assert len(grid.cv_results_["mean_test_score"]) == 4
    assert grid.best_estimator_.n == 200


def test_the_command_line_imports_no_scikit_learn():
    """The command line's jobs and the evaluations hold ``Map`` values (the
    estimator is imported by none of them), so they load no scikit-learn;
    ``RhythmicMap``, asked for, is a plain ``BaseEstimator`` subclass."""
    import subprocess
    import sys

    code = (
        "import sys, rhythmic_jax, rhythmic_jax.app.jobs, rhythmic_jax.app.demo\n"
        "import rhythmic_jax.app.scale_jobs, rhythmic_jax.app.fusion\n"
        "import rhythmic_jax.eval.frontier, rhythmic_jax.eval.ablation\n"
        "assert 'sklearn' not in sys.modules, 'imported'\n"
        "assert 'rhythmic_jax.rhythmic_map' not in sys.modules, 'estimator'\n"
        "from sklearn.base import BaseEstimator\n"
        "cls = rhythmic_jax.RhythmicMap\n"
        "assert cls.__mro__[1] is BaseEstimator, cls.__mro__\n"
        "assert repr(cls(r=3)) == 'RhythmicMap(r=3)', repr(cls(r=3))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]


def test_the_methods_are_defined_in_the_class_with_their_parameters():
    """What ``help(model.decode)`` shows: every method a function of the class
    body, named for it, with its parameters (none made by a loop)."""
    named = {
        "fit": ["X", "y", "verbose", "progress", "refine", "plan"],
        "predict": ["X", "method", "top", "sequence", "speeds", "threshold"],
        "decode": ["X", "method", "top"],
        "scores": ["X"],
        "place_scores": ["X"],
        "locate": ["q"],
        "score": ["X", "y"],
        "save": ["path"],
        "load": ["path", "descriptor", "descriptor_settings", "d"],
        "with_dtype": ["dtype"],
        "info": [],
        "storage": [],
    }
    model = RhythmicMap()
    for name, params in named.items():
        method = getattr(model, name)
        assert method.__qualname__ == f"RhythmicMap.{name}"
        assert name in vars(RhythmicMap)
        assert list(inspect.signature(method).parameters) == params, name
        assert method.__doc__


def test_fit_checks_the_parameters_as_the_command_line_does():
    """Parameters set after construction are checked at fit, one line naming
    the parameter: the option domains of fit, and top-m's phases."""
    from rhythmic_jax import RhythmicMap
    from rhythmic_jax.errors import InputError

    x = np.random.default_rng(0).normal(size=(40, 8)).astype(np.float32)
    for params, name in (({"method": "topm", "top": 0}, "top"), ({"r": 1}, "r"),
                         ({"count": 1}, "count")):  # fmt: skip
        with pytest.raises(InputError, match=rf"^{name} .*must be") as err:
            RhythmicMap().set_params(**params).fit(x)
        assert "\n" not in str(err.value)


@pytest.mark.parametrize("scale", [1e-30, 1e30])
def test_scale_auto_standardises_frames_of_extreme_length(scale):
    """scale='auto' turns frames multiplied by 1e-30 or 1e30 into a usable map
    (per-feature standardisation by their measured scale); 'refuse' refuses."""
    from rhythmic_jax import RhythmicMap
    from rhythmic_jax.errors import InputError

    x = np.random.default_rng(0).normal(size=(120, 64)).astype(np.float32)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    plain = RhythmicMap().fit(x).predict(x)
    far = x * np.float32(scale)
    got = RhythmicMap(scale="auto").fit(far).predict(far)
    right = np.arange(len(x))
    assert np.mean(got == right) >= np.mean(plain == right) - 0.05
    assert np.mean(got == right) > 0.5
    with pytest.raises(InputError, match="RMS length"):
        RhythmicMap(scale="refuse").fit(far)


# ------------------------------------------------------- score's tolerance


def test_tolerance_is_a_parameter_clone_and_set_params_keep():
    """``tolerance`` round-trips through get_params / clone / set_params and
    a grid over it, and changes no fit."""
    est = RhythmicMap(r=3, tolerance=2)
    assert est.get_params()["tolerance"] == 2
    twin = clone(est)
    assert twin.get_params() == est.get_params() and twin is not est
    assert "tolerance=2" in repr(est) and "tolerance" not in repr(RhythmicMap())
    assert clone(est.set_params(tolerance=1)).tolerance == 1
    assert RhythmicMap.from_config(MapConfig(), tolerance=3).tolerance == 3
    x = route(60, 32, seed=11)
    a = RhythmicMap(tolerance=0).fit(x, progress=False)
    b = RhythmicMap(tolerance=5).fit(x, progress=False)
    np.testing.assert_array_equal(a.predict(x), b.predict(x))
    assert pickle.loads(pickle.dumps(b)).tolerance == 5


def test_score_counts_a_place_within_the_tolerance():
    """score(X, y) against numpy: |predict - y| <= tolerance, an outlier (y -1)
    right only when rejected; it grows with the tolerance."""
    x = route(80, 32, seed=12)
    rng = np.random.default_rng(13)
    q = x + 0.9 * rng.normal(size=x.shape).astype("f4") / np.sqrt(32)
    est = RhythmicMap().fit(x, progress=False)
    pred = est.predict(q)
    y = np.arange(80)
    y[::9] = -1
    got = []
    for tol in (0, 1, 3, 10):
        want = np.where(y >= 0, (pred >= 0) & (np.abs(pred - y) <= tol), pred == -1)
        est.set_params(tolerance=tol)
        got.append(est.score(q, y))
        assert got[-1] == pytest.approx(want.mean())
    assert got == sorted(got) and got[-1] > got[0]
    with pytest.raises(InputError, match="tolerance"):
        est.set_params(tolerance=-1).score(q, y)


def test_grid_search_scores_within_the_tolerance():
    """GridSearchCV's scores are the held-out recall@1 within the estimator's
    tolerance: the same folds give higher or equal scores at ±3 than at 0."""
    x = route(60, 32, seed=14)
    rng = np.random.default_rng(15)
    two = np.concatenate([x, x + 0.6 * rng.normal(size=x.shape).astype("f4") / 6])
    y = np.tile(np.arange(60), 2)
    scores = {}
    for tol in (0, 3):
        est = RhythmicMap(tolerance=tol)
        grid = GridSearchCV(est, {"r": [2, 3]}, cv=KFold(2), error_score="raise")
        grid.fit(two, y, progress=False)
        scores[tol] = grid.cv_results_["mean_test_score"]
        assert grid.best_estimator_.tolerance == tol
    assert np.all(scores[3] >= scores[0])
