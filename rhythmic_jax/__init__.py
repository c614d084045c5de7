"""rhythmic_jax: sub-linear-storage visual place recognition in JAX.

A map of N frames is stored as r groups of linear "phase" classifiers with
co-prime periods; a query is localised by the argmax phase of each period and the
Chinese-remainder intersection (Yu, Jacobson, Milford, "Rhythmic Representations").
This module is the public face; it imports without torch.
"""

from __future__ import annotations

__version__ = "0.1.0"

from rhythmic_jax.baselines import ITQ as ITQ
from rhythmic_jax.baselines import OPQ as OPQ
from rhythmic_jax.baselines import BruteForce as BruteForce
from rhythmic_jax.baselines import KDTreeSearch as KDTreeSearch
from rhythmic_jax.baselines import default_baselines as default_baselines
from rhythmic_jax.decode import decode as decode
from rhythmic_jax.decode import decode_scores as decode_scores
from rhythmic_jax.decode import hard_decode as hard_decode
from rhythmic_jax.errors import InputError as InputError
from rhythmic_jax.evaluate import RecallAtK as RecallAtK
from rhythmic_jax.evaluate import accuracy as accuracy
from rhythmic_jax.evaluate import pr_auc as pr_auc
from rhythmic_jax.evaluate import pr_curve as pr_curve
from rhythmic_jax.evaluate import recall_at_100_precision as recall_at_100_precision
from rhythmic_jax.evaluate import recall_at_k as recall_at_k
from rhythmic_jax.evaluate import storage_report as storage_report
from rhythmic_jax.memory import check_memory as check_memory
from rhythmic_jax.memory import fit_bytes as fit_bytes
from rhythmic_jax.newton import NewtonConfig as NewtonConfig
from rhythmic_jax.newton import newton_fit as newton_fit
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
from rhythmic_jax.periods import pairwise_coprime as pairwise_coprime
from rhythmic_jax.periods import storage_bytes as storage_bytes
from rhythmic_jax.projection import LDA as LDA
from rhythmic_jax.projection import PCA as PCA
from rhythmic_jax.projection import fit_lda as fit_lda
from rhythmic_jax.projection import fit_pca as fit_pca
from rhythmic_jax.projection import project as project
from rhythmic_jax.rhythmic_map import MapConfig as MapConfig
from rhythmic_jax.rhythmic_map import RhythmicMap as RhythmicMap
from rhythmic_jax.run import RunConfig as RunConfig
from rhythmic_jax.run import memmap_batches as memmap_batches
from rhythmic_jax.run import train_run as train_run
from rhythmic_jax.seqslam import seqslam_decode as seqslam_decode
from rhythmic_jax.sequence import SPEEDS as SPEEDS
from rhythmic_jax.sequence import SequenceState as SequenceState
from rhythmic_jax.sequence import sequence_decode as sequence_decode
from rhythmic_jax.sequence import sequence_init as sequence_init
from rhythmic_jax.sequence import sequence_scores as sequence_scores
from rhythmic_jax.sequence import sequence_step as sequence_step
from rhythmic_jax.soft import Decoded as Decoded
from rhythmic_jax.soft import calibrate as calibrate
from rhythmic_jax.soft import soft_decode as soft_decode
from rhythmic_jax.soft import topm_decode as topm_decode
from rhythmic_jax.split import NORDLAND_SPLIT as NORDLAND_SPLIT
from rhythmic_jax.split import PlaceSplit as PlaceSplit
from rhythmic_jax.split import pair_split as pair_split
from rhythmic_jax.split import route_split as route_split
from rhythmic_jax.train import TrainState as TrainState
from rhythmic_jax.train import fit_full_batch as fit_full_batch
from rhythmic_jax.train import fit_minibatch as fit_minibatch
from rhythmic_jax.train import minibatch_step as minibatch_step
from rhythmic_jax.train import ridge_start as ridge_start
