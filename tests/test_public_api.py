"""The public face: every name in __all__-style re-exports imports, without torch."""

from __future__ import annotations

import subprocess
import sys

import pytest

import rhythmic_jax

PUBLIC = [
    "RhythmicMap", "MapConfig", "candidate_periods", "storage_bytes",
    "compression_ratio", "choose_periods", "crt_tables", "total_objective", "targets",
    "newton_fit", "fit_full_batch", "decode", "decode_scores", "soft_decode",
    "topm_decode", "sequence_decode", "seqslam_decode", "InputError", "Decoded",
    "GroundTruth", "from_lists", "from_positions", "read_vpr_bench",
    "load_ground_truth",
    "CodeBook", "fit_codes", "fused_decode", "fused_sequence_decode", "learn_weight",
    "frontier_rows", "projected_bytes", "crossover_n",
    "Groups", "parse_layout", "resolve_layout", "place_scores", "group_soft_decode",
]  # fmt: skip


def test_public_names_exist():
    missing = [name for name in PUBLIC if not hasattr(rhythmic_jax, name)]
    assert not missing


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
