"""The VPR tools' files, each written here to its documented layout, read back,
and refused in one line when malformed (truncated, wrong shapes, a pickle)."""

from __future__ import annotations

import json
import pickle
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

from rhythmic_jax.errors import InputError
from rhythmic_jax.io.vpr_files import (
    load_descriptor_file,
    read_hloc_descriptors,
    read_image_list,
    read_openvprlab_positives,
    read_patchnetvlad,
    read_vpr_tutorial,
)

RNG = np.random.default_rng(3)


def _ragged(rows) -> np.ndarray:
    out = np.empty(len(rows), dtype=object)
    for i, r in enumerate(rows):
        out[i] = np.asarray(r, np.int64)
    return out


def _truncate(path: Path, keep: float = 0.6) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])


def test_openvprlab_image_lists_resolve_against_the_root(tmp_path):
    names = np.array(["images/db/a.jpg", "images/db/b.jpg"])
    np.save(tmp_path / "nord_dbImages.npy", names)
    assert read_image_list(tmp_path / "nord_dbImages.npy") == [
        Path("images/db/a.jpg"),
        Path("images/db/b.jpg"),
    ]
    with pytest.raises(InputError, match="2 of 2 images not under"):
        read_image_list(tmp_path / "nord_dbImages.npy", tmp_path)
    for n in names:
        (tmp_path / n).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / n).write_bytes(b"")
    got = read_image_list(tmp_path / "nord_dbImages.npy", tmp_path)
    assert got == [tmp_path / n for n in names]
    np.save(tmp_path / "out_dbImages.npy", np.array(["images/db/a.jpg", "../x.jpg"]))
    with pytest.raises(InputError, match="'../x.jpg' leads outside"):
        read_image_list(tmp_path / "out_dbImages.npy", tmp_path)
    np.save(tmp_path / "bad_qImages.npy", np.zeros((2, 2)))
    with pytest.raises(InputError, match="1-d array of image paths"):
        read_image_list(tmp_path / "bad_qImages.npy")


def test_openvprlab_positives_ragged_and_rectangular(tmp_path):
    rows = [[0, 1], [5], [], [2, 3, 4]]
    path = tmp_path / "nord_gt_25m.npy"
    np.save(path, _ragged(rows), allow_pickle=True)  # as the tools write it
    got = read_openvprlab_positives(path, 6)
    assert [g.tolist() for g in got] == rows
    assert all(g.dtype == np.int64 for g in got)
    with pytest.raises(InputError, match="query 1 lists database image 5"):
        read_openvprlab_positives(path, 5)
    square = np.array([[0, 1], [2, 3]])
    np.save(path, square)
    assert [g.tolist() for g in read_openvprlab_positives(path)] == square.tolist()


def test_openvprlab_refuses_other_objects_truncation_and_shapes(tmp_path):
    path = tmp_path / "x_gt_25m.npy"
    np.save(path, np.array([Fraction(1, 2), 3], dtype=object), allow_pickle=True)
    with pytest.raises(InputError, match="refused: the pickle names fractions"):
        read_openvprlab_positives(path)
    np.save(path, np.array([[1, 2], "a"], dtype=object), allow_pickle=True)
    with pytest.raises(InputError, match="query 0 holds list"):
        read_openvprlab_positives(path)
    np.save(path, _ragged([[0, 1], [2]]), allow_pickle=True)
    _truncate(path)
    with pytest.raises(InputError, match="unreadable object array"):
        read_openvprlab_positives(path)
    np.save(path, np.zeros(4, np.float32))
    with pytest.raises(InputError, match=r"\(b, k\) integers"):
        read_openvprlab_positives(path)
    # a pickle whose payload would run code: refused before anything is called
    with path.open("wb") as f:
        np.lib.format.write_array_header_1_0(
            f, {"descr": "|O", "fortran_order": False, "shape": (1,)}
        )
        f.write(pickle.dumps(_Boom()))
    with pytest.raises(InputError, match="refused: the pickle names"):
        read_openvprlab_positives(path)


class _Boom:
    def __reduce__(self):
        return (print, ("never printed",))


def test_vpr_tutorial_gt(tmp_path):
    hard = RNG.random((7, 5)) < 0.3
    soft = hard | (RNG.random((7, 5)) < 0.3)
    path = tmp_path / "GT.npz"
    np.savez(path, GThard=hard, GTsoft=soft)
    h, s = read_vpr_tutorial(path)
    np.testing.assert_array_equal(h, hard)
    np.testing.assert_array_equal(s, soft)
    np.savez(path, GThard=hard, GTsoft=soft[:, :4])
    with pytest.raises(InputError, match=r"GThard is \(7, 5\) but GTsoft is \(7, 4\)"):
        read_vpr_tutorial(path)
    np.savez(path, GThard=hard)
    with pytest.raises(InputError, match="no array 'GTsoft'"):
        read_vpr_tutorial(path)
    np.savez(path, GThard=np.array([[1, None]], object), GTsoft=soft)
    with pytest.raises(InputError, match="refused: holds Python objects"):
        read_vpr_tutorial(path)
    np.savez(path, GThard=hard, GTsoft=soft)
    _truncate(path)
    with pytest.raises(InputError, match="not a readable .npz"):
        read_vpr_tutorial(path)


def test_patchnetvlad_gt(tmp_path):
    db, q = RNG.uniform(0, 100, (9, 2)), RNG.uniform(0, 100, (4, 2))
    path = tmp_path / "nordland.npz"
    np.savez(path, utmQ=q, utmDb=db, posDistThr=25)
    got_db, got_q, thr = read_patchnetvlad(path)
    np.testing.assert_array_equal(got_db, db)
    np.testing.assert_array_equal(got_q, q)
    assert thr == 25.0
    np.savez(path, utmQ=q[:, :1], utmDb=db, posDistThr=25)
    with pytest.raises(InputError, match=r"utmQ must be \(n, 2\)"):
        read_patchnetvlad(path)
    np.savez(path, utmQ=q, utmDb=db, posDistThr=-1.0)
    with pytest.raises(InputError, match="posDistThr must be one positive"):
        read_patchnetvlad(path)


def _write_hloc(path: Path, feats: dict[str, np.ndarray]) -> None:
    import h5py

    with h5py.File(path, "w") as f:  # hloc: one group per image name
        for name, v in feats.items():
            f.create_group(name).create_dataset("global_descriptor", data=v)


def test_hloc_global_features(tmp_path):
    names = [f"db/frame_{i:03d}.jpg" for i in range(6)]
    x = RNG.standard_normal((6, 16)).astype(np.float16)
    path = tmp_path / "global-feats-netvlad.h5"
    _write_hloc(path, dict(zip(reversed(names), x[::-1], strict=True)))
    got_names, got = read_hloc_descriptors(path)
    assert got_names == names
    np.testing.assert_array_equal(got, x.astype(np.float32))
    np.testing.assert_array_equal(load_descriptor_file(path), got)
    _write_hloc(path, {"a.jpg": np.zeros(4), "b.jpg": np.zeros(5)})
    with pytest.raises(InputError, match="must all be"):
        read_hloc_descriptors(path)
    _write_hloc(path, dict(zip(names, x, strict=True)))
    _truncate(path, 0.3)
    with pytest.raises(InputError, match="not a readable HDF5 file"):
        read_hloc_descriptors(path)
    path.write_bytes(pickle.dumps({"global_descriptor": [1.0]}))
    with pytest.raises(InputError, match="not a readable HDF5 file"):
        read_hloc_descriptors(path)


def test_hloc_file_is_a_descriptor_source(tmp_path):
    """``fit``, ``query`` and ``evaluate`` read an hloc .h5 as they read a .npy."""
    from rhythmic_jax.frames.sources import load_sources

    x = RNG.standard_normal((8, 6)).astype(np.float32)
    path = tmp_path / "global-feats-cosplace.h5"
    _write_hloc(path, {f"r/{i:02d}.png": v for i, v in enumerate(x)})
    np.save(tmp_path / "same.npy", x)
    h5, npy = load_sources([str(path)]), load_sources([str(tmp_path / "same.npy")])
    np.testing.assert_array_equal(h5.x, npy.x)
    assert h5.settings == npy.settings == {"dim": 6}
    (tmp_path / "feats.txt").write_text("1 2 3")
    with pytest.raises(
        InputError, match="not a .npy descriptor file.*.h5 descriptor files are read"
    ):
        load_sources([str(tmp_path / "feats.txt")])


# --------------------------------------------- hloc's own layout, hloc's order


def _write_hloc_as_hloc(path: Path, names: list[str], x: np.ndarray) -> None:
    """As hloc's ``extract_features`` writes a global descriptor: one group per
    image name (nested where the name has ``/``), ``global_descriptor`` float16
    (``as_half``) and ``image_size`` beside it, images in the alphabetical order
    of its sorted glob."""
    import h5py

    order = sorted(range(len(names)), key=lambda i: names[i])
    with h5py.File(path, "w", libver="latest") as f:
        for i in order:
            group = f.create_group(names[i])
            group.create_dataset("global_descriptor", data=x[i].astype(np.float16))
            group.create_dataset("image_size", data=np.array([64, 32]))


def _frames(folder: Path, n: int, rng) -> None:
    """``n`` smooth random frames ``frame1.png`` .. ``frame{n}.png``, unpadded."""
    import skimage.io
    from skimage.transform import resize

    folder.mkdir(parents=True)
    for i in range(n):
        low = rng.uniform(0, 1, (4, 8, 3))
        image = (resize(low, (32, 64), order=1) * 255).astype(np.uint8)
        skimage.io.imsave(folder / f"frame{i + 1}.png", image, check_contrast=False)


def test_hloc_names_are_read_in_the_order_of_an_image_folder(tmp_path):
    """Unpadded names (frame1, frame2, ..., frame10, frame12): the .h5 of a folder's
    frames has its rows in the folder's order, and a map fitted on either side
    recognises every frame of the other (R@1 1.0 both ways)."""
    from rhythmic_jax.app import jobs
    from rhythmic_jax.app.specs import FitJob, QueryJob
    from rhythmic_jax.frames.sources import load_sources

    n, rng = 12, np.random.default_rng(5)
    _frames(tmp_path / "frames", n, rng)
    folder = load_sources([str(tmp_path / "frames")], "patchnorm", progress=False)
    names = [f"frame{i + 1}.png" for i in range(n)]
    h5 = tmp_path / "global-feats.h5"
    _write_hloc_as_hloc(h5, names, folder.x)
    got_names, got = read_hloc_descriptors(h5)
    assert got_names == names  # not frame1, frame10, frame11, frame12, frame2, ...
    assert sorted(names) != names  # alphabetical order would shift the rows
    np.testing.assert_allclose(got, folder.x, atol=2e-3)  # float16 as written
    np.save(tmp_path / "folder.npy", folder.x)

    jobs.fit(FitJob((str(tmp_path / "frames"),), str(tmp_path / "folder.map")))
    pred = jobs.query(QueryJob(str(tmp_path / "folder.map"), str(h5)))
    np.testing.assert_array_equal(pred, np.arange(n))
    jobs.fit(FitJob((str(h5),), str(tmp_path / "h5.map")))
    pred = jobs.query(QueryJob(str(tmp_path / "h5.map"), str(tmp_path / "folder.npy")))
    np.testing.assert_array_equal(pred, np.arange(n))


def test_select_splits_one_hloc_file_into_database_and_queries(tmp_path):
    """hloc's single file (``db/`` and ``query/`` names, as ``pairs_from_retrieval``
    picks them with ``db_prefix``/``query_prefix``): ``select`` fits the map on the
    database rows only and queries with the query rows; brute force reads the
    map's own prefix again."""
    from rhythmic_jax.app import jobs
    from rhythmic_jax.app.specs import EvaluateJob, FitJob, QueryJob, Reading

    n, d = 11, 24
    db = RNG.standard_normal((n, d)).astype(np.float32)
    q = db + 0.05 * RNG.standard_normal((n, d)).astype(np.float32)
    names = [f"db/frame{i + 1}.jpg" for i in range(n)]
    names += [f"query/night/frame{i + 1}.jpg" for i in range(n)]
    path = tmp_path / "global-feats-netvlad.h5"
    _write_hloc_as_hloc(path, names, np.concatenate([db, q]))
    got_names, got = read_hloc_descriptors(path, "query/")
    assert got_names == names[n:]
    np.testing.assert_allclose(got, q, atol=2e-2)
    assert read_hloc_descriptors(path)[1].shape == (2 * n, d)  # whole without one

    out = str(tmp_path / "route.map")
    model = jobs.fit(FitJob((str(path),), out, reading=Reading(select="db/")))
    assert model.n == n and model.reference["select"] == "db/"
    pred = jobs.query(QueryJob(out, str(path), reading=Reading(select="query/")))
    np.testing.assert_array_equal(pred, np.arange(n))
    result = jobs.evaluate(
        EvaluateJob(out, str(path), reading=Reading(select="query/"))
    )
    assert result["n_queries"] == n
    assert result["methods"]["brute force"]["recall@1"] == 1.0
    assert result["reference_note"] == f"brute force over the map's reference {path}"
    with pytest.raises(InputError, match="with 'q/'; the names start with db/, query/"):
        read_hloc_descriptors(path, "q/")
    with pytest.raises(InputError, match="select.*hloc .h5"):
        FitJob(("a.npy",), out, reading=Reading(select="db/"))


def test_select_on_the_command_line(tmp_path, capsys):
    """``--select`` on fit, query and frontier; a prefix selecting nothing is one
    line (exit 2) naming the prefixes present; a .npy source refuses it."""
    from rhythmic_jax.app.cli import main

    n, d = 10, 16
    db = RNG.standard_normal((n, d)).astype(np.float32)
    names = [f"{part}/{i + 1}.jpg" for part in ("db", "query") for i in range(n)]
    path = tmp_path / "feats.h5"
    _write_hloc_as_hloc(path, names, np.concatenate([db, db]))
    out = str(tmp_path / "m.map")
    assert main(["fit", str(path), "--select", "db/", "--out", out, "--json"]) == 0
    capsys.readouterr()
    assert main(["query", out, str(path), "--select", "query/", "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    assert got["predictions"] == list(range(n))
    assert [q["query"] for q in got["queries"]] == names[n:]  # in natural order
    assert [q["place_name"] for q in got["queries"]] == names[:n]  # the map's rows
    assert main(["query", out, str(path), "--select", "night/"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no image name starts with 'night/'" in err[0]
    assert "db/, query/" in err[0]
    np.save(tmp_path / "q.npy", db)
    assert main(["query", out, str(tmp_path / "q.npy"), "--select", "query/"]) == 2
    assert "--select picks the images of hloc .h5 files" in capsys.readouterr().err
    argv = ["frontier", str(path), str(path), "--select", "db/", "query/", "--maps",
            "2:1", "--bits", "32", "--pq", "", "--lengths", "1", "--json",
            "--no-progress"]  # fmt: skip
    assert main(argv) == 0
    result = json.loads(capsys.readouterr().out)
    assert (result["n"], result["n_queries"]) == (n, n)
    brute = next(r for r in result["rows"] if r["kind"] == "brute force")
    assert brute["recall@1 L=1"] == 1.0
