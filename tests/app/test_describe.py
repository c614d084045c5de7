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


# ------------------------------------------------- descriptor files' records


def ok(capsys, *argv):
    code, out, err = run(capsys, *argv, "--no-progress")
    assert code == 0, (argv, err)
    return out


def refused(capsys, *argv):
    """The one line a refused command prints (exit status 2)."""
    code, _, err = run(capsys, *argv, "--no-progress")
    assert code == 2 and len(err.strip().splitlines()) == 1, (argv, err)
    return err


def test_a_described_file_goes_through_every_command(corridor, capsys, monkeypatch):
    """describe writes ref.npy with its record; a map fitted from it knows its
    descriptor, so image-folder queries, --matches (frames found through the
    records), embeddings learned on the folders, learn and frontier all take it."""
    monkeypatch.setenv("RHYTHMIC_JAX_CACHE", str(corridor / "cache"))
    c = corridor
    for name in ("ref", "query"):
        ok(capsys, "describe", str(c / name), "--out", str(c / f"{name}.npy"))
    record = json.loads((c / "ref.npy.json").read_text())
    names = sorted(p.name for p in (c / "ref").iterdir())
    assert record["descriptor"] == "patchnorm" and record["input_size"] == [64, 32]
    assert record["frames"] == names and record["folder"] == str(c / "ref")
    assert (record["rows"], record["dim"]) == (60, 2048)
    import hashlib

    assert record["sha256"] == hashlib.sha256((c / "ref.npy").read_bytes()).hexdigest()
    ok(capsys, "fit", str(c / "ref.npy"), "--out", str(c / "m.map"))
    ok(capsys, "fit", str(c / "ref.npy"), "--stream", "--out", str(c / "s.map"))
    model = rj.RhythmicMap.load(c / "m.map")
    assert model.config.descriptor == "patchnorm"
    assert rj.RhythmicMap.load(c / "s.map").config.descriptor == "patchnorm"
    assert model.config.descriptor_settings["width"] == 64
    preds = [
        json.loads(ok(capsys, "query", str(c / "m.map"), q, "--json"))["predictions"]
        for q in (str(c / "query"), str(c / "query.npy"))
    ]
    assert preds[0] == preds[1]
    ok(
        capsys,
        "evaluate",
        str(c / "m.map"),
        str(c / "query.npy"),
        "--tolerance",
        "1",
        "--matches",
        str(c / "m.png"),
    )
    assert (c / "m.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    ok(capsys, "learn", str(c / "ref"), str(c / "query"), "--out", str(c / "f.emb"),
       "--k", "16")  # fmt: skip
    ok(capsys, "fit", str(c / "ref.npy"), "--embedding", str(c / "f.emb"), "--out",
       str(c / "e.map"))  # fmt: skip
    ok(capsys, "learn", str(c / "ref.npy"), str(c / "query.npy"), "--out",
       str(c / "n.emb"), "--k", "16")  # fmt: skip
    code, out, err = run(capsys, "info", str(c / "n.emb"), "--json")
    assert code == 0 and json.loads(out)["descriptor"] == "patchnorm", err
    frontier = [
        "frontier",
        str(c / "ref.npy"),
        str(c / "query.npy"),
        "--maps",
        "2:1",
        "--bits",
        "8",
        "--pq",
        "",
        "--lengths",
        "1",
        "--tolerance",
        "1",
    ]
    ok(capsys, *frontier)
    x = np.load(c / "query.npy")
    np.save(c / "query.npy", x[::-1].copy())  # rewritten without describe
    for argv in (frontier, ["query", str(c / "m.map"), str(c / "query.npy")]):
        assert "the record of another file" in refused(capsys, *argv)


def test_files_without_records_declare_and_name_their_frames(
    corridor, capsys, monkeypatch
):
    """A .npy without a record: --descriptor declares it (its dimension
    checked), and --matches takes the frames from --query-images and
    --reference-images; without them it says which option names them."""
    monkeypatch.setenv("RHYTHMIC_JAX_CACHE", str(corridor / "cache"))
    c = corridor
    ref, qry = (rj.describe_frames(c / f, "patchnorm") for f in ("ref", "query"))
    np.save(c / "ref.npy", ref)
    np.save(c / "query.npy", qry)
    err = refused(capsys, "fit", str(c / "ref.npy"), "--descriptor", "hog", "--out",
                  str(c / "h.map"))  # fmt: skip
    assert "2048-d rows, but hog at 64x32 gives 756-d" in err
    ok(capsys, "fit", str(c / "ref.npy"), "--out", str(c / "plain.map"))
    assert "fit from files describe wrote" in refused(
        capsys, "query", str(c / "plain.map"), str(c / "query")
    )
    ok(capsys, "fit", str(c / "ref.npy"), "--descriptor", "patchnorm", "--out",
       str(c / "m.map"))  # fmt: skip
    assert rj.RhythmicMap.load(c / "m.map").config.descriptor == "patchnorm"
    ok(capsys, "query", str(c / "m.map"), str(c / "query"))
    evaluate = [
        "evaluate",
        str(c / "m.map"),
        str(c / "query.npy"),
        "--tolerance",
        "1",
        "--matches",
        str(c / "m.png"),
    ]
    assert "--query-images" in refused(capsys, *evaluate)
    err = refused(capsys, *evaluate, "--query-images", str(c / "query"))
    assert "--reference-images" in err
    ok(capsys, *evaluate, "--query-images", str(c / "query"), "--reference-images",
       str(c / "ref"))  # fmt: skip
    assert (c / "m.png").is_file()


def test_input_size_is_recorded_and_held_to(corridor, capsys, monkeypatch):
    """--input-size WxH: the rows are the descriptor's at that size, the record
    and the map keep it, and a map refuses queries described at another size
    (a file's record, or --input-size) in one line."""
    from rhythmic_jax.frames.features import get_descriptor

    monkeypatch.setenv("RHYTHMIC_JAX_CACHE", str(corridor / "cache"))
    c = corridor
    ok(capsys, "describe", str(c / "query"), "--input-size", "128x64", "--out",
       str(c / "q128.npy"))  # fmt: skip
    x = np.load(c / "q128.npy")
    assert x.shape == (60, 128 * 64)
    assert json.loads((c / "q128.npy.json").read_text())["input_size"] == [128, 64]
    from rhythmic_jax.io.images import load_traversal

    frames = load_traversal(c / "query").images
    want = get_descriptor("patchnorm", width=128, height=64)
    import torch

    batch = torch.from_numpy(frames).permute(0, 3, 1, 2).float() / 255
    np.testing.assert_allclose(x, want(batch).numpy(), atol=1e-6)
    ok(capsys, "fit", str(c / "ref"), "--out", str(c / "m.map"))
    err = refused(capsys, "query", str(c / "m.map"), str(c / "q128.npy"))
    assert "described at 128x64, the map's frames at 64x32" in err
    err = refused(capsys, "query", str(c / "m.map"), str(c / "query"),
                  "--input-size", "128x64")  # fmt: skip
    assert "the map's frames were described at 64x32" in err
    ok(capsys, "fit", str(c / "ref"), "--input-size", "128x64", "--out",
       str(c / "big.map"))  # fmt: skip
    big = rj.RhythmicMap.load(c / "big.map")
    assert (big.d, big.config.descriptor_settings["width"]) == (8192, 128)
    ok(capsys, "query", str(c / "big.map"), str(c / "q128.npy"))
    ok(capsys, "learn", str(c / "ref"), str(c / "query"), "--input-size", "128x64",
       "--k", "8", "--out", str(c / "e128.emb"))  # fmt: skip
    ok(capsys, "fit", str(c / "ref"), "--embedding", str(c / "e128.emb"), "--out",
       str(c / "e.map"))  # fmt: skip
    assert rj.RhythmicMap.load(c / "e.map").config.descriptor_settings["width"] == 128
    ok(capsys, "describe", str(c / "ref"), "--out", str(c / "ref.npy"))
    err = refused(capsys, "fit", str(c / "ref.npy"), "--embedding",
                  str(c / "e128.emb"), "--out", str(c / "f.map"))  # fmt: skip
    assert "learned on frames described at 128x64, the map's at 64x32" in err
    assert "WIDTHxHEIGHT" in refused(
        capsys,
        "describe",
        str(c / "ref"),
        "--input-size",
        "64",
        "--out",
        str(c / "y.npy"),
    )


def test_fit_says_when_a_map_buys_nothing(corridor, capsys, monkeypatch):
    """fit adds one line naming frontier when the map's share of the database's
    bytes is above 15 % (60 places: the share recomputed from the map's own
    arrays), or its periods' training error is high; none otherwise."""
    from rhythmic_jax.app.cli import worth_note

    monkeypatch.setenv("RHYTHMIC_JAX_CACHE", str(corridor / "cache"))
    c = corridor
    code, out, err = run(capsys, "fit", str(c / "ref"), "--out", str(c / "m.map"),
                         "--no-progress")  # fmt: skip
    assert code == 0, err
    model = rj.RhythmicMap.load(c / "m.map")
    share = model.storage_bytes / (60 * 2048 * 4)
    assert share > 0.15
    notes = [line for line in err.splitlines() if ": note: " in line]
    assert len(notes) == 1 and f"{100 * share:.1f} %" in notes[0]
    assert f"rhythmic-jax frontier {c / 'ref'} QUERIES" in notes[0]
    info = {
        "storage_bytes": 10,
        "database_bytes": 100,
        "periods": [5, 7],
        "candidates": [5, 6, 7],
        "candidate_errors": [0.0, 0.9, 0.05],
    }
    assert worth_note(info, ["r.npy"]) is None  # 10 %, and 6 was not chosen
    assert "miss 20.0 %" in worth_note({**info, "candidate_errors": [0.2, 0, 0]},
                                       ["r.npy"])  # fmt: skip
