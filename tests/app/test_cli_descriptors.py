"""Every descriptor through the installed ``rhythmic-jax``: fit -> info -> query ->
evaluate, on image folders and on a tiled image, run from a directory other than
the fit's, with the map moved after fitting (the map must find its descriptor's
weights wherever it is used)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import skimage.io
from skimage.transform import resize

from rhythmic_jax.frames.weights import LITE0_PACKAGE, file_sha256, packaged_path

FRAMES = 8
TILE = ["--tile", "32", "--stride", "32"]


def _smooth(rng, h: int, w: int) -> np.ndarray:
    """A random uint8 (h, w, 3) image, smooth enough to survive mild noise."""
    low = rng.uniform(0, 1, (h // 8, w // 8, 3))
    return (resize(low, (h, w), order=1) * 255).astype(np.uint8)


def _noisy(rng, image: np.ndarray) -> np.ndarray:
    noise = rng.normal(0, 6, image.shape)
    return np.clip(image + noise, 0, 255).astype(np.uint8)


def _save(path: Path, image: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    skimage.io.imsave(path, image, check_contrast=False)


def _route(root: Path, kind: str) -> tuple[str, str]:
    """Reference and query sources (relative to ``root``) of ``FRAMES`` places."""
    rng = np.random.default_rng(0)
    if kind == "folders":
        for i in range(FRAMES):
            frame = _smooth(rng, 32, 64)
            _save(root / "ref" / f"{i:03d}.png", frame)
            _save(root / "qry" / f"{i:03d}.png", _noisy(rng, frame))
        return "ref", "qry"
    big = _smooth(rng, 64, 32 * FRAMES // 2)  # 2 x 4 tiles of 32
    _save(root / "aerial.png", big)
    _save(root / "aerial_q.png", _noisy(rng, big))
    return "aerial.png", "aerial_q.png"


def _cli(cwd: Path, cache: Path, *argv: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "RHYTHMIC_JAX_CACHE": str(cache)}  # PYTHONPATH inherited
    return subprocess.run(
        ["rhythmic-jax", *argv], cwd=cwd, env=env, capture_output=True, text=True,
        timeout=600,
    )  # fmt: skip


def _ok(proc: subprocess.CompletedProcess) -> str:
    assert proc.returncode == 0, proc.stderr[-2000:]
    return proc.stdout


FAST = ("efficientnet_lite0", "folders")  # the rest run in the slow step
CASES = [
    pytest.param(d, k, marks=() if (d, k) == FAST else pytest.mark.slow, id=f"{d}-{k}")
    for d in ("patchnorm", "hog", "efficientnet_lite0", "vgg16_fc7")
    for k in ("folders", "tiles")
]


@pytest.mark.parametrize("descriptor, kind", CASES)
def test_fit_info_query_evaluate_elsewhere(tmp_path, small_vgg16, descriptor, kind):
    fit_dir, elsewhere, cache = tmp_path / "fit", tmp_path / "elsewhere", tmp_path / "c"
    elsewhere.mkdir()
    ref, qry = _route(fit_dir, kind)
    tile = TILE if kind == "tiles" else []
    weights = []
    if descriptor == "vgg16_fc7":
        weights = ["--weights", str(small_vgg16(fit_dir / "vgg16.pth"))]
    _ok(_cli(fit_dir, cache, "fit", ref, "--descriptor", descriptor, *weights,
             "--out", "route.map", "--no-progress", *tile))  # fmt: skip
    moved = shutil.move(fit_dir / "route.map", tmp_path / "moved" / "route.map")

    info = json.loads(_ok(_cli(elsewhere, cache, "info", str(moved), "--json")))
    assert info["descriptor"] == descriptor and info["n"] == FRAMES
    settings = info["descriptor_settings"]
    if descriptor == "efficientnet_lite0":
        assert settings["weights_package"] == LITE0_PACKAGE
        assert settings["weights_sha256"] == file_sha256(packaged_path())
        assert settings["weights"] == packaged_path().name
    elif descriptor == "vgg16_fc7":
        assert settings["weights"] == weights[1] and Path(weights[1]).is_absolute()
        assert settings["weights_sha256"] == file_sha256(weights[1])
    else:
        assert not any(k.startswith("weights") for k in settings)

    queries = str(fit_dir / qry)
    pred_file = elsewhere / "pred.npy"
    _ok(_cli(elsewhere, cache, "query", str(moved), queries, "--out", "pred.npy",
             "--no-progress", *tile))  # fmt: skip
    pred = np.load(pred_file)
    assert pred.shape == (FRAMES,)
    assert (pred == np.arange(FRAMES)).mean() >= 0.75, pred

    out = _ok(_cli(elsewhere, cache, "evaluate", str(moved), queries, "--json",
                   "--no-progress", *tile))  # fmt: skip
    result = json.loads(out)
    assert result["methods"]["map"]["accuracy"] == (pred == np.arange(FRAMES)).mean()
    brute = result["methods"]["brute force"]  # the map's reference, found again
    assert brute["recall@1"] >= 0.75
    assert str(fit_dir / ref) in result["reference_note"]
