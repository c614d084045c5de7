"""Jobs: the command line's policy as library calls (provenance, checks, files)."""

from __future__ import annotations

import hashlib
import json
import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from rhythmic_jax import BruteForce, InputError, MapConfig, RhythmicMap
from rhythmic_jax.app import jobs, render
from rhythmic_jax.app.jobs import _before_reading
from rhythmic_jax.app.options import OptionRefused
from rhythmic_jax.app.specs import EvaluateJob, FitJob, QueryJob, Reading
from rhythmic_jax.frames.compile_policy import CompilePolicy


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
    rows = np.ascontiguousarray(x, np.float32)  # the frames' digest, by hand
    digest = hashlib.sha256(repr(rows.shape).encode() + rows.tobytes()).hexdigest()
    assert loaded.reference == {
        "sources": [str((folder / "ref.npy").absolute())],
        "tile": None,
        "stride": None,
        "frames_sha256": digest,
    }
    checked = {"checksums": "sha256 of every stored array, checked"}
    assert jobs.info(str(folder / "m.map")) == loaded.info() | checked
    line = render.fit_summary("m.map", loaded.info())
    assert line.startswith(f"map m.map: n=90 d=12 periods {loaded.periods}")


def test_query_writes_what_the_map_predicts(route, tmp_path):
    folder, _, q, model = route
    out = tmp_path / "pred.npy"
    job = QueryJob(str(folder / "m.map"), str(folder / "qry.npy"), out=str(out))
    pred = jobs.query(job)
    np.testing.assert_array_equal(pred, model.predict(q))
    np.testing.assert_array_equal(np.load(out), pred)
    assert render.query_summary(pred, "p.npy").endswith("no match) -> p.npy")


def test_evaluate_finds_the_reference_again_for_brute_force(route):
    folder, x, q, _ = route
    result = jobs.evaluate(EvaluateJob(str(folder / "m.map"), str(folder / "qry.npy")))
    want = BruteForce().fit(x).search(q, 1)[1][:, 0]
    brute = result["methods"]["brute force"]["accuracy"]
    assert brute == pytest.approx(float((want == np.arange(90)).mean()))
    assert str((folder / "ref.npy").absolute()) in result["reference_note"]
    assert render.evaluate_summary(result).endswith(result["reference_note"])


def test_option_checks_name_parameters_and_run_before_any_work(route, tmp_path):
    folder = route[0]
    ref = (str(folder / "ref.npy"),)
    cases = [
        (dict(augment="all", pca=4), "augment and pca together"),
        (dict(augment="all", epochs=0), "^epochs must be an integer >= 1, got 0$"),
        (dict(augment="all"), "augment needs image sources .folders or tile., not"),
    ]
    for extra, match in cases:
        with pytest.raises(InputError, match=match) as err:
            jobs.fit(FitJob(ref, str(tmp_path / "x.map"), **extra), progress=False)
        assert "--" in err.value.as_flag()
    assert not (tmp_path / "x.map").exists()
    with pytest.raises(InputError, match="tile cuts one large image"):
        jobs.query(QueryJob(str(folder / "m.map"), ref[0], reading=Reading(tile=8)))


def test_info_reads_the_metadata_alone_and_says_what_load_says(route, tmp_path):
    folder = route[0]
    path = str(folder / "m.map")
    checked = {"checksums": "sha256 of every stored array, checked"}
    assert jobs.info(path) == RhythmicMap.load(path).info() | checked
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
    out = str(tmp_path / "m.map")
    huge = FitJob((str(tmp_path / "huge.npy"),), out)
    with pytest.raises(InputError, match="needs about .* stream the frames instead"):
        _before_reading(huge)
    np.save(tmp_path / "small.npy", np.zeros((100, 8), np.float32))
    two = FitJob((str(tmp_path / "small.npy"),) * 2, out)
    planned = _before_reading(two).plan  # fits
    assert (planned.n, planned.d) == (100, 8)
    np.save(tmp_path / "xy.npy", np.arange(200.0).reshape(100, 2))
    located = (str(tmp_path / "xy.npy"),) * 2
    for left in (  # to the read: absent, projected, grouped into places
        FitJob((str(tmp_path / "absent.npy"),), out),
        FitJob(two.sources, out, pca=4),
        FitJob(two.sources, out, positions=located, places=5),
    ):
        assert _before_reading(left).plan is None


def test_positions_and_places_are_settled_before_the_frames_are_read(tmp_path):
    """k-means over the positions runs (and is refused) before any frame is
    read; one position a frame is checked once the frames are read."""
    np.save(tmp_path / "ref.npy", np.zeros((100, 8), np.float32))
    np.save(tmp_path / "xy.npy", np.arange(200.0).reshape(100, 2))
    np.save(tmp_path / "short.npy", np.arange(198.0).reshape(99, 2))
    out = str(tmp_path / "m.map")
    absent = FitJob((str(tmp_path / "absent.npy"),), out,
                    positions=(str(tmp_path / "xy.npy"),), places=101)  # fmt: skip
    with pytest.raises(InputError, match=r"k must be an integer in \[1, 100\]"):
        _before_reading(absent)  # the source is never looked at
    labels, kept = _before_reading(replace(absent, places=4)).placed
    assert labels.shape == (100,) and set(labels.tolist()) == {0, 1, 2, 3}
    assert kept["reference_positions"].shape == (100, 2)
    short = FitJob((str(tmp_path / "ref.npy"),), out,
                   positions=(str(tmp_path / "short.npy"),))  # fmt: skip
    with pytest.raises(InputError, match="99 positions for 100 reference frames"):
        jobs.fit(short)
    assert not Path(out).exists()


@pytest.mark.parametrize("kind", ["npy", "images"])
def test_a_fit_is_planned_once(kind, tmp_path, monkeypatch):
    """From descriptor files' headers before they are read, or from the frames
    once images are described: one plan, which the map's fit takes as it is."""
    from skimage.io import imsave

    from rhythmic_jax.fitting import fit_plan

    rng = np.random.default_rng(2)
    if kind == "npy":
        source = str(tmp_path / "ref.npy")
        np.save(source, rng.normal(size=(30, 8)).astype(np.float32))
    else:
        source = str(tmp_path / "frames")
        (tmp_path / "frames").mkdir()
        for i in range(30):
            pixels = rng.integers(0, 256, (16, 32, 3), dtype=np.uint8)
            imsave(tmp_path / "frames" / f"f{i}.png", pixels, check_contrast=False)
    from rhythmic_jax.fitting import fit_map as fit_module

    made = []

    def counted(*args):
        made.append(plan(*args))
        return made[-1]

    plan = fit_plan.plan
    monkeypatch.setattr(fit_plan, "plan", counted)
    monkeypatch.setattr(fit_module, "plan_fit", counted)
    model = jobs.fit(FitJob((source,), str(tmp_path / "m.map")))
    assert len(made) == 1 and (made[0].n, made[0].d) == (30, model.d)
    assert set(model.periods) <= set(made[0].candidates)


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

    def refining(images, x, labels, descriptor, config, **kw):
        seen["descriptor"] = descriptor.descriptor
        return None  # the plain fit's

    monkeypatch.setattr(features, "get_descriptor", counted)
    monkeypatch.setattr(stream, "refining", refining)
    job = FitJob(tuple(sources), str(tmp_path / "m.map"), augment="all")
    model = jobs.fit(job, progress=False)
    assert len(resolved) == 1 and seen["descriptor"] is resolved[0]
    saved = RhythmicMap.load(tmp_path / "m.map").config
    assert saved.descriptor == model.config.descriptor == "patchnorm"
    assert saved.descriptor_settings == resolved[0].settings()


def test_a_job_checks_its_rules_when_made():
    """The rules the command line reports are the job's: a setting away from its
    default where it has no effect is refused when the job is made, one given
    explicitly (``given``) even at its default; warning rules only warn."""
    with pytest.raises(OptionRefused, match="^epochs needs augment .it shapes"):
        FitJob(("a.npy",), "m.map", epochs=5)
    FitJob(("a.npy",), "m.map", epochs=5, augment="all")
    with pytest.raises(OptionRefused, match="^r acts only with a layout that"):
        FitJob(("a.npy",), "m.map", config=MapConfig(layout="mixed:8,8"), given={"r"})
    FitJob(("a.npy",), "m.map", config=MapConfig(layout="mixed:8,8"))  # r default
    with pytest.raises(OptionRefused, match="^stride needs tile"):
        QueryJob("m.map", "q", reading=Reading(stride=4))
    with pytest.raises(OptionRefused, match="^tolerance_m needs ground_truth"):
        EvaluateJob("m.map", "q.npy", tolerance_m=10.0)
    with pytest.raises(InputError, match="^places must be an integer >= 1, got 0"):
        FitJob(("a.npy",), "m.map", places=0, positions=("names",))
    policy = CompilePolicy("never", 5)
    job = QueryJob("m.map", "q.npy", reading=Reading(compile=policy))
    assert [InputError(w).as_flag() for w in job.warnings] == [
        "--compile-min-frames acts only with --compile auto; ignored",
        "--compile applies to images; .npy files are descriptors; ignored",
    ]


def _info_rows(text: str) -> list[tuple[str, str]]:
    return [tuple(s.strip() for s in line.split(": ", 1)) for line in text.split("\n")]


@pytest.mark.parametrize("codes", [None, "int8", 32])
def test_info_lines_state_units_per_place_per_period_and_c(tmp_path, codes):
    """per place is one place's bytes; one line per period with its templates'
    bytes and training error; C named as log N; ratios rounded; the compile
    options of the backend in use only, all recomputed from the map."""
    import math

    import jax

    from rhythmic_jax.jit_options import describe
    rng = np.random.default_rng(1)
    x = rng.standard_normal((500, 32)).astype(np.float32)
    model = RhythmicMap(r=2, level=1, codes=codes).fit(x)
    model.save(str(tmp_path / "m.map"))
    info = jobs.info(str(tmp_path / "m.map"))
    rows = _info_rows(render.info_lines(info))
    names = [name for name, _ in rows]
    assert len(names) == len(set(names))  # one line per period, no repeats
    got = dict(rows)
    each = {None: 0, "int8": 32, 32: 4}[codes]  # bytes of one place's code
    if each:
        assert got["per place"] == (f"{each} B (codes; {500 * each:,} B for 500 "
                                    "places)")  # fmt: skip
    else:
        assert got["per place"] == "0 B (no codes)"
    for t, e in zip(model.candidates, model.candidate_errors, strict=True):
        kept = f"{t * (32 + 1) * 4:,} B (templates), "  # w (d, t), b (t) float32
        where = kept if t in model.periods else "not kept, "
        assert got[f"period {t}"] == f"{where}training error {e:.4f}"
    assert got["C"] == f"{math.log(500):.4f} (SVM penalty C = log N, N = 500)"
    ratio = model.compression_ratio
    assert got["compression_ratio"].startswith(f"{ratio:.4f} of 64,000 B")
    assert got["storage_bytes"] == f"{model.storage_bytes:,}"
    assert got["compile options"] == describe(jax.default_backend())
    assert "gpu:" not in got["compile options"]  # these tests run on the CPU
