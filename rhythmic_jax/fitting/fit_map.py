"""Fitting a map: reference frames and a configuration -> a :class:`Map`.

:func:`fit` trains every template of every candidate period in one joint solve
(:mod:`rhythmic_jax.solvers`), measures each candidate's training error, keeps
the groups the plan chooses (:meth:`~rhythmic_jax.fitting.fit_plan.FitPlan.keep`:
``r`` pairwise co-prime periods, product >= N, least summed error, or the
configured layout) and returns them as a :class:`~rhythmic_jax.map.pytree.Map`
value, with codes when the configuration asks for them.

Shapes: n_frames reference frames of d features (k after an embedding), n places.
"""

from __future__ import annotations

import logging
import warnings

import jax
import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.fitting.fit_plan import FitPlan
from rhythmic_jax.fitting.fit_plan import plan as plan_fit
from rhythmic_jax.jit_options import describe as compile_options
from rhythmic_jax.map.codes import CodeBook
from rhythmic_jax.map.config import INT8, MapConfig
from rhythmic_jax.map.embedding import Embedding
from rhythmic_jax.map.embedding import apply as apply_embedding
from rhythmic_jax.map.pytree import Map, host_templates
from rhythmic_jax.map.scalar_codes import ScalarCodeBook
from rhythmic_jax.solvers.frame_length import LENGTH_RANGE as LENGTH_RANGE
from rhythmic_jax.solvers.frame_length import check_length
from rhythmic_jax.solvers.newton import FitWarning, NewtonInfo, step_cap_line
from rhythmic_jax.solvers.objective import period_errors, targets
from rhythmic_jax.solvers.protocol import solver_for
from rhythmic_jax.validate import (
    check_features,
    check_fit_scale,
    check_labels,
    scale_sums,
)

__all__ = ["LENGTH_RANGE", "PLACED_AT_LEAST", "check_length", "fit"]

log = logging.getLogger(__name__)

# A period whose argmax misses more than half the frames it was trained on
# leaves the map unable to place most of its own frames: said in one warning.
# Fitted maps miss far fewer (Nordland's candidate errors 4-5 %, the README).
PLACED_AT_LEAST = 0.5


def _placed_note(errors) -> str | None:
    """One line when a kept group's training error shows the map cannot place
    most of its own frames (None otherwise)."""
    worst = float(np.max(np.asarray(errors, np.float64), initial=0.0))
    if 1.0 - worst >= PLACED_AT_LEAST:
        return None
    return (
        f"the map places at most {1 - worst:.0%} of its own frames (a kept period's "
        f"training error is {worst:.0%}): queries will be mostly wrong; check the "
        "frames' scale and that frames of one place look alike"
    )


def fit(
    frames,
    config: MapConfig | None = None,
    *,
    labels=None,
    embedding: Embedding | None = None,
    progress: bool = False,
    refine=None,
    plan: FitPlan | None = None,
) -> Map:
    """A map of the reference frames (n_frames, d) built as ``config`` says.

    Features on a scale no solver fits (unscaled 8-bit descriptors) are
    refused before any compile (:func:`rhythmic_jax.validate.check_fit_scale`).

    Args:
      labels: (n_frames,) place of each frame (default: its row), so several
        traversals of one route share templates (multi-exemplar map).
      embedding: applied to the frames (and, by the map, to every query) first.
      progress: show the solver's progress bar.
      refine: optional ``refine(params, candidates, c) -> params`` run after
        the exact solve and before the period choice (e.g. minibatch steps over
        augmented frames, :func:`rhythmic_jax.augment.stream.fit_augmented`).
      plan: the fit's plan when made already
        (:func:`rhythmic_jax.fitting.fit_plan.plan` of ``config`` for these places
        and the templates' d), its memory checked
        (:meth:`~rhythmic_jax.fitting.fit_plan.FitPlan.check_memory`).
    """
    cfg = config or MapConfig()
    x = check_features(frames, "reference features")
    labels = check_labels(np.arange(len(x)) if labels is None else labels, len(x))
    d_in = int(x.shape[1])
    if embedding is not None:
        x = apply_embedding(embedding, x)
    name = "reference features" + (" (embedded)" if embedding is not None else "")
    sums = scale_sums(x)
    check_fit_scale(sums, float(max(x.max(), -x.min())), name)
    check_length(sums, name)
    n, d = int(labels.max()) + 1, int(x.shape[1])
    if plan is None:  # else planned, and its memory checked, by the caller
        plan = plan_fit(cfg, n, d)
        plan.check_memory(len(x))
    elif (plan.n, plan.d) != (n, d):
        raise ValueError(f"a plan for {plan.n} x {plan.d}, not {n} x {d}")
    if cfg.codes is not None and not np.array_equal(labels, np.arange(len(x))):
        raise InputError("codes need one reference frame per place, in order")
    trained, c = plan.trained, plan.c
    log.info("fitting %s on %d x %d, C=%.3g", plan.describe(), *x.shape, c)
    log.info("compile options %s", compile_options(jax.default_backend()))
    solver = solver_for(cfg.solver, cfg.gap, progress)
    params, info = solver.run(None, x, targets(labels, trained), c)
    if isinstance(info, NewtonInfo):
        line = step_cap_line(info, cfg.gap, solver.config.max_iter)
        if line is not None:
            warnings.warn(FitWarning(line), stacklevel=2)
    if refine is not None:
        params = refine(params, trained, c)
    params = host_templates(params, x)
    # the training errors from scores on the host (float32 BLAS): no XLA program
    errors = period_errors(x @ params.w + params.b, labels, trained)
    kept = plan.keep(params, errors, cfg.dtype)
    note = _placed_note(kept.group_errors)
    if note is not None:
        warnings.warn(FitWarning(note), stacklevel=2)
    book = None
    if cfg.codes is not None:  # planned: bits within the templates' d
        book = (
            CodeBook.fit(x, cfg.codes) if cfg.codes != INT8 else ScalarCodeBook.fit(x)
        )
    return Map.build(kept, d_in, cfg, codebook=book, embedding=embedding)
