"""The public face: every name in __all__-style re-exports imports, without torch."""

from __future__ import annotations

import subprocess
import sys

import pytest

import rhythmic_jax

PUBLIC = [
    "Map", "MapConfig", "fit", "scores", "place_scores", "decode", "decode_sequence",
    "predict", "Decoded", "save", "load", "RhythmicMap", "describe_frames",
    "candidate_periods", "choose_periods", "compression_ratio", "database_bytes",
    "pairwise_coprime", "storage_bytes",
    "Embedding", "fit_invariant", "load_embedding", "save_embedding",
    "learn_embedding", "LearnConfig", "CodeBook", "learn_weight",
    "BruteForce", "ITQ", "OPQ", "seqslam_decode", "GroundTruth", "load_ground_truth",
    "accuracy", "recall_at_100_precision", "recall_at_k", "route_split",
    "enable_compile_cache", "InputError", "__version__",
]  # fmt: skip


def test_public_names_exist():
    missing = [name for name in PUBLIC if not hasattr(rhythmic_jax, name)]
    assert not missing


def test_the_face_is_short_and_every_name_documented():
    """At most 40 names; solver internals stay under ``rhythmic_jax.solvers``;
    each name but the version string says what it is."""
    assert len(rhythmic_jax.__all__) <= 40
    assert sorted(rhythmic_jax.__all__) == sorted(PUBLIC)
    for name in rhythmic_jax.__all__:
        if name != "__version__":
            doc = getattr(rhythmic_jax, name).__doc__
            assert doc and len(doc.strip()) > 20, name
    internals = {"TrainState", "minibatch_step", "memmap_batches", "ridge_start",
                 "DropLosers", "fit_bytes", "newton_fit", "NewtonConfig"}  # fmt: skip
    assert not internals & set(rhythmic_jax.__all__)


def test_the_pure_functions_and_the_face_agree(tmp_path):
    """``fit`` -> ``Map`` -> ``predict`` / ``decode`` / ``save`` / ``load``, the
    public face's way, gives the estimator's places."""
    import numpy as np

    import rhythmic_jax as rj

    x = np.random.default_rng(0).normal(size=(120, 32)).astype(np.float32)
    m = rj.fit(x, rj.MapConfig(r=2, level=1))
    assert isinstance(m, rj.Map)
    est = rj.RhythmicMap(r=2, level=1).fit(x)
    np.testing.assert_array_equal(rj.predict(m, x), est.predict(x))
    np.testing.assert_array_equal(np.asarray(rj.decode(m, x).index), est.predict(x))
    rj.save(tmp_path / "m.map", m)
    back = rj.load(tmp_path / "m.map")
    np.testing.assert_array_equal(rj.predict(back, x), est.predict(x))
    assert rj.RhythmicMap.load(tmp_path / "m.map").periods == m.periods


def test_importing_the_package_does_not_import_torch():
    code = "import sys, rhythmic_jax; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "False"


def test_the_face_is_its_one_table_and_every_name_resolves():
    """Each name of ``_API`` once, all of them in ``__all__`` and ``dir``, each the
    object of the module that table names."""
    import importlib

    listed = [n for names in rhythmic_jax._API.values() for n in names.split()]
    assert len(listed) == len(set(listed))
    assert set(rhythmic_jax.__all__) == {*listed, "InputError", "__version__"}
    assert set(rhythmic_jax.__all__) <= set(dir(rhythmic_jax))
    for module, names in rhythmic_jax._API.items():
        mod = importlib.import_module(f"rhythmic_jax.{module}")
        for name in names.split():
            assert getattr(rhythmic_jax, name) is getattr(mod, name), name
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        rhythmic_jax.nothing  # noqa: B018


def test_no_public_name_is_also_a_module():
    """A name that is both would change meaning once its module is imported."""
    import pkgutil

    modules = {
        m.name.rsplit(".", 1)[-1]
        for m in pkgutil.walk_packages(rhythmic_jax.__path__, "rhythmic_jax.")
    }
    assert "objective" in modules  # the module; its function is objective.objective
    assert not modules & set(rhythmic_jax.__all__)
    import rhythmic_jax.solvers.objective as module

    assert rhythmic_jax.solvers.objective is module
