"""``rhythmic-jax query --top K --json / --csv``: each query named, the place
chosen (named where the map's reference names it), its score and confidence,
and the K best places, checked against the map's scores summed by numpy."""

from __future__ import annotations

import csv
import io
import json

import numpy as np
import pytest
from skimage import data as skdata
from skimage.io import imsave
from skimage.transform import resize

from rhythmic_jax import RhythmicMap
from rhythmic_jax.app.cli import main
from rhythmic_jax.map.periods import place_columns


def run(capsys, *argv):
    code = main([*argv])
    out, err = capsys.readouterr()
    return code, out, err


def summed(model, x) -> np.ndarray:
    """Place scores (b, n) of a periods map by hand: sum_k s_k[i mod tau_k]."""
    s = np.asarray(model.scores(x), np.float64)
    return s[:, place_columns(model.periods, model.n)].sum(axis=1)


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    """A map fitted on a folder of 40 frames; queries: the frames brightened,
    in a second folder (names differ from the reference's)."""
    root = tmp_path_factory.mktemp("folders")
    photo = resize(skdata.astronaut(), (96, 400), anti_aliasing=True)
    frames = [(photo[:, 8 * i : 8 * i + 64] * 255).astype(np.uint8) for i in range(40)]
    for name, pics in (("ref", frames), ("qry", [np.clip(f * 0.9 + 10, 0, 255)
                                                 .astype(np.uint8) for f in frames])):
        (root / name).mkdir()
        for i, img in enumerate(pics):
            imsave(root / name / f"{name}_{i:03d}.png", img, check_contrast=False)
    assert main(["fit", str(root / "ref"), "--out", str(root / "m.map"),
                 "--no-progress"]) == 0  # fmt: skip
    return root


def test_results_per_query_on_image_folders(folders, capsys):
    root = folders
    path = root / "r.csv"
    code, out, err = run(capsys, "query", str(root / "m.map"), str(root / "qry"),
                         "--top", "3", "--json", "--csv", str(path),
                         "--no-progress")  # fmt: skip
    assert code == 0, err
    result = json.loads(out)
    model = RhythmicMap.load(root / "m.map")
    from rhythmic_jax.frames.sources import load_query_source

    x = load_query_source(str(root / "qry"), model).x
    want = model.predict(x)
    np.testing.assert_array_equal(result["predictions"], want)
    total = summed(model, x)
    conf = np.asarray(model.decode(x).confidence)
    rows = result["queries"]
    assert [r["query"] for r in rows] == [f"qry_{i:03d}.png" for i in range(40)]
    for i, r in enumerate(rows):
        assert r["place"] == want[i]
        assert r["place_name"] == (f"ref_{want[i]:03d}.png" if want[i] >= 0 else None)
        best = np.argsort(-total[i], kind="stable")[:3]
        assert [t["place"] for t in r["top"]] == best.tolist()
        assert [t["name"] for t in r["top"]] == [f"ref_{j:03d}.png" for j in best]
        np.testing.assert_allclose([t["score"] for t in r["top"]], total[i, best],
                                   rtol=1e-4, atol=1e-4)  # fmt: skip
        if want[i] >= 0:
            assert r["score"] == pytest.approx(total[i, want[i]], rel=1e-4, abs=1e-4)
        assert r["confidence"] == pytest.approx(float(conf[i]), rel=1e-5, abs=1e-6)
    assert result["ranks"] == "single-frame scores" and result["decode"] == "hard"
    table = list(csv.DictReader(io.StringIO(path.read_text())))
    assert [t["query"] for t in table] == [r["query"] for r in rows]
    assert list(table[0])[-3:] == ["top3", "top3_name", "top3_score"]
    assert [int(t["top1"]) for t in table] == [r["top"][0]["place"] for r in rows]
    assert [t["place_name"] for t in table] == [r["place_name"] or "" for r in rows]


def test_rows_of_a_npy_are_numbered_and_sequences_ranked_over_the_sequence(
    folders, capsys, tmp_path
):
    root = folders
    model = RhythmicMap.load(root / "m.map")
    from rhythmic_jax.frames.sources import load_query_source

    x = load_query_source(str(root / "qry"), model).x
    np.save(tmp_path / "q.npy", x)
    # a map of .npy rows names no places
    np.save(tmp_path / "ref.npy", x)
    assert main(["fit", str(tmp_path / "ref.npy"), "--out", str(tmp_path / "n.map"),
                 "--no-progress"]) == 0  # fmt: skip
    capsys.readouterr()
    code, out, err = run(capsys, "query", str(tmp_path / "n.map"),
                         str(tmp_path / "q.npy"), "--json", "--sequence", "4",
                         "--decode", "soft", "--no-progress")  # fmt: skip
    assert code == 0, err
    result = json.loads(out)
    rows = result["queries"]
    assert [r["query"] for r in rows] == [str(i) for i in range(40)]  # one type
    assert [r["index"] for r in rows] == list(range(40))
    assert all(r["place_name"] is None and len(r["top"]) == 5 for r in rows)
    assert result["ranks"] == "sequence scores (L=4, speed 1)"
    npy_map = RhythmicMap.load(tmp_path / "n.map")
    assert result["predictions"] == npy_map.predict(x, "soft", sequence=4).tolist()
    # a soft sequence decode picks the best accumulated place: the top-1
    assert [r["top"][0]["place"] for r in rows] == result["predictions"]


def test_top_without_json_or_csv_is_refused(folders, capsys, tmp_path):
    root = folders
    code, _, err = run(capsys, "query", str(root / "m.map"), str(root / "qry"),
                       "--top", "3")  # fmt: skip
    assert code == 2 and "--top needs --json, --csv or --pairs" in err
    assert len(err.strip().splitlines()) == 1
    code, _, err = run(capsys, "query", str(root / "m.map"), str(root / "qry"),
                       "--csv", str(tmp_path / "none" / "r.csv"))  # fmt: skip
    assert code == 2 and "--csv" in err and "not found" in err


def test_hloc_files_name_queries_and_places(capsys, tmp_path):
    """A map fitted on an hloc .h5 names its places by the file's image names,
    and queries from one are named by theirs."""
    import h5py

    rng = np.random.default_rng(1)
    walk = np.cumsum(rng.normal(size=(30, 12)), axis=0).astype(np.float32)
    walk -= walk.mean(axis=0)
    for name, rows in (("db", walk), ("q", walk + 0.1 * rng.normal(size=walk.shape))):
        with h5py.File(tmp_path / f"{name}.h5", "w") as f:  # hloc: a group per image
            for i, v in enumerate(rows):
                f.create_group(f"{name}/{i:02d}.jpg").create_dataset(
                    "global_descriptor", data=v.astype(np.float32)
                )
    assert main(["fit", str(tmp_path / "db.h5"), "--out", str(tmp_path / "m.map"),
                 "--no-progress"]) == 0  # fmt: skip
    capsys.readouterr()
    code, out, err = run(capsys, "query", str(tmp_path / "m.map"),
                         str(tmp_path / "q.h5"), "--json", "--top", "2")  # fmt: skip
    assert code == 0, err
    rows = json.loads(out)["queries"]
    assert [r["query"] for r in rows] == [f"q/{i:02d}.jpg" for i in range(30)]
    for r in rows:
        assert [t["name"] for t in r["top"]] == [f"db/{t['place']:02d}.jpg"
                                                 for t in r["top"]]  # fmt: skip
        assert r["place_name"] == (f"db/{r['place']:02d}.jpg" if r["place"] >= 0
                                   else None)  # fmt: skip
