"""The fit job at scale through the installed command: shards from image folders."""

import json
import subprocess

import numpy as np
import pytest

from rhythmic_jax import RhythmicMap
from rhythmic_jax.frames.features import describe, get_descriptor
from rhythmic_jax.io.frame_files import open_frames, shard_descriptor
from rhythmic_jax.io.images import list_images, read_rgb


def _run(cwd, *args):
    cmd = ["rhythmic-jax", *args, "--no-progress"]
    return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)


@pytest.mark.slow
def test_shards_are_described_from_an_image_folder_and_fitted(tmp_path, nordland_root):
    """``fit route/ --shards DIR`` from another directory on 300 real Nordland
    frames: the shards hold the patch-normalised descriptors the library computes,
    and the map is the one fitted on the images directly."""
    route = tmp_path / "route"
    route.mkdir()
    for path in list_images(nordland_root / "summer", "traversal")[:300]:
        (route / path.name).symlink_to(path)
    work = tmp_path / "elsewhere"
    work.mkdir()
    done = _run(work, "fit", "../route", "--out", "shards.map", "--shards",
                "../route.shards", "--memory", "2GiB", "--json")  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    info = json.loads(done.stdout[done.stdout.index("{") :])
    folder = tmp_path / "route.shards" / "00-route"
    assert shard_descriptor(folder)[0] == "patchnorm"
    frames = open_frames(folder)
    images = np.stack([read_rgb(p) for p in list_images(route, "traversal")])
    want = describe(images, get_descriptor("patchnorm"), progress=False)
    np.testing.assert_allclose(frames.read(0, frames.n), want, atol=1e-6)
    plain = _run(work, "fit", "../route", "--out", "plain.map")
    assert plain.returncode == 0, plain.stderr[-3000:]
    a = RhythmicMap.load(work / "shards.map")
    b = RhythmicMap.load(work / "plain.map")
    assert a.periods == b.periods == tuple(info["periods"])
    np.testing.assert_allclose(a.candidate_errors, b.candidate_errors, atol=1e-6)
    w1, w2 = np.asarray(b.params.w), np.asarray(a.params.w)
    assert np.linalg.norm(w2 - w1) / np.linalg.norm(w1) < 1e-5
    # the same images again: the shards described are taken, not refused
    again = _run(work, "fit", "../route", "--out", "again.map", "--shards",
                 "../route.shards", "--memory", "2GiB")  # fmt: skip
    assert again.returncode == 0, again.stderr[-3000:]
    c = RhythmicMap.load(work / "again.map")
    np.testing.assert_array_equal(np.asarray(c.params.w), w2)
    # other images into the same folder: one line
    extra = list_images(nordland_root / "summer", "traversal")[300]
    (route / extra.name).symlink_to(extra)
    other = _run(work, "fit", "../route", "--out", "other.map", "--shards",
                 "../route.shards")  # fmt: skip
    assert other.returncode == 2 and "other images" in other.stderr
    assert len(other.stderr.strip().splitlines()) == 1


@pytest.mark.slow
def test_fixed_periods_stream_and_leave_no_checkpoint(tmp_path):
    rng = np.random.default_rng(0)
    x = np.cumsum(rng.normal(size=(300, 16)), axis=0).astype(np.float32)
    np.save(tmp_path / "ref.npy", x / np.linalg.norm(x, axis=1, keepdims=True))
    args = ["fit", "ref.npy", "--out", "m.map", "--stream", "--memory", "1GiB",
            "--gap", "1e-3", "--json"]  # fmt: skip
    done = _run(tmp_path, *args, "--layout", "periods:17,19")
    assert done.returncode == 0, done.stderr
    info = json.loads(done.stdout[done.stdout.index("{") :])
    assert info["periods"] == [17, 19] and info["candidates"] == []
    assert info["fit"]["mode"] == "stream" and info["fit"]["passes"] > 2
    assert not (tmp_path / "m.map.ckpt").exists()
    model = RhythmicMap.load(tmp_path / "m.map")
    assert model.periods == (17, 19) and model.params.w.shape == (16, 36)
    # a layout the streamed solver does not train is refused in one line
    bad = _run(tmp_path, *args[:3], "n.map", *args[4:], "--layout", "mixed")
    assert bad.returncode == 2 and "--layout" in bad.stderr
    assert len(bad.stderr.strip().splitlines()) == 1
