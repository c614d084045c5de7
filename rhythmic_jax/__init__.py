"""rhythmic_jax: sub-linear-storage visual place recognition in JAX.

A map of N frames is stored as r groups of linear "phase" classifiers with
co-prime periods; a query is localised by the argmax phase of each period and the
Chinese-remainder intersection (Yu, Jacobson, Milford, "Rhythmic Representations").
This module is the public face, generated from the one table ``_API`` (module ->
the names it gives the package). It imports nothing heavy: each name loads its
module on first use (``rhythmic_jax.RhythmicMap`` imports JAX and
scikit-learn, ``BruteForce`` faiss), so ``import rhythmic_jax`` and
``rhythmic-jax --help`` start at once, and a command, which works on ``Map``
values, never loads scikit-learn. No
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
    # the map as a value, and the pure functions over it
    "map.pytree": "Map",
    "map.config": "MapConfig",
    "fitting.fit_map": "fit",
    "decoding.queries": "decode decode_sequence place_scores predict scores",
    "decoding.hard": "Decoded",
    "map.map_file": "load save",
    # the scikit-learn estimator over them (imports scikit-learn when asked for)
    "rhythmic_map": "RhythmicMap",
    # the paper's periods and storage arithmetic
    "map.periods": (
        "candidate_periods choose_periods compression_ratio database_bytes "
        "pairwise_coprime storage_bytes"
    ),
    # a route's frames described once into a descriptor file
    "frames.route_descriptors": "describe_frames",
    # appearance change: embeddings, codes beside the map, their fusion weight
    "fitting.learn": "learn_embedding LearnConfig",
    "map.embedding": "Embedding fit_invariant load_embedding save_embedding",
    "map.codes": "CodeBook",
    "decoding.fusion": "learn_weight",
    # judging a map beside the baselines a user would otherwise pick
    "eval.baselines": "BruteForce ITQ OPQ",
    "eval.seqslam": "seqslam_decode",
    "eval.ground_truth": "GroundTruth",
    "eval.ground_truth_files": "load_ground_truth",
    "eval.metrics": "accuracy recall_at_100_precision recall_at_k",
    "eval.split": "route_split",
    "jit_cache": "enable_compile_cache",
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
