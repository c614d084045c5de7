"""rhythmic_jax: sub-linear-storage visual place recognition in JAX.

A map of N frames is stored as r groups of linear "phase" classifiers with
co-prime periods; a query is localised by the argmax phase of each period and the
Chinese-remainder intersection (Yu, Jacobson, Milford, "Rhythmic Representations").
This module is the public face, generated from the one table ``_API`` (module ->
the names it gives the package). It imports nothing heavy: each name loads its
module on first use (``rhythmic_jax.RhythmicMap`` imports JAX, ``BruteForce``
faiss), so ``import rhythmic_jax`` and ``rhythmic-jax --help`` start at once. No
public name is also a submodule's or folder's name (``rhythmic_jax.map`` is the
folder of the map's modules, never a function).
"""

from __future__ import annotations

import importlib

from rhythmic_jax.errors import InputError as InputError
from rhythmic_jax.version import __version__ as __version__

# The public API, the only list of it: module (under rhythmic_jax) -> the names
# it exports, separated by spaces. A new public name goes here and nowhere else.
_API: dict[str, str] = {
    "map.codes": "code_bytes code_similarity CodeBook CodeTransform fit_codes",
    "map.config": "MapConfig",
    "decoding.dispatch": "decode_scores",
    "decoding.fusion": "fused_decode fused_sequence_decode learn_weight",
    "decoding.group_decode": (
        "group_hard_decode group_sequence_decode group_soft_decode group_topm_decode "
        "place_scores"
    ),
    "decoding.hard": "decode Decoded hard_decode",
    "decoding.sequence": "sequence_decode sequence_scores SPEEDS",
    "decoding.soft": "calibrate soft_decode topm_decode",
    "map.embedding": (
        "Embedding embedding_bytes fit_invariant load_embedding save_embedding"
    ),
    "eval.baselines": "BruteForce default_baselines ITQ KDTreeSearch OPQ",
    "eval.frontier": "crossover_n frontier_rows FrontierConfig projected_bytes",
    "eval.ground_truth": "from_indices from_lists from_positions GroundTruth",
    "eval.ground_truth_files": "load_ground_truth read_positions read_vpr_bench",
    "eval.metrics": (
        "accuracy pr_auc pr_curve recall_at_100_precision recall_at_k RecallAtK"
    ),
    "eval.seqslam": "seqslam_decode",
    "map.groups": "choose_radices choose_segment Groups parse_layout resolve_layout",
    "jit_cache": "enable_compile_cache",
    "fitting.learn": "learn_embedding LearnConfig",
    "solvers.objective": (
        "classifier_objective default_c period_errors squared_hinge targets Templates "
        "total_objective"
    ),
    "map.periods": (
        "candidate_periods choose_periods compression_ratio crt_tables database_bytes "
        "nominal_periods pairwise_coprime storage_bytes"
    ),
    "map.projection": "fit_pca PCA project",
    "rhythmic_map": "RhythmicMap",
    "solvers.candidates": "DropLosers",
    "solvers.memory": "check_memory fit_bytes",
    "solvers.newton": "newton_fit NewtonConfig",
    "solvers.newton_cg": "newton_solver",
    "solvers.optax_loops": "fit_full_batch minibatch_step ridge_start TrainState",
    "solvers.protocol": "LBFGS Minibatch Newton Solution",
    "solvers.resumable": "memmap_batches RunConfig train_run",
    "eval.split": "NORDLAND_SPLIT pair_split PlaceSplit route_split",
}

# public name -> the module that defines it
_EXPORTS = {
    name: f"rhythmic_jax.{module}"
    for module, names in _API.items()
    for name in names.split()
}
__all__ = sorted(["InputError", "__version__", *_EXPORTS], key=str.lower)


def __getattr__(name: str):
    """Load a public name's module on first use (then keep the name here)."""
    if name not in _EXPORTS:
        raise AttributeError(f"module 'rhythmic_jax' has no attribute {name!r}")
    value = getattr(importlib.import_module(_EXPORTS[name]), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
