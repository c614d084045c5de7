"""The library is quiet; bars appear where asked for and TQDM_DISABLE hides them."""

from __future__ import annotations

import numpy as np
import pytest

from rhythmic_jax import RhythmicMap
from rhythmic_jax.app.cli import main
from rhythmic_jax.frames.features import describe, get_descriptor
from rhythmic_jax.progress import bar, bars_disabled

X = np.random.default_rng(0).normal(size=(40, 8)).astype(np.float32)


def test_fit_and_describe_are_quiet_by_default(capfd, monkeypatch):
    monkeypatch.delenv("TQDM_DISABLE", raising=False)
    RhythmicMap().fit(X)
    describe(np.zeros((3, 32, 64, 3), np.uint8), get_descriptor("patchnorm"))
    out, err = capfd.readouterr()
    assert out == "" and err == ""
    RhythmicMap().fit(X, verbose=1)
    assert "newton" in capfd.readouterr().err


@pytest.mark.parametrize("value, hidden", [("1", True), ("true", True), ("0", False)])
def test_tqdm_disable_hides_bars_that_were_asked_for(capfd, monkeypatch, value, hidden):
    monkeypatch.setenv("TQDM_DISABLE", value)
    assert bars_disabled() == hidden
    list(bar(range(3), show=True, desc="counting"))
    assert ("counting" not in capfd.readouterr().err) == hidden


def test_the_command_line_shows_bars_unless_disabled(tmp_path, capfd, monkeypatch):
    np.save(tmp_path / "ref.npy", X / np.linalg.norm(X, axis=1, keepdims=True))
    monkeypatch.delenv("TQDM_DISABLE", raising=False)
    assert main(["fit", str(tmp_path / "ref.npy"), "--out", str(tmp_path / "a")]) == 0
    assert "newton" in capfd.readouterr().err
    monkeypatch.setenv("TQDM_DISABLE", "1")
    assert main(["fit", str(tmp_path / "ref.npy"), "--out", str(tmp_path / "b")]) == 0
    assert "newton" not in capfd.readouterr().err


@pytest.mark.parametrize("value, hidden", [("1", True), ("0", False)])
def test_the_scale_out_bars_follow_tqdm_disable(tmp_path, capfd, monkeypatch, value,
                                                hidden):  # fmt: skip
    from PIL import Image

    from rhythmic_jax.frames.describe_shards import describe_to_shards
    from rhythmic_jax.io.frame_files import open_frames
    from rhythmic_jax.solvers.streamed import StreamConfig, streamed_newton_fit

    monkeypatch.setenv("TQDM_DISABLE", value)
    (tmp_path / "route").mkdir()
    for i in range(3):
        Image.fromarray(np.full((32, 64, 3), 40 * i, np.uint8)).save(
            tmp_path / "route" / f"{i:03d}.png"
        )
    describe_to_shards(tmp_path / "route", tmp_path / "shards", progress=True)
    np.save(tmp_path / "ref.npy", X / np.linalg.norm(X, axis=1, keepdims=True))
    frames = open_frames(tmp_path / "ref.npy")
    config = StreamConfig(max_iter=2, max_cg=2)
    streamed_newton_fit(frames, np.arange(40), (3, 4), 1.0, config, progress=True)
    err = capfd.readouterr().err
    assert ("newton (streamed)" not in err) == hidden
    assert ("route" not in err) == hidden
