"""``rhythmic-jax describe``: a route described once into a .npy, then fitted,
queried and evaluated from the file, with the map the image folder gives."""

from __future__ import annotations

import json

import numpy as np
import pytest
from skimage import data as skdata
from skimage.io import imsave
from skimage.transform import resize

import rhythmic_jax as rj
from rhythmic_jax.app.cli import main


def run(capsys, *argv):
    code = main([*argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture()
def folders(tmp_path):
    """Two traversals (72 frames of 64x96 pixels) of one route: a photograph
    swept left to right, and the same frames darker and flatter."""
    photo = resize(skdata.astronaut(), (96, 640), anti_aliasing=True)
    frames = [(photo[:, 8 * i : 8 * i + 64] * 255).astype(np.uint8) for i in range(72)]
    for name, change in (("a", lambda f: f), ("b", lambda f: f * 0.9 + 10)):
        (tmp_path / name).mkdir()
        for i, f in enumerate(frames):
            img = np.clip(change(f.astype(np.float32)), 0, 255).astype(np.uint8)
            imsave(tmp_path / name / f"frame{i:03d}.png", img, check_contrast=False)
    return tmp_path


def test_describe_then_fit_gives_the_folders_map(folders, capsys, monkeypatch):
    """describe + fit on the .npy = fit on the folder: same periods, same
    predictions for the other traversal (described the same way), and the
    file's rows are the public function's."""
    monkeypatch.setenv("RHYTHMIC_JAX_CACHE", str(folders / "cache"))
    a, b = str(folders / "a"), str(folders / "b")
    for name in ("a", "b"):
        code, out, err = run(capsys, "describe", str(folders / name), "--out",
                             str(folders / f"{name}.npy"), "--no-progress")  # fmt: skip
        assert code == 0, err
        assert out.strip().endswith("2048-d float32 (589,824 B)"), out
    xa = np.load(folders / "a.npy")
    assert xa.shape == (72, 2048) and xa.dtype == np.float32
    np.testing.assert_array_equal(rj.describe_frames(a, "patchnorm"), xa)
    for src, out_map in ((a, "folder.map"), (str(folders / "a.npy"), "file.map")):
        code, _, err = run(capsys, "fit", src, "--out", str(folders / out_map),
                           "--no-progress")  # fmt: skip
        assert code == 0, err
    from_folder = rj.RhythmicMap.load(folders / "folder.map")
    from_file = rj.RhythmicMap.load(folders / "file.map")
    assert from_file.periods == from_folder.periods
    preds = []
    for out_map, queries in (("folder.map", b), ("file.map", str(folders / "b.npy"))):
        code, out, err = run(capsys, "query", str(folders / out_map), queries,
                             "--json", "--no-progress")  # fmt: skip
        assert code == 0, err
        preds.append(json.loads(out)["predictions"])
    assert preds[0] == preds[1]
    assert np.mean(np.abs(np.asarray(preds[1]) - np.arange(72)) <= 1) > 0.9
    code, out, err = run(capsys, "evaluate", str(folders / "file.map"),
                         str(folders / "b.npy"), "--json", "--no-progress")  # fmt: skip
    assert code == 0, err
    res = json.loads(out)
    assert res["methods"]["brute force"]["storage_bytes"] == 72 * 2048 * 4


def test_describe_refuses_in_one_line(folders, capsys):
    """A descriptor file, an out that is not .npy, --stride without --tile and
    a missing folder: exit 2, one line, nothing written."""
    np.save(folders / "x.npy", np.zeros((3, 4), np.float32))
    cases = [
        (["describe", str(folders / "x.npy"), "--out", str(folders / "y.npy")],
         "already a descriptor file"),
        (["describe", str(folders / "a"), "--out", str(folders / "a.txt")],
         "give a .npy file name"),
        (["describe", str(folders / "a"), "--out", str(folders / "y.npy"),
          "--stride", "2"], "--stride needs --tile"),
        (["describe", str(folders / "none"), "--out", str(folders / "y.npy")],
         "no such file or folder"),
        (["describe", str(folders / "a"), "--out", str(folders / "a")],
         "the same path as"),
    ]  # fmt: skip
    for argv, says in cases:
        code, _, err = run(capsys, *argv, "--no-progress")
        assert code == 2 and len(err.strip().splitlines()) == 1, (argv, err)
        assert says in err, (argv, err)
    assert not (folders / "y.npy").exists() and not (folders / "a.txt").exists()


def test_evaluate_reads_the_references_from_the_cache(folders, capsys, monkeypatch):
    """The brute-force line of evaluate takes the reference rows the fit left in
    the descriptor cache: only the queries are described (one new entry), and
    the reference's entry is read, not written again."""
    cache = folders / "cache"
    monkeypatch.setenv("RHYTHMIC_JAX_CACHE", str(cache))
    code, _, err = run(capsys, "fit", str(folders / "a"), "--out",
                       str(folders / "m.map"), "--no-progress")  # fmt: skip
    assert code == 0, err
    before = {p.name: p.stat().st_mtime_ns for p in cache.glob("*.npy")}
    assert len(before) == 1 and next(iter(before)).startswith("a-")
    code, out, err = run(capsys, "evaluate", str(folders / "m.map"),
                         str(folders / "b"), "--json", "--no-progress")  # fmt: skip
    assert code == 0, err
    after = {p.name: p.stat().st_mtime_ns for p in cache.glob("*.npy")}
    assert set(after) - set(before) == {n for n in after if n.startswith("b-")}
    assert len(after) == 2
    assert all(after[n] == t for n, t in before.items())  # read, not rewritten
    assert json.loads(out)["methods"]["brute force"]["storage_bytes"] == 72 * 2048 * 4
