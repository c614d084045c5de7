"""The VPR tools' files, each written here to its documented layout, read back,
and refused in one line when malformed (truncated, wrong shapes, a pickle)."""

from __future__ import annotations

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
