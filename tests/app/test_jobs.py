"""Jobs: the command line's policy as library calls (provenance, checks, files)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import numpy as np
import pytest

from rhythmic_jax import BruteForce, InputError, MapConfig, RhythmicMap
from rhythmic_jax.app import jobs
from rhythmic_jax.app.jobs import FitJob, Reading, _check_sources_memory


@pytest.fixture(scope="module")
def route(tmp_path_factory):
    folder = tmp_path_factory.mktemp("route")
    rng = np.random.default_rng(0)
    x = rng.standard_normal((90, 12)).astype(np.float32)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    q = x + 0.05 * rng.standard_normal(x.shape).astype(np.float32)
    np.save(folder / "ref.npy", x)
    np.save(folder / "qry.npy", q)
    model = jobs.fit(FitJob((str(folder / "ref.npy"),), str(folder / "m.map")), False)
    return folder, x, q, model


def test_fit_saves_the_map_with_its_provenance(route):
    folder, x, _, model = route
    loaded = RhythmicMap.load(folder / "m.map")
    assert (
        loaded.periods == model.periods == RhythmicMap().fit(x, progress=False).periods
    )
    assert loaded.reference == {
        "sources": [str((folder / "ref.npy").absolute())],
        "tile": None,
        "stride": None,
    }
    assert jobs.info(str(folder / "m.map")) == loaded.info()
    line = jobs.fit_summary("m.map", loaded.info())
    assert line.startswith(f"map m.map: n=90 d=12 periods {loaded.periods}")


def test_query_writes_what_the_map_predicts(route, tmp_path):
    folder, _, q, model = route
    out = tmp_path / "pred.npy"
    pred = jobs.query(str(folder / "m.map"), str(folder / "qry.npy"), out=str(out))
    np.testing.assert_array_equal(pred, model.predict(q))
    np.testing.assert_array_equal(np.load(out), pred)
    assert jobs.query_summary(pred, "p.npy").endswith("no match) -> p.npy")


def test_evaluate_finds_the_reference_again_for_brute_force(route):
    folder, x, q, _ = route
    result = jobs.evaluate(str(folder / "m.map"), str(folder / "qry.npy"))
    want = BruteForce().fit(x).search(q, 1)[1][:, 0]
    brute = result["methods"]["brute force"]["accuracy"]
    assert brute == pytest.approx(float((want == np.arange(90)).mean()))
    assert str((folder / "ref.npy").absolute()) in result["reference_note"]
    assert jobs.evaluate_summary(result).endswith(result["reference_note"])


def test_option_checks_name_parameters_and_run_before_any_work(route, tmp_path):
    folder = route[0]
    ref = (str(folder / "ref.npy"),)
    cases = [
        (dict(augment="all", pca=4), "augment and pca together"),
        (dict(augment="all", epochs=0), "^epochs must be >= 1, got 0$"),
        (dict(augment="all"), "augment needs image sources .folders or tile., not"),
    ]
    for extra, match in cases:
        job = FitJob(ref, str(tmp_path / "x.map"), **extra)
        with pytest.raises(InputError, match=match) as err:
            jobs.fit(job, progress=False)
        assert "--" in err.value.as_flag()
    assert not (tmp_path / "x.map").exists()
    with pytest.raises(InputError, match="^out .*: folder .* not found$"):
        jobs.query(str(folder / "m.map"), ref[0], out=str(tmp_path / "no" / "p.npy"))
    with pytest.raises(InputError, match="tile cuts one large image"):
        jobs.query(str(folder / "m.map"), ref[0], reading=Reading(tile=8))


def test_info_reads_the_metadata_alone_and_says_what_load_says(route, tmp_path):
    folder = route[0]
    path = str(folder / "m.map")
    assert jobs.info(path) == RhythmicMap.load(path).info()
    code = (
        "import sys; from rhythmic_jax.app import jobs; "
        f"jobs.info({path!r}); print('jax' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "False"
    broken = tmp_path / "broken.map"
    shutil.copytree(path, broken)
    meta = json.loads((broken / "map.json").read_text())
    (broken / "map.json").write_text(json.dumps({**meta, "periods": [5, 6]}))
    with pytest.raises(InputError, match="do not fit periods"):
        jobs.info(str(broken))
    shutil.rmtree(broken / "arrays")
    (broken / "map.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match="arrays are missing or corrupt"):
        jobs.info(str(broken))


def test_descriptor_files_too_large_are_refused_from_the_header(tmp_path):
    header = {"descr": "<f4", "fortran_order": False, "shape": (10**8, 2048)}
    with open(tmp_path / "huge.npy", "wb") as f:
        np.lib.format.write_array_header_1_0(f, header)
    with pytest.raises(InputError, match="needs about .* stream the frames instead"):
        _check_sources_memory(
            [str(tmp_path / "huge.npy")], MapConfig(r=2, level=1, count=7)
        )
    np.save(tmp_path / "small.npy", np.zeros((100, 8), np.float32))
    _check_sources_memory(
        [str(tmp_path / "small.npy")], MapConfig(r=2, level=1, count=7)
    )  # fits
    _check_sources_memory(
        [str(tmp_path / "absent.npy")], MapConfig(r=2, level=1, count=7)
    )  # left to the read
    _check_sources_memory(
        [str(tmp_path / "small.npy")], MapConfig(r=1, level=1, count=7)
    )  # left to the map


def test_the_descriptor_is_resolved_once_and_carried_to_the_augmented_fit(
    tmp_path, monkeypatch
):
    from skimage.io import imsave

    from rhythmic_jax.augment import stream
    from rhythmic_jax.frames import features

    rng = np.random.default_rng(1)
    sources = []
    for name in ("summer", "winter"):
        (tmp_path / name).mkdir()
        for i in range(12):
            pixels = rng.integers(0, 256, (16, 32, 3), dtype=np.uint8)
            imsave(tmp_path / name / f"f{i}.png", pixels, check_contrast=False)
        sources.append(str(tmp_path / name))
    resolved = []

    def counted(name, **settings):
        resolved.append(features.DESCRIPTORS[name](**settings))
        return resolved[-1]

    seen = {}

    def augmented(model, images, x, descriptor, config, labels, **kw):
        seen["descriptor"] = descriptor.descriptor
        return model.fit(x, labels, progress=False)

    monkeypatch.setattr(features, "get_descriptor", counted)
    monkeypatch.setattr(stream, "fit_map_augmented", augmented)
    job = FitJob(tuple(sources), str(tmp_path / "m.map"), augment="all")
    model = jobs.fit(job, progress=False)
    assert len(resolved) == 1 and seen["descriptor"] is resolved[0]
    saved = RhythmicMap.load(tmp_path / "m.map").config
    assert saved.descriptor == model.config.descriptor == "patchnorm"
    assert saved.descriptor_settings == resolved[0].settings()
