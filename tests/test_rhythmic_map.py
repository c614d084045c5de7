"""The estimator: fit, period choice, predict, storage, save/load, refusals."""

from __future__ import annotations

import numpy as np
import pytest
from jax.experimental.sparse import BCOO
from scipy import sparse

from rhythmic_jax import InputError, MapConfig, RhythmicMap
from rhythmic_jax.decoding.dispatch import decode_scores
from rhythmic_jax.map.periods import candidate_periods, choose_periods, storage_bytes
from rhythmic_jax.solvers.objective import objective, period_errors, scores, targets


def wide(n=150, d=250, seed=0):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, d)).astype(np.float32)
    return x / np.linalg.norm(x, axis=1, keepdims=True)


@pytest.fixture(scope="module")
def fitted():
    x = wide()
    return RhythmicMap(r=2, level=1).fit(x, progress=False), x


def test_fit_chooses_coprime_candidates_and_keeps_only_them(fitted):
    model, x = fitted
    assert model.candidates == candidate_periods(150, 2, 1, 7)
    assert set(model.periods) <= set(model.candidates)
    errors = model.candidate_errors
    assert model.periods == choose_periods(model.candidates, errors, 150)
    assert model.params.w.shape == (250, sum(model.periods))
    assert (
        model.storage_bytes
        == storage_bytes(model.periods, 250)
        == sum(model.periods) * 251 * 4
    )
    ratio = sum(model.periods) * 251 / (150 * 250)
    assert model.compression_ratio == pytest.approx(ratio)


def test_candidate_errors_come_from_the_joint_fit(fitted):
    model, x = fitted
    err = period_errors(scores(model.params, x), np.arange(150), model.periods)
    idx = [model.candidates.index(t) for t in model.periods]
    np.testing.assert_allclose(
        np.asarray(err), np.asarray(model.candidate_errors)[idx], atol=1e-6
    )


def test_self_query_is_exact_on_separable_frames(fitted):
    model, x = fitted
    np.testing.assert_array_equal(model.predict(x), np.arange(150))
    for method in ("soft", "topm"):
        np.testing.assert_array_equal(model.predict(x, method), np.arange(150))


def test_threshold_rejects_low_confidence_queries(fitted):
    model, x = fitted
    noise = wide(50, 250, seed=7)
    conf_in = np.asarray(model.decode(x).confidence)
    thr = float(np.quantile(conf_in, 0.05))
    kept = model.predict(x, threshold=thr)
    assert (kept >= 0).mean() >= 0.94
    rejected = model.predict(noise, threshold=thr)
    assert (rejected == -1).mean() > (kept == -1).mean()


def test_multi_exemplar_labels_share_templates():
    base = wide(120, 200, seed=1)
    rng = np.random.default_rng(2)
    second = base + 0.3 * rng.normal(size=base.shape).astype(np.float32) / 20
    x = np.concatenate([base, second])
    labels = np.tile(np.arange(120), 2)
    model = RhythmicMap().fit(x, labels, progress=False)
    assert model.n == 120
    assert (model.predict(second) == np.arange(120)).mean() > 0.95


def test_lbfgs_solver_reaches_the_newton_map(fitted):
    model, x = fitted
    other = RhythmicMap(solver="lbfgs").fit(x, progress=False)
    assert other.periods == model.periods
    np.testing.assert_array_equal(other.predict(x), model.predict(x))


def test_gap_setting_stops_near_the_optimum():
    x = wide(400, 120, seed=3)
    exact = RhythmicMap().fit(x, progress=False)
    loose = RhythmicMap(gap=5e-4).fit(x, progress=False)
    assert loose.periods == exact.periods
    y = targets(np.arange(len(x)), exact.periods)
    f_exact = np.asarray(objective(exact.params, x, y, exact.map_.c), np.float64)
    f_loose = np.asarray(objective(loose.params, x, y, loose.map_.c), np.float64)
    rel = (f_loose - f_exact) / f_exact
    assert rel.max() <= 1e-3  # within 0.1 % of the optimum, template by template
    assert rel.max() > 1e-7  # and it did stop early
    with pytest.raises(InputError, match="gap"):
        MapConfig(gap=0.0)


def test_save_load_round_trip_and_refusals(fitted, tmp_path):
    model, x = fitted
    model.save(tmp_path / "m")
    again = RhythmicMap.load(tmp_path / "m")
    assert again.periods == model.periods and again.n == 150 and again.d == 250
    np.testing.assert_array_equal(again.predict(x), model.predict(x))
    assert again.info() == model.info()
    with pytest.raises(InputError, match="descriptor 'features'"):
        RhythmicMap.load(tmp_path / "m", descriptor="patchnorm")
    with pytest.raises(InputError, match="250-d"):
        RhythmicMap.load(tmp_path / "m", d=64)
    with pytest.raises(InputError, match="250-d"):
        again.predict(x[:, :64])


@pytest.mark.parametrize(
    "bad, match",
    [
        (np.zeros((0, 5), np.float32), "empty"),
        (np.zeros(5, np.float32), "2-D"),
        (np.full((10, 5), np.nan, np.float32), "NaN or inf"),
        (np.array([["a"]]), "numbers"),
    ],
)
def test_bad_reference_features(bad, match):
    with pytest.raises(InputError, match=match):
        RhythmicMap().fit(bad, progress=False)


def test_bad_configuration():
    with pytest.raises(InputError, match="solver"):
        MapConfig(solver="sgd")
    with pytest.raises(InputError, match="r "):
        RhythmicMap(r=1).fit(wide(20, 30), progress=False)
    with pytest.raises(InputError, match="not fitted"):
        RhythmicMap().predict(wide(2, 3))


def test_targets_follow_labels_not_rows():
    y = np.asarray(targets(np.array([0, 1, 0, 1]), (2, 3)))
    np.testing.assert_array_equal(y[0], y[2])


@pytest.mark.slow
@pytest.mark.parametrize("level, floor", [(1, 0.93)])
def test_nordland_self_query_reaches_the_optimum_accuracy(
    nordland_patchnorm, level, floor
):
    """The paper's Table 2 protocol on Nordland summer (3576 frames, patchnorm)."""
    summer, _ = nordland_patchnorm
    model = RhythmicMap(level=level).fit(summer, progress=False)
    acc = float(np.mean(model.predict(summer) == np.arange(len(summer))))
    assert acc >= floor, (level, model.periods, acc)
    assert 0.03 < min(model.candidate_errors) and max(model.candidate_errors) < 0.06


def test_fused_hard_decode_equals_scores_then_decode(fitted):
    """``decode`` runs scores and the hard decode in one compiled call; it gives
    what decoding the map's scores gives, field by field."""
    model, x = fitted
    q = x[::3] + np.random.default_rng(1).normal(0, 0.5, x[::3].shape).astype("f4")
    fused = model.decode(q)
    apart = decode_scores(model.scores(q), model.periods, model.n, "hard", 1)
    assert (np.asarray(fused.index) == -1).any() and (
        np.asarray(fused.index) >= 0
    ).any()
    for a, b in zip(fused, apart, strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-6)


@pytest.mark.parametrize("layout", ["mixed", "hierarchical:15:4,5"])
def test_layouts_localise_and_survive_a_round_trip(layout, tmp_path):
    x = wide()
    model = RhythmicMap(layout=layout).fit(x, progress=False)
    groups = model.groups
    assert groups.kind == layout.split(":")[0] and model.periods == ()
    assert model.params.w.shape == (250, groups.p)
    assert model.storage_bytes == groups.p * 251 * 4
    assert model.compression_ratio == pytest.approx(groups.p * 251 / (150 * 250))
    assert len(model.group_errors) == len(groups.sizes)
    rng = np.random.default_rng(3)
    q = x + 0.01 * rng.normal(size=x.shape).astype(np.float32)
    preds = {}
    for method in ("hard", "soft", "topm"):
        preds[method] = model.predict(q, method)
        assert (preds[method] == np.arange(150)).mean() > 0.97, method
    preds["sequence"] = model.predict(q, "soft", sequence=5)
    assert (preds["sequence"] == np.arange(150)).mean() > 0.97
    info = model.info()
    assert info["groups"] == groups.to_dict() and info["layout"] == groups.describe()
    model.save(tmp_path / "route.map")
    back = RhythmicMap.load(tmp_path / "route.map")
    assert back.groups == groups and back.config.layout == layout
    for method, want in preds.items():
        got = back.predict(q, "soft", sequence=5) if method == "sequence" else None
        got = back.predict(q, method) if got is None else got
        np.testing.assert_array_equal(got, want)


def test_maps_saved_without_a_layout_still_load(fitted, tmp_path):
    import json

    model, x = fitted
    model.save(tmp_path / "old.map")
    meta_file = tmp_path / "old.map" / "map.json"
    meta = json.loads(meta_file.read_text())
    for key in ("layout", "groups", "group_errors"):
        del meta[key]
    del meta["config"]["layout"]
    meta_file.write_text(json.dumps(meta))
    back = RhythmicMap.load(tmp_path / "old.map")
    assert back.groups.kind == "periods" and back.groups.sizes == model.periods
    np.testing.assert_array_equal(back.predict(x), model.predict(x))


def test_maps_saved_with_the_top_m_count_as_m_still_load(fitted, tmp_path):
    """The phases top-m keeps were saved as ``m`` before they were named
    ``top``: such a map.json loads with them as ``top``."""
    import json

    model, x = fitted
    model.save(tmp_path / "old.map")
    meta_file = tmp_path / "old.map" / "map.json"
    meta = json.loads(meta_file.read_text())
    assert meta["config"].pop("top") == 3
    meta["config"]["m"] = 2
    meta_file.write_text(json.dumps(meta))
    back = RhythmicMap.load(tmp_path / "old.map")
    assert back.config.top == 2 and back.top == 2 and "m" not in back.get_params()
    np.testing.assert_array_equal(
        back.predict(x, "topm"), model.predict(x, "topm", top=2)
    )
    assert back.info()["config"]["top"] == 2 and "m" not in back.info()["config"]


def test_bad_layouts_are_refused_before_fitting():
    with pytest.raises(InputError, match="layout 'mixed:1,2'"):
        RhythmicMap(layout="mixed:1,2").fit(np.zeros((0, 3)), progress=False)
    with pytest.raises(InputError, match="tells apart 100 places"):
        RhythmicMap(layout="mixed:10,10").fit(wide(), progress=False)


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda x: x + 0.5j, r"Complex data not supported \(dtype complex64\)"),
        (sparse.csr_matrix, "sparse matrix"),
        (sparse.coo_array, "sparse matrix"),
        (lambda x: BCOO.fromdense(x), "sparse matrix"),
    ],
)
def test_complex_and_sparse_features_are_refused_naming_them(fitted, make, match):
    """Not cut to their real part, not read as one object: fit, predict, locate
    and the pure functions refuse them in one line."""
    import rhythmic_jax as rj

    model, x = fitted
    bad = make(x[:20])
    calls = [
        lambda: RhythmicMap().fit(bad, progress=False),
        lambda: rj.fit(bad),
        lambda: model.predict(bad),
        lambda: rj.predict(model.map_, bad),
        lambda: rj.decode(model.map_, bad),
    ]
    if match.startswith("Complex"):
        calls.append(lambda: model.locate(bad[0]))
    for call in calls:
        with pytest.raises(InputError, match=match) as err:
            call()
        assert "\n" not in str(err.value)


def test_the_command_line_queries_a_scaled_labelled_map_as_the_estimator(tmp_path):
    """A map the estimator fitted on unscaled frames with place labels, saved,
    is queried by the command line's job (a ``Map`` value, no estimator) to
    the estimator's places, and both equal the map's own pure functions applied
    by hand: queries standardized with numpy, place rows named by the labels."""
    import rhythmic_jax as rj
    from rhythmic_jax.app import jobs
    from rhythmic_jax.app.specs import QueryJob
    from rhythmic_jax.decoding import held

    x = wide(120, 40, seed=3) * 200.0 + 50.0  # not of order one: standardized
    labels = np.arange(120) * 3 + 7  # places named 7, 10, ... (not rows)
    est = RhythmicMap(level=1).fit(x, labels)
    assert {"scale_mean", "scale_std", "place_labels"} <= set(est.extra)
    est.save(tmp_path / "m.map")
    q = x + np.random.default_rng(4).normal(size=x.shape).astype(np.float32)
    np.save(tmp_path / "q.npy", q.astype(np.float32))
    mean = x.mean(axis=0, dtype=np.float64).astype(np.float32)
    std = x.std(axis=0, dtype=np.float64).astype(np.float32)
    m = rj.load(tmp_path / "m.map")
    for method in ("hard", "soft", "topm"):
        rows = np.asarray(rj.predict(m, (q - mean) / std, method))
        by_hand = np.where(rows >= 0, labels[np.maximum(rows, 0)], -1)
        np.testing.assert_array_equal(est.predict(q, method), by_hand)
        np.testing.assert_array_equal(held.predict(m, q, method), by_hand)
        job = QueryJob(str(tmp_path / "m.map"), str(tmp_path / "q.npy"), decode=method)
        np.testing.assert_array_equal(jobs.query(job), by_hand)
    assert (by_hand >= 7).mean() > 0.9  # most queries placed, by their labels
    assert est.locate(q[5]) == held.locate(m, q[5]) == by_hand[5]


def test_fit_frames_is_the_estimators_fit():
    """``fit_frames`` (what the demo, the frontier and the ablation fit with) gives
    the estimator's map: the same templates, periods and extra arrays."""
    from rhythmic_jax.fitting.prepare import fit_frames

    x = wide(90, 30, seed=5) * 100.0 + 30.0  # standardized by scale="auto"
    est = RhythmicMap(r=2, level=2).fit(x)
    m = fit_frames(x, MapConfig(r=2, level=2))
    assert m.periods == est.periods and sorted(m.extra) == sorted(est.extra) != []
    np.testing.assert_array_equal(np.asarray(m.w), np.asarray(est.map_.w))
    np.testing.assert_array_equal(m.extra["scale_mean"], est.extra["scale_mean"])
    with pytest.raises(InputError, match="scale must be one of"):
        fit_frames(x, MapConfig(), scale="sometimes")


def test_a_held_map_reads_as_the_estimator_does(fitted):
    """What the reports and printers read of the command line's map
    (:class:`~rhythmic_jax.decoding.held.HeldMap`) is what they read of the
    estimator holding the same map."""
    from rhythmic_jax.decoding.held import HeldMap

    model, x = fitted
    held = HeldMap(model.map_)
    for name in ("n", "d", "periods", "candidates", "groups", "codebook",
                 "storage_bytes", "compression_ratio", "embedding_bytes",
                 "reference", "config"):  # fmt: skip
        assert getattr(held, name) == getattr(model, name), name
    assert held.storage_bytes == sum(model.periods) * 251 * 4
    assert held.info() == model.info() and held.value is model.map_
    for method in ("hard", "soft", "topm"):
        np.testing.assert_array_equal(held.predict(x, method), np.arange(150))
    assert held.locate(x[7]) == 7
    np.testing.assert_array_equal(
        np.asarray(held.decode(x[:9]).index), np.asarray(model.decode(x[:9]).index)
    )
