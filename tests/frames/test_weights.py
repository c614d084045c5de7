"""Descriptor weights: found through their package or an absolute path, recorded
with their sha256, and refused in one line when the file found differs."""

from __future__ import annotations

import hashlib
import importlib.metadata
import json
import os
import shutil

import numpy as np
import pytest

from rhythmic_jax import RhythmicMap
from rhythmic_jax.app.cli import main
from rhythmic_jax.errors import InputError
from rhythmic_jax.frames.features import _cache_settings, get_descriptor
from rhythmic_jax.frames.weights import (
    LITE0_PACKAGE,
    file_record,
    file_sha256,
    packaged_path,
    packaged_record,
    resolve_weights,
)


def test_file_sha256_is_hashlib_and_follows_changes(tmp_path):
    path = tmp_path / "w.bin"
    path.write_bytes(b"a" * 3_000_000)
    assert file_sha256(path) == hashlib.sha256(b"a" * 3_000_000).hexdigest()
    path.write_bytes(b"b" * 10)
    os.utime(path, ns=(1, 1))  # another size and mtime: hashed again
    assert file_sha256(path) == hashlib.sha256(b"b" * 10).hexdigest()


def test_packaged_record_names_package_version_and_hash():
    record = packaged_record()
    path = packaged_path()
    assert record["weights"] == path.name and record["weights_package"] == LITE0_PACKAGE
    assert record["weights_version"] == importlib.metadata.version(LITE0_PACKAGE)
    assert record["weights_sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()
    # torch hub names a file by its hash prefix: efficientnet-lite0-57934424.pth
    assert path.stem.split("-")[-1] == record["weights_sha256"][:8]


def test_resolve_refuses_another_file_in_one_line(tmp_path):
    path = tmp_path / "w.pth"
    path.write_bytes(b"weights")
    record = file_record("vgg16_fc7", path)
    assert record["weights"] == str(path) and path.is_absolute()
    assert resolve_weights("vgg16_fc7", str(path), record["weights_sha256"]) == path
    path.write_bytes(b"other weights")
    with pytest.raises(InputError, match=r"^vgg16_fc7 weights .*w\.pth: sha256 ") as e:
        resolve_weights("vgg16_fc7", str(path), record["weights_sha256"])
    assert "\n" not in str(e.value) and record["weights_sha256"][:16] in str(e.value)
    path.unlink()
    with pytest.raises(
        InputError, match=r"not found: .*w\.pth; give weights PATH"
    ) as e:
        resolve_weights("vgg16_fc7", str(path), record["weights_sha256"])
    assert e.value.as_flag().endswith("; give --weights PATH of the file or a copy")


def test_lite0_settings_resolve_from_the_package_wherever_run(tmp_path, monkeypatch):
    settings = get_descriptor("efficientnet_lite0").settings()
    assert settings == {"width": 224, "height": 112, "block": 10} | packaged_record()
    monkeypatch.chdir(tmp_path)  # nowhere near the package
    again = get_descriptor("efficientnet_lite0", **settings)
    assert again._path() == packaged_path() and again.settings() == settings
    # maps written before the package was recorded name only the file
    old = {"width": 224, "height": 112, "block": 10, "weights": packaged_path().name}
    assert get_descriptor("efficientnet_lite0", **old)._path() == packaged_path()
    # the cache keeps naming the packaged file as it always did
    assert _cache_settings(again) == old
    bad = settings | {"weights_sha256": "0" * 64}
    with pytest.raises(InputError, match=r"differs from the map's 0000.*0\.1"):
        get_descriptor("efficientnet_lite0", **bad)


def _run(capsys, *argv):
    code = main([*argv])
    out, err = capsys.readouterr()
    return code, out, err


def _map(tmp_path, descriptor, settings, d):
    """A map over random d-dim features, recorded as built with ``descriptor``."""
    x = np.random.default_rng(0).normal(size=(12, d)).astype(np.float32)
    model = RhythmicMap(descriptor=descriptor, descriptor_settings=settings)
    model.fit(x / np.linalg.norm(x, axis=1, keepdims=True), progress=False)
    model.save(tmp_path / "m.map")
    return str(tmp_path / "m.map")


@pytest.fixture
def frames(tmp_path, rgb, write_image):
    for i in range(2):
        write_image(tmp_path / "q", f"{i}.png", rgb(40, 40))
    return str(tmp_path / "q")


def test_query_refuses_a_tampered_lite0_hash(tmp_path, frames, capsys):
    settings = get_descriptor("efficientnet_lite0").settings()
    settings["weights_sha256"] = "f" * 64
    path = _map(tmp_path, "efficientnet_lite0", settings, 10976)
    code, _, err = _run(capsys, "query", path, frames, "--no-progress")
    assert code == 2 and err.count("\n") == 1
    assert (
        "sha256" in err
        and "differs from the map's ffff" in err
        and LITE0_PACKAGE in err
    )


def test_vgg_weights_moved_given_again_or_replaced(
    tmp_path, frames, small_vgg16, capsys
):
    weights = small_vgg16(tmp_path / "fit" / "vgg16.pth")
    settings = get_descriptor("vgg16_fc7", weights=str(weights)).settings()
    assert settings["weights_sha256"] == file_sha256(weights)
    path = _map(tmp_path, "vgg16_fc7", settings, 4096)
    moved = shutil.move(weights, tmp_path / "vgg16_moved.pth")

    code, _, err = _run(capsys, "query", path, frames, "--no-progress")
    assert code == 2 and err.count("\n") == 1
    assert f"weights file not found: {weights}; give --weights PATH" in err

    other = small_vgg16(tmp_path / "other.pth", seed=1)
    code, _, err = _run(capsys, "query", path, frames, "--weights", str(other))
    assert code == 2 and err.count("\n") == 1 and "other.pth: sha256" in err

    code, out, err = _run(capsys, "query", path, frames, "--weights", str(moved),
                          "--json", "--no-progress")  # fmt: skip
    assert code == 0, err
    assert len(json.loads(out)["predictions"]) == 2


def test_weights_for_a_map_without_weights_is_refused(tmp_path, frames, capsys):
    settings = get_descriptor("patchnorm").settings()
    path = _map(tmp_path, "patchnorm", settings, 16)
    code, _, err = _run(capsys, "query", path, frames, "--weights", "x.pth")
    assert code == 2 and "--weights: the map's descriptor 'patchnorm' takes no" in err


def test_the_packaged_file_is_found_without_torch():
    """Where the package put the file, by the package's own path function: no
    network module (nor torch) is imported to find it, from any folder."""
    import subprocess
    import sys

    code = (
        "import sys; from rhythmic_jax.frames.weights import packaged_path; "
        "p = packaged_path(); print(p.is_file(), p.name, 'torch' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True,
                         text=True, cwd="/")  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["True", packaged_path().name, "False"]


def test_an_embedding_names_its_descriptor_and_packaged_weights_by_package():
    """fit --embedding reads images with the embedding's descriptor: packaged
    weights by their package (never the recorded file name as a path in the
    current folder), a user's file by its recorded absolute path."""
    from rhythmic_jax.map.embedding import embedding_descriptor

    packaged = {"descriptor": "efficientnet_lite0",
                "descriptor_settings": {**packaged_record(), "block": 10}}  # fmt: skip
    assert embedding_descriptor(packaged) == ("efficientnet_lite0", None)
    own = {"descriptor": "vgg16_fc7",
           "descriptor_settings": {"weights": "/data/vgg.pth", "weights_sha256": "0"}}
    assert embedding_descriptor(own) == ("vgg16_fc7", "/data/vgg.pth")
    assert embedding_descriptor({"descriptor": "features"}) == (None, None)
    assert embedding_descriptor({"descriptor": "patchnorm"}) == ("patchnorm", None)
