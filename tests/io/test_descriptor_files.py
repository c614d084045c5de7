"""Descriptor files: round trips, refusals, atomic saves."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from rhythmic_jax.errors import InputError
from rhythmic_jax.io.descriptor_files import (
    descriptor_shape,
    load_descriptors,
    save_descriptors,
)

RNG = np.random.default_rng(0)


def test_descriptors_round_trip(tmp_path):
    x = RNG.standard_normal((7, 5))
    save_descriptors(tmp_path / "d.npy", x)
    y = load_descriptors(tmp_path / "d.npy")
    assert y.dtype == np.float32 and y.shape == (7, 5)
    np.testing.assert_array_equal(y, x.astype(np.float32))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.npy"]


def test_descriptors_refuse_bad_files(tmp_path):
    objects = tmp_path / "objects.npy"
    np.save(objects, np.array([{"a": 1}, None], dtype=object), allow_pickle=True)
    with pytest.raises(InputError, match="contains Python objects; refusing"):
        load_descriptors(objects)
    pickled = tmp_path / "pickled.npy"
    pickled.write_bytes(pickle.dumps(np.zeros((2, 2))))
    with pytest.raises(InputError, match="contains Python objects; refusing"):
        load_descriptors(pickled)
    junk = tmp_path / "junk.npy"
    junk.write_bytes(b"hello world, this is not numpy")
    with pytest.raises(InputError, match="not a valid .npy"):
        load_descriptors(junk)
    full = tmp_path / "full.npy"
    np.save(full, np.ones((50, 8), np.float32))
    cut = tmp_path / "cut.npy"
    cut.write_bytes(full.read_bytes()[:300])
    with pytest.raises(InputError, match="not a valid .npy"):
        load_descriptors(cut)
    cases = {
        "flat.npy": np.ones(4),
        "empty.npy": np.ones((0, 3)),
        "text.npy": np.array([["a", "b"]]),
    }
    for name, array in cases.items():
        np.save(tmp_path / name, array)
        with pytest.raises(InputError, match=name):
            load_descriptors(tmp_path / name)
    with pytest.raises(InputError, match="must be .npy"):
        load_descriptors(tmp_path / "d.npz")
    with pytest.raises(InputError, match="not found"):
        load_descriptors(tmp_path / "missing.npy")


def test_descriptors_non_finite_rows(tmp_path):
    x = np.ones((6, 3))
    x[3, 1], x[5, 0] = np.nan, np.inf
    np.save(tmp_path / "nan.npy", x)
    with pytest.raises(InputError, match="row 3 holds NaN or inf"):
        load_descriptors(tmp_path / "nan.npy")
    big = np.ones((2, 2))
    big[1, 1] = 1e300  # overflows float32
    np.save(tmp_path / "big.npy", big)
    with pytest.raises(InputError, match="row 1"):
        load_descriptors(tmp_path / "big.npy")


def test_failed_save_leaves_old_file(tmp_path):
    target = tmp_path / "d.npy"
    save_descriptors(target, np.ones((2, 2)))
    before = target.read_bytes()
    with pytest.raises(InputError, match="row 0"):
        save_descriptors(target, np.full((2, 2), np.nan))
    assert target.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.npy"]


def test_shape_comes_from_the_header_alone(tmp_path):
    x = RNG.standard_normal((6, 3)).astype(np.float32)
    save_descriptors(tmp_path / "d.npy", x)
    assert descriptor_shape(tmp_path / "d.npy") == (6, 3)
    header = {"descr": "<f4", "fortran_order": False, "shape": (10**9, 512)}
    with open(tmp_path / "huge.npy", "wb") as f:  # the header, no data behind it
        np.lib.format.write_array_header_1_0(f, header)
    assert descriptor_shape(tmp_path / "huge.npy") == (10**9, 512)
    with pytest.raises(InputError, match="not a valid .npy file"):
        load_descriptors(tmp_path / "huge.npy")
    (tmp_path / "obj.npy").write_bytes(pickle.dumps([1, 2]))
    with pytest.raises(InputError, match="Python objects; refusing to unpickle"):
        descriptor_shape(tmp_path / "obj.npy")


def test_a_described_file_and_its_record_stay_paired(tmp_path):
    """save_described writes the .npy and its record (rows, dimension and the
    file's sha256, checked against hashlib); a record whose file was since
    rewritten, or a JSON file that is no record, is refused in one line; a
    file without one has none."""
    import hashlib
    import json

    from rhythmic_jax.errors import InputError
    from rhythmic_jax.io.descriptor_files import (
        read_record,
        record_path,
        save_described,
    )

    x = np.arange(12, dtype=np.float32).reshape(3, 4)
    path = tmp_path / "ref.npy"
    save_described(path, x, {"descriptor": "patchnorm", "settings": {"width": 64}})
    record = read_record(path)
    assert record_path(path) == tmp_path / "ref.npy.json"
    assert (record["rows"], record["dim"], record["descriptor"]) == (3, 4, "patchnorm")
    assert record["sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()
    np.save(path, x[::-1].copy())  # same shape, other rows: not its record
    with pytest.raises(InputError, match="the record of another file"):
        read_record(path)
    save_described(path, x[:2], {"descriptor": "hog", "settings": {}})
    assert read_record(path)["rows"] == 2  # the old record replaced
    record_path(path).write_text(json.dumps({"format": "something else"}))
    with pytest.raises(InputError, match="not a descriptor record"):
        read_record(path)
    np.save(tmp_path / "plain.npy", x)
    assert read_record(tmp_path / "plain.npy") is None


def test_frame_names_of_a_folder_a_record_and_neither(tmp_path):
    from rhythmic_jax.io.descriptor_files import frame_names, save_described

    folder = tmp_path / "route"
    folder.mkdir()
    for name in ("img10.png", "img2.png", "img1.png"):
        (folder / name).write_bytes(b"")
    assert frame_names(folder, "reference") == ["img1.png", "img2.png", "img10.png"]
    x = np.ones((3, 4), np.float32)
    record = dict(
        descriptor="patchnorm", settings={}, frames=["b.png", "a.png", "c.png"]
    )
    save_described(tmp_path / "d.npy", x, record)
    assert frame_names(tmp_path / "d.npy", "query") == ["b.png", "a.png", "c.png"]
    np.save(tmp_path / "bare.npy", x)
    for path in (tmp_path / "bare.npy", tmp_path / "missing"):
        with pytest.raises(InputError, match=r"^query .*: no frame names to read"):
            frame_names(path, "query")
