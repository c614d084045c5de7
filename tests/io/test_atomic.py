"""The one atomic writer: whole files or nothing, plain-open permissions."""

from __future__ import annotations

import os

import numpy as np
import pytest

from rhythmic_jax.io.atomic import atomic_path, save_npy, write_file


def test_write_file_replaces_whole_and_leaves_no_temporary(tmp_path):
    path = tmp_path / "sub" / "report.md"
    write_file(path, "first\n")
    write_file(path, "second\n")
    assert path.read_text() == "second\n"
    write_file(path, b"\x00\x01")
    assert path.read_bytes() == b"\x00\x01"
    assert sorted(p.name for p in path.parent.iterdir()) == ["report.md"]


def test_permissions_follow_the_umask(tmp_path):
    old = os.umask(0o022)
    try:
        write_file(tmp_path / "a.txt", "x")
    finally:
        os.umask(old)
    assert (tmp_path / "a.txt").stat().st_mode & 0o777 == 0o644


def test_a_failed_write_keeps_the_previous_content(tmp_path):
    path = tmp_path / "x.npy"
    save_npy(path, np.arange(3))
    with pytest.raises(RuntimeError, match="on purpose"):
        with atomic_path(path) as tmp:
            tmp.write_bytes(b"half")
            raise RuntimeError("on purpose")
    np.testing.assert_array_equal(np.load(path), np.arange(3))
    assert [p.name for p in tmp_path.iterdir()] == ["x.npy"]


def test_save_npy_refuses_objects(tmp_path):
    with pytest.raises(ValueError):
        save_npy(tmp_path / "o.npy", np.array([{}], dtype=object))
    assert not any(tmp_path.iterdir())
