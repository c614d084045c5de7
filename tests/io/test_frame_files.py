"""Frames read in blocks from .npy files and shard folders; shards written."""

import numpy as np
import pytest

from rhythmic_jax.errors import InputError
from rhythmic_jax.io.frame_files import (
    ShardWriter,
    is_frame_source,
    open_frames,
    shard_descriptor,
)


def test_shards_read_back_as_the_frames_written(tmp_path):
    x = np.random.default_rng(0).normal(size=(230, 5)).astype(np.float32)
    with ShardWriter(
        tmp_path / "s", rows=64, meta={"descriptor": "hog", "settings": {"a": 1}}
    ) as w:
        for lo in range(0, 230, 50):
            w.write(x[lo : lo + 50])
    assert (
        sorted(p.name for p in (tmp_path / "s").glob("*.npy"))[-1] == "shard-000003.npy"
    )
    frames = open_frames(tmp_path / "s")
    assert frames.shape == (230, 5) and is_frame_source(tmp_path / "s")
    np.testing.assert_array_equal(frames.read(0, 230), x)
    np.testing.assert_array_equal(frames.read(60, 70), x[60:70])  # across shards
    np.testing.assert_array_equal(
        np.concatenate(list(frames.blocks(7, 200, 33))), x[7:200]
    )
    assert shard_descriptor(tmp_path / "s") == ("hog", {"a": 1})
    np.save(tmp_path / "one.npy", x.astype(np.float64))
    both = open_frames([tmp_path / "one.npy", tmp_path / "s"])
    np.testing.assert_array_equal(
        both.read(220, 240), np.concatenate([x[220:], x[:10]])
    )


def test_bad_files_are_refused_with_their_name(tmp_path):
    x = np.ones((10, 4), np.float32)
    np.save(tmp_path / "a.npy", x)
    raw = (tmp_path / "a.npy").read_bytes()
    (tmp_path / "cut.npy").write_bytes(raw[:-8])
    with pytest.raises(InputError, match="cut.npy: truncated"):
        open_frames(tmp_path / "cut.npy")
    np.save(tmp_path / "obj.npy", np.array([{}], dtype=object), allow_pickle=True)
    with pytest.raises(InputError, match="obj.npy"):
        open_frames(tmp_path / "obj.npy")
    (tmp_path / "mix").mkdir()
    np.save(tmp_path / "mix" / "0.npy", x)
    np.save(tmp_path / "mix" / "1.npy", np.ones((3, 5), np.float32))
    with pytest.raises(InputError, match="different widths"):
        open_frames(tmp_path / "mix")
    bad = x.copy()
    bad[7, 1] = np.nan
    np.save(tmp_path / "nan.npy", bad)
    with pytest.raises(InputError, match="nan.npy rows 0..10 .*NaN"):
        open_frames(tmp_path / "nan.npy").read(0, 10)
    with pytest.raises(InputError, match="exists"):
        ShardWriter(tmp_path / "mix")


def test_a_failed_writer_leaves_no_folder(tmp_path):
    with pytest.raises(RuntimeError):
        with ShardWriter(tmp_path / "s", rows=4) as w:
            w.write(np.ones((9, 3), np.float32))
            raise RuntimeError("stop")
    assert list(tmp_path.iterdir()) == []
