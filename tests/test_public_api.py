"""The public face: every name in __all__-style re-exports imports, without torch."""

from __future__ import annotations

import subprocess
import sys

import rhythmic_jax

PUBLIC = [
    "RhythmicMap", "MapConfig", "candidate_periods", "storage_bytes",
    "compression_ratio", "choose_periods", "crt_tables", "objective", "targets",
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
