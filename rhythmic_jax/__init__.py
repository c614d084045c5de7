"""rhythmic_jax: sub-linear-storage visual place recognition in JAX.

A map of N frames is stored as r groups of linear "phase" classifiers with
co-prime periods; a query is localised by the argmax phase of each period and the
Chinese-remainder intersection (Yu, Jacobson, Milford, "Rhythmic Representations").
This module is the public face. It imports nothing heavy: each name loads its
module on first use (``rhythmic_jax.RhythmicMap`` imports JAX, ``BruteForce``
faiss), so ``import rhythmic_jax`` and ``rhythmic-jax --help`` start at once.
"""

from __future__ import annotations

import importlib
import types
from typing import TYPE_CHECKING

from rhythmic_jax.errors import InputError as InputError
from rhythmic_jax.version import __version__ as __version__

# public name -> the module that defines it
_EXPORTS = {
    "CodeBook": "rhythmic_jax.codes",
    "CodeTransform": "rhythmic_jax.codes",
    "code_bytes": "rhythmic_jax.codes",
    "code_similarity": "rhythmic_jax.codes",
    "fit_codes": "rhythmic_jax.codes",
    "decode_scores": "rhythmic_jax.decoding.dispatch",
    "fused_decode": "rhythmic_jax.decoding.fusion",
    "fused_sequence_decode": "rhythmic_jax.decoding.fusion",
    "learn_weight": "rhythmic_jax.decoding.fusion",
    "FrontierConfig": "rhythmic_jax.eval.frontier",
    "crossover_n": "rhythmic_jax.eval.frontier",
    "frontier_rows": "rhythmic_jax.eval.frontier",
    "projected_bytes": "rhythmic_jax.eval.frontier",
    "Embedding": "rhythmic_jax.embedding",
    "embedding_bytes": "rhythmic_jax.embedding",
    "fit_invariant": "rhythmic_jax.embedding",
    "enable_compile_cache": "rhythmic_jax.jit_cache",
    "load_embedding": "rhythmic_jax.embedding",
    "save_embedding": "rhythmic_jax.embedding",
    "LearnConfig": "rhythmic_jax.learn",
    "learn_embedding": "rhythmic_jax.learn",
    "decode": "rhythmic_jax.decoding.hard",
    "Decoded": "rhythmic_jax.decoding.hard",
    "hard_decode": "rhythmic_jax.decoding.hard",
    "sequence_decode": "rhythmic_jax.decoding.sequence",
    "sequence_scores": "rhythmic_jax.decoding.sequence",
    "SPEEDS": "rhythmic_jax.decoding.sequence",
    "calibrate": "rhythmic_jax.decoding.soft",
    "soft_decode": "rhythmic_jax.decoding.soft",
    "topm_decode": "rhythmic_jax.decoding.soft",
    "BruteForce": "rhythmic_jax.eval.baselines",
    "default_baselines": "rhythmic_jax.eval.baselines",
    "ITQ": "rhythmic_jax.eval.baselines",
    "KDTreeSearch": "rhythmic_jax.eval.baselines",
    "OPQ": "rhythmic_jax.eval.baselines",
    "accuracy": "rhythmic_jax.eval.metrics",
    "pr_auc": "rhythmic_jax.eval.metrics",
    "pr_curve": "rhythmic_jax.eval.metrics",
    "recall_at_100_precision": "rhythmic_jax.eval.metrics",
    "recall_at_k": "rhythmic_jax.eval.metrics",
    "RecallAtK": "rhythmic_jax.eval.metrics",
    "seqslam_decode": "rhythmic_jax.eval.seqslam",
    "GroundTruth": "rhythmic_jax.eval.ground_truth",
    "from_indices": "rhythmic_jax.eval.ground_truth",
    "from_lists": "rhythmic_jax.eval.ground_truth",
    "from_positions": "rhythmic_jax.eval.ground_truth",
    "load_ground_truth": "rhythmic_jax.io.ground_truth_files",
    "read_positions": "rhythmic_jax.io.ground_truth_files",
    "read_vpr_bench": "rhythmic_jax.io.ground_truth_files",
    "classifier_objective": "rhythmic_jax.objective",
    "default_c": "rhythmic_jax.objective",
    "objective": "rhythmic_jax.objective",
    "period_errors": "rhythmic_jax.objective",
    "squared_hinge": "rhythmic_jax.objective",
    "targets": "rhythmic_jax.objective",
    "Templates": "rhythmic_jax.objective",
    "total_objective": "rhythmic_jax.objective",
    "candidate_periods": "rhythmic_jax.periods",
    "choose_periods": "rhythmic_jax.periods",
    "compression_ratio": "rhythmic_jax.periods",
    "crt_tables": "rhythmic_jax.periods",
    "database_bytes": "rhythmic_jax.periods",
    "nominal_periods": "rhythmic_jax.periods",
    "pairwise_coprime": "rhythmic_jax.periods",
    "storage_bytes": "rhythmic_jax.periods",
    "fit_pca": "rhythmic_jax.projection",
    "PCA": "rhythmic_jax.projection",
    "project": "rhythmic_jax.projection",
    "MapConfig": "rhythmic_jax.rhythmic_map",
    "RhythmicMap": "rhythmic_jax.rhythmic_map",
    "DropLosers": "rhythmic_jax.solvers.candidates",
    "check_memory": "rhythmic_jax.solvers.memory",
    "fit_bytes": "rhythmic_jax.solvers.memory",
    "newton_fit": "rhythmic_jax.solvers.newton",
    "NewtonConfig": "rhythmic_jax.solvers.newton",
    "newton_solver": "rhythmic_jax.solvers.newton_cg",
    "LBFGS": "rhythmic_jax.solvers.protocol",
    "Minibatch": "rhythmic_jax.solvers.protocol",
    "Newton": "rhythmic_jax.solvers.protocol",
    "Solution": "rhythmic_jax.solvers.protocol",
    "fit_full_batch": "rhythmic_jax.solvers.optax_loops",
    "minibatch_step": "rhythmic_jax.solvers.optax_loops",
    "ridge_start": "rhythmic_jax.solvers.optax_loops",
    "TrainState": "rhythmic_jax.solvers.optax_loops",
    "memmap_batches": "rhythmic_jax.solvers.resumable",
    "RunConfig": "rhythmic_jax.solvers.resumable",
    "train_run": "rhythmic_jax.solvers.resumable",
    "Groups": "rhythmic_jax.groups",
    "choose_radices": "rhythmic_jax.groups",
    "choose_segment": "rhythmic_jax.groups",
    "parse_layout": "rhythmic_jax.groups",
    "resolve_layout": "rhythmic_jax.groups",
    "group_hard_decode": "rhythmic_jax.decoding.group_decode",
    "group_sequence_decode": "rhythmic_jax.decoding.group_decode",
    "group_soft_decode": "rhythmic_jax.decoding.group_decode",
    "group_topm_decode": "rhythmic_jax.decoding.group_decode",
    "place_scores": "rhythmic_jax.decoding.group_decode",
    "NORDLAND_SPLIT": "rhythmic_jax.split",
    "pair_split": "rhythmic_jax.split",
    "PlaceSplit": "rhythmic_jax.split",
    "route_split": "rhythmic_jax.split",
}

if TYPE_CHECKING:  # the same names, spelled out for readers and type checkers
    from rhythmic_jax.codes import CodeBook as CodeBook
    from rhythmic_jax.codes import CodeTransform as CodeTransform
    from rhythmic_jax.codes import code_bytes as code_bytes
    from rhythmic_jax.codes import code_similarity as code_similarity
    from rhythmic_jax.codes import fit_codes as fit_codes
    from rhythmic_jax.decoding.dispatch import decode_scores as decode_scores
    from rhythmic_jax.decoding.fusion import fused_decode as fused_decode
    from rhythmic_jax.decoding.fusion import (
        fused_sequence_decode as fused_sequence_decode,
    )
    from rhythmic_jax.decoding.fusion import learn_weight as learn_weight
    from rhythmic_jax.decoding.group_decode import (
        group_hard_decode as group_hard_decode,
    )
    from rhythmic_jax.decoding.group_decode import (
        group_sequence_decode as group_sequence_decode,
    )
    from rhythmic_jax.decoding.group_decode import (
        group_soft_decode as group_soft_decode,
    )
    from rhythmic_jax.decoding.group_decode import (
        group_topm_decode as group_topm_decode,
    )
    from rhythmic_jax.decoding.group_decode import place_scores as place_scores
    from rhythmic_jax.decoding.hard import Decoded as Decoded
    from rhythmic_jax.decoding.hard import decode as decode
    from rhythmic_jax.decoding.hard import hard_decode as hard_decode
    from rhythmic_jax.decoding.sequence import SPEEDS as SPEEDS
    from rhythmic_jax.decoding.sequence import sequence_decode as sequence_decode
    from rhythmic_jax.decoding.sequence import sequence_scores as sequence_scores
    from rhythmic_jax.decoding.soft import calibrate as calibrate
    from rhythmic_jax.decoding.soft import soft_decode as soft_decode
    from rhythmic_jax.decoding.soft import topm_decode as topm_decode
    from rhythmic_jax.embedding import Embedding as Embedding
    from rhythmic_jax.embedding import embedding_bytes as embedding_bytes
    from rhythmic_jax.embedding import fit_invariant as fit_invariant
    from rhythmic_jax.embedding import load_embedding as load_embedding
    from rhythmic_jax.embedding import save_embedding as save_embedding
    from rhythmic_jax.eval.baselines import ITQ as ITQ
    from rhythmic_jax.eval.baselines import OPQ as OPQ
    from rhythmic_jax.eval.baselines import BruteForce as BruteForce
    from rhythmic_jax.eval.baselines import KDTreeSearch as KDTreeSearch
    from rhythmic_jax.eval.baselines import default_baselines as default_baselines
    from rhythmic_jax.eval.frontier import FrontierConfig as FrontierConfig
    from rhythmic_jax.eval.frontier import crossover_n as crossover_n
    from rhythmic_jax.eval.frontier import frontier_rows as frontier_rows
    from rhythmic_jax.eval.frontier import projected_bytes as projected_bytes
    from rhythmic_jax.eval.ground_truth import GroundTruth as GroundTruth
    from rhythmic_jax.eval.ground_truth import from_indices as from_indices
    from rhythmic_jax.eval.ground_truth import from_lists as from_lists
    from rhythmic_jax.eval.ground_truth import from_positions as from_positions
    from rhythmic_jax.eval.metrics import RecallAtK as RecallAtK
    from rhythmic_jax.eval.metrics import accuracy as accuracy
    from rhythmic_jax.eval.metrics import pr_auc as pr_auc
    from rhythmic_jax.eval.metrics import pr_curve as pr_curve
    from rhythmic_jax.eval.metrics import (
        recall_at_100_precision as recall_at_100_precision,
    )
    from rhythmic_jax.eval.metrics import recall_at_k as recall_at_k
    from rhythmic_jax.eval.seqslam import seqslam_decode as seqslam_decode
    from rhythmic_jax.groups import Groups as Groups
    from rhythmic_jax.groups import choose_radices as choose_radices
    from rhythmic_jax.groups import choose_segment as choose_segment
    from rhythmic_jax.groups import parse_layout as parse_layout
    from rhythmic_jax.groups import resolve_layout as resolve_layout
    from rhythmic_jax.io.ground_truth_files import (
        load_ground_truth as load_ground_truth,
    )
    from rhythmic_jax.io.ground_truth_files import read_positions as read_positions
    from rhythmic_jax.io.ground_truth_files import read_vpr_bench as read_vpr_bench
    from rhythmic_jax.jit_cache import enable_compile_cache as enable_compile_cache
    from rhythmic_jax.learn import LearnConfig as LearnConfig
    from rhythmic_jax.learn import learn_embedding as learn_embedding
    from rhythmic_jax.objective import Templates as Templates
    from rhythmic_jax.objective import classifier_objective as classifier_objective
    from rhythmic_jax.objective import default_c as default_c
    from rhythmic_jax.objective import objective as objective
    from rhythmic_jax.objective import period_errors as period_errors
    from rhythmic_jax.objective import squared_hinge as squared_hinge
    from rhythmic_jax.objective import targets as targets
    from rhythmic_jax.objective import total_objective as total_objective
    from rhythmic_jax.periods import candidate_periods as candidate_periods
    from rhythmic_jax.periods import choose_periods as choose_periods
    from rhythmic_jax.periods import compression_ratio as compression_ratio
    from rhythmic_jax.periods import crt_tables as crt_tables
    from rhythmic_jax.periods import database_bytes as database_bytes
    from rhythmic_jax.periods import nominal_periods as nominal_periods
    from rhythmic_jax.periods import pairwise_coprime as pairwise_coprime
    from rhythmic_jax.periods import storage_bytes as storage_bytes
    from rhythmic_jax.projection import PCA as PCA
    from rhythmic_jax.projection import fit_pca as fit_pca
    from rhythmic_jax.projection import project as project
    from rhythmic_jax.rhythmic_map import MapConfig as MapConfig
    from rhythmic_jax.rhythmic_map import RhythmicMap as RhythmicMap
    from rhythmic_jax.solvers.candidates import DropLosers as DropLosers
    from rhythmic_jax.solvers.memory import check_memory as check_memory
    from rhythmic_jax.solvers.memory import fit_bytes as fit_bytes
    from rhythmic_jax.solvers.newton import NewtonConfig as NewtonConfig
    from rhythmic_jax.solvers.newton import newton_fit as newton_fit
    from rhythmic_jax.solvers.newton_cg import newton_solver as newton_solver
    from rhythmic_jax.solvers.optax_loops import TrainState as TrainState
    from rhythmic_jax.solvers.optax_loops import fit_full_batch as fit_full_batch
    from rhythmic_jax.solvers.optax_loops import minibatch_step as minibatch_step
    from rhythmic_jax.solvers.optax_loops import ridge_start as ridge_start
    from rhythmic_jax.solvers.protocol import LBFGS as LBFGS
    from rhythmic_jax.solvers.protocol import Minibatch as Minibatch
    from rhythmic_jax.solvers.protocol import Newton as Newton
    from rhythmic_jax.solvers.protocol import Solution as Solution
    from rhythmic_jax.solvers.resumable import RunConfig as RunConfig
    from rhythmic_jax.solvers.resumable import memmap_batches as memmap_batches
    from rhythmic_jax.solvers.resumable import train_run as train_run
    from rhythmic_jax.split import NORDLAND_SPLIT as NORDLAND_SPLIT
    from rhythmic_jax.split import PlaceSplit as PlaceSplit
    from rhythmic_jax.split import pair_split as pair_split
    from rhythmic_jax.split import route_split as route_split


def __getattr__(name: str):
    """Load a public name's module on first use."""
    if name not in _EXPORTS:
        raise AttributeError(f"module 'rhythmic_jax' has no attribute {name!r}")
    value = getattr(importlib.import_module(_EXPORTS[name]), name)
    if name not in _SHADOWED:
        globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))


# Public names that are also submodule names: importing the submodule sets the
# package attribute to the module, so the name is a property that keeps the
# public meaning (the function) whichever was imported first.
_SHADOWED = {name for name in _EXPORTS if _EXPORTS[name] == f"{__name__}.{name}"}


class _Face(types.ModuleType):
    pass


for _name in _SHADOWED:
    setattr(
        _Face,
        _name,
        property(
            lambda self, _n=_name: getattr(importlib.import_module(_EXPORTS[_n]), _n),
            lambda self, value: None,
        ),
    )
importlib.import_module("sys").modules[__name__].__class__ = _Face
