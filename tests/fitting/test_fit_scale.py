"""Unscaled 8-bit features: every fit refuses them alike, before any solve, with
one line of advice (:func:`rhythmic_jax.validate.check_fit_scale`); the same
values / 255 fit, and features just inside the limit reach liblinear's optimum."""

from __future__ import annotations

import numpy as np
import pytest

from rhythmic_jax import RhythmicMap
from rhythmic_jax.errors import InputError
from rhythmic_jax.fitting.fit_map import fit
from rhythmic_jax.fitting.fit_plan import plan
from rhythmic_jax.fitting.scale_fit import fit_map_files
from rhythmic_jax.map.config import MapConfig
from rhythmic_jax.solvers.newton import NewtonConfig
from rhythmic_jax.solvers.objective import targets
from rhythmic_jax.solvers.protocol import solver_for
from rhythmic_jax.validate import FIT_OFFSET_LIMIT, scale_sums

EIGHT_BIT = np.random.default_rng(0).integers(0, 254, (60, 16)).astype(np.float32)
ADVICE = (
    r"^reference features: values up to 253 \(8-bit scale\?\), their mean frame "
    r"[\d.]+ from the origin; the solvers expect features of order one: divide "
    r"them by 255 or L2-normalise each row$"
)
FITS = {
    "newton": lambda x, path: fit(x, MapConfig()),
    "lbfgs": lambda x, path: fit(x, MapConfig(solver="lbfgs")),
    "estimator": lambda x, path: RhythmicMap(scale="refuse").fit(x, progress=False),
    "stream": lambda x, path: fit_map_files(
        MapConfig(), [str(path)], stream=True, progress=False
    )[1],
}


def _solved(monkeypatch) -> list:
    """Records every solve that starts (none may, for refused features)."""
    import rhythmic_jax.fitting.fit_map as fit_map
    import rhythmic_jax.fitting.scale_fit as scale_fit

    calls = []

    def solver_for_spy(*args, **kwargs):
        calls.append("memory")
        return solver_for(*args, **kwargs)

    def streamed_spy(*args, **kwargs):
        calls.append("stream")
        raise AssertionError("the streamed solve started")

    monkeypatch.setattr(fit_map, "solver_for", solver_for_spy)
    monkeypatch.setattr(scale_fit, "streamed_newton_fit", streamed_spy)
    return calls


@pytest.mark.parametrize("how", sorted(FITS))
def test_every_fit_refuses_8_bit_features_alike_before_solving(
    how, tmp_path, monkeypatch
):
    np.save(tmp_path / "u8.npy", EIGHT_BIT)
    calls = _solved(monkeypatch)
    with pytest.raises(InputError, match=ADVICE) as err:
        FITS[how](EIGHT_BIT, tmp_path / "u8.npy")
    assert "\n" not in str(err.value) and calls == []


@pytest.mark.parametrize("how", sorted(FITS))
def test_the_same_values_over_255_fit(how, tmp_path):
    x = EIGHT_BIT / 255
    np.save(tmp_path / "x.npy", x)
    out = FITS[how](x, tmp_path / "x.npy")
    if how == "stream":
        assert out["mode"] == "stream"
        return
    params = out.params
    assert np.isfinite(np.asarray(params.w)).all()
    assert np.isfinite(np.asarray(params.b)).all()


def test_a_uint8_file_is_refused_as_its_float_values(tmp_path):
    np.save(tmp_path / "u8.npy", EIGHT_BIT.astype(np.uint8))
    with pytest.raises(InputError, match=ADVICE):
        fit_map_files(MapConfig(), [str(tmp_path / "u8.npy")], progress=False)


def test_features_just_inside_the_limit_reach_liblinears_optimum(liblinear_objectives):
    """Integers 0..2 scaled so that the mean frame lies just inside the limit
    (and an offset the frames share: above half their spread); 10 % more is
    refused."""
    base = np.random.default_rng(1).integers(0, 3, (60, 16)).astype(np.float64)
    sums = scale_sums(base)
    length = np.linalg.norm(sums[:-2] / 60)
    x = (base * (0.97 * FIT_OFFSET_LIMIT / length)).astype(np.float32)
    with pytest.raises(InputError, match="mean frame 4.268 from the origin"):
        fit(x * 1.1, MapConfig())
    fp = plan(MapConfig(), 60, 16)
    y = np.asarray(targets(np.arange(60), fp.trained))
    params, info = solver_for("newton").run(None, x, y, fp.c)
    x64 = x.astype(np.float64)
    ref = liblinear_objectives(x64, y, fp.c)
    assert np.all(info.gap_estimate <= NewtonConfig().gap_tol)
    w, b = np.asarray(params.w, np.float64), np.asarray(params.b, np.float64)
    got = 0.5 * (np.sum(w * w, 0) + b * b)
    got += fp.c * np.sum(np.maximum(0, 1 - y * (x64 @ w + b)) ** 2, 0)
    assert np.all(got <= ref * (1 + 1e-5)), np.max((got - ref) / ref)
    np.testing.assert_allclose(got, ref, rtol=1e-5)
