"""Frames far longer or shorter than the solver fits (multiplied by 1e30 or
1e-30) are refused in one line by every fit, the command line's with or
without codes too; frames of length about 1 fit as before; a map that cannot
place most of its own frames says so; a solve stopped at its step cap warns."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import rhythmic_jax.fitting.fit_map as fit_map_module
from rhythmic_jax import predict
from rhythmic_jax.app.cli import main
from rhythmic_jax.errors import InputError
from rhythmic_jax.fitting.fit_map import LENGTH_RANGE, fit
from rhythmic_jax.map.config import MapConfig
from rhythmic_jax.solvers.newton import FitWarning, NewtonConfig
from rhythmic_jax.solvers.protocol import Newton


def route(n=120, d=64, seed=0):
    """n places of d features, L2-normalised rows (length 1)."""
    x = np.random.default_rng(seed).normal(size=(n, d)).astype(np.float32)
    return x / np.linalg.norm(x, axis=1, keepdims=True)


@pytest.mark.parametrize("scale", [1e30, 1e-30, 1e3, 1e-6])
def test_frames_of_extreme_length_are_refused_in_one_line(scale):
    x = route() * np.float32(scale)
    with pytest.raises(InputError, match=r"RMS length .* outside \[0.001, 100\]") as e:
        fit(x, MapConfig())
    assert "\n" not in str(e.value) and f"{1 / scale:.0e}" in str(e.value)


@pytest.mark.parametrize("scale", ["1e30", "1e-30"])
@pytest.mark.parametrize("codes", [(), ("--codes", "int8")])
def test_the_command_line_refuses_them_with_exit_2(tmp_path, capsys, scale, codes):
    np.save(tmp_path / "ref.npy", route() * np.float32(float(scale)))
    status = main(["fit", str(tmp_path / "ref.npy"), "--out", str(tmp_path / "m.map"),
                   "--no-progress", *codes])  # fmt: skip
    err = capsys.readouterr().err
    assert status == 2 and err.count("\n") == 1 and "RMS length" in err, err
    assert not (tmp_path / "m.map").exists()


def test_frames_of_length_one_fit_unaffected():
    """Inside the range nothing changes: the same places as the solver's own
    templates give, every frame its own place, and no warning."""
    x = route()
    lo, hi = LENGTH_RANGE
    assert lo < 1 < hi
    with warnings.catch_warnings():
        warnings.simplefilter("error", FitWarning)
        m = fit(x, MapConfig())
    pred = np.asarray(predict(m, x))
    scores = x @ np.asarray(m.w) + np.asarray(m.b)
    # the hard decode recomputed: argmax phase per period, the place of those
    # residues (Chinese remainder, by table), -1 where no place has them
    off, phases = 0, []
    for t in m.periods:
        phases.append(np.argmax(scores[:, off : off + t], axis=1))
        off += t
    place = {tuple(i % t for t in m.periods): i for i in range(len(x))}
    want = [place.get(tuple(int(p[j]) for p in phases), -1) for j in range(len(x))]
    np.testing.assert_array_equal(pred, want)
    assert np.mean(pred == np.arange(len(x))) > 0.9


def test_a_solve_stopped_at_its_cap_warns_and_the_command_line_says_one_line(
    tmp_path, capsys, monkeypatch
):
    x = np.random.default_rng(1).normal(size=(200, 48)).astype(np.float32)
    capped = lambda name, gap, progress: Newton(NewtonConfig(gap_tol=gap, max_iter=2))  # noqa: E731
    monkeypatch.setattr(fit_map_module, "solver_for", capped)
    with pytest.warns(FitWarning, match=r"cap of 2 Newton steps .* target gap 1e-07"):
        fit(x, MapConfig())
    np.save(tmp_path / "ref.npy", x)
    status = main(["fit", str(tmp_path / "ref.npy"), "--out", str(tmp_path / "m.map"),
                   "--no-progress"])  # fmt: skip
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if "warning" in line]
    assert status == 0 and len(lines) == 1, err
    assert "cap of 2 Newton steps" in lines[0] and "--gap" in lines[0]


def test_a_converging_fit_does_not_warn(tmp_path, capsys):
    x = route(n=80, d=32, seed=2)
    with warnings.catch_warnings():
        warnings.simplefilter("error", FitWarning)
        fit(x, MapConfig())
    np.save(tmp_path / "ref.npy", x)
    assert main(["fit", str(tmp_path / "ref.npy"), "--out", str(tmp_path / "m.map"),
                 "--no-progress"]) == 0  # fmt: skip
    assert "warning" not in capsys.readouterr().err


def test_a_map_that_cannot_place_its_own_frames_says_so(monkeypatch):
    """Templates that separate nothing (every frame alike) leave the map unable
    to place its frames: one warning line."""
    x = np.repeat(route(n=1, d=16), 60, axis=0)
    x += np.random.default_rng(0).normal(scale=1e-3, size=x.shape).astype(np.float32)
    with pytest.warns(FitWarning, match=r"places at most \d+% of its own frames"):
        fit(x, MapConfig(gap=1e-3))


def test_a_streamed_solve_stopped_at_its_cap_warns_alike(tmp_path, monkeypatch):
    import rhythmic_jax.fitting.scale_fit as scale_fit

    x = np.random.default_rng(1).normal(size=(200, 48)).astype(np.float32)
    np.save(tmp_path / "ref.npy", x)
    stream = scale_fit.StreamConfig
    monkeypatch.setattr(scale_fit, "StreamConfig",
                        lambda **kw: stream(**{**kw, "max_iter": 2}))  # fmt: skip
    with pytest.warns(FitWarning, match=r"cap of 2 Newton steps .* target gap 1e-07"):
        _, run = scale_fit.fit_map_files(
            MapConfig(), [str(tmp_path / "ref.npy")], stream=True, progress=False
        )
    assert run["steps"] == 2
