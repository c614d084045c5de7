"""Training over frames that kornia augments on the fly (paper Sec. III-D).

Every epoch (:class:`AugmentedEpoch`) draws freshly augmented copies of the
reference frames (:func:`rhythmic_jax.augment.kornia_ops.augmented_batch`), describes
them with the map's descriptor in torch, hands the descriptors to JAX through DLPack
(no copy) and takes optax minibatch steps of the same vmapped objective
(:func:`rhythmic_jax.solvers.optax_loops.minibatch_step`). The clean descriptors, from
the cache, join every epoch as one more exemplar of each place, so the objective is
that of a multi-exemplar map whose second traversal is drawn anew each epoch.

The start is the exact optimum on the clean frames (Newton), so the minibatch
steps only have to move the templates towards the augmented exemplars. Candidate
errors and the period choice are then measured on the clean frames.

The epochs run through :func:`rhythmic_jax.solvers.resumable.train_run`, so a fit given
a checkpoint folder keeps orbax checkpoints every ``checkpoint_every`` steps, at the
end and on Ctrl-C; killed at any moment and started again on the same folder it
resumes, skipping the batches done without augmenting them again, and ends on
the map of an uninterrupted fit.

Names: n places, d features, p templates, b batch.
"""

from __future__ import annotations

import json
import logging
import os
import time
from collections.abc import Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.solvers.objective import Templates, targets

__all__ = [
    "AugmentedEpoch",
    "AugmentedFit",
    "fit_augmented",
    "fit_map_augmented",
    "refining",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class AugmentedFit:
    """Settings of an augmented fit.

    Attributes:
      names: augmentations (``rhythmic_jax.augment.kornia_ops.NAMES`` or ``"all"``).
      p: probability of each operation per frame.
      epochs: passes over the route, each with fresh augmentations.
      batch_size: frames per optax step.
      learning_rate: Adam step size.
      seed: seeds the augmentations (replayable) and the batch order.
      checkpoint_every: optimiser steps between checkpoints, when the fit is given
        a checkpoint folder (one more is kept at the end and on a stop).
      augment_settings: other fields of
        :class:`~rhythmic_jax.augment.kornia_ops.AugmentConfig`.
    """

    names: tuple[str, ...] = ("all",)
    p: float = 0.5
    epochs: int = 3
    batch_size: int = 128
    learning_rate: float = 1e-3
    seed: int = 0
    checkpoint_every: int = 50
    augment_settings: dict = field(default_factory=dict, hash=False)


class AugmentedEpoch(Sequence):
    """The batches ``(x (b, d), y (b, p))`` of one epoch, made when taken.

    First the augmented frames (``ceil(n / b)`` batches, batch ``i`` drawn with
    the seed ``(seed, epoch, i)``, so it can be made again on its own), then the
    clean descriptors in a shuffled order. Being a sized sequence, a resumed
    :func:`~rhythmic_jax.solvers.resumable.train_run` skips the batches already trained
    on without augmenting or describing them.

    Taking augmented batch ``i`` starts batch ``i + 1``'s augmentation and
    resizing in a background thread (one batch ahead, bounded), so describing
    batch ``i`` waits only for the network; the batches are the same as made
    one at a time.

    ``images`` uint8 (n, H, W, 3); ``clean`` (n, d) descriptors; ``labels`` (n,)
    place of each frame; ``timings`` accumulates seconds augmenting and describing.
    """

    def __init__(
        self, images, clean, labels, periods, descriptor, config: AugmentedFit,
        epoch: int, timings: dict[str, float] | None = None,
    ):  # fmt: skip
        from rhythmic_jax.augment.kornia_ops import AugmentConfig, epoch_order, to_batch

        to_batch(np.asarray(images)[:0])  # shape and dtype check
        self._images, self._clean, self._labels = images, clean, labels
        self._periods, self._descriptor, self._config = periods, descriptor, config
        self._epoch, self._timings = epoch, timings
        self._aug = AugmentConfig(
            names=config.names, p=config.p, **config.augment_settings
        )
        self._order = epoch_order(len(images), config.seed, epoch)
        rng = np.random.default_rng([config.seed, epoch, 1])
        self._clean_order = rng.permutation(len(clean))
        self._per_half = -(-len(clean) // config.batch_size)
        from rhythmic_jax.frames.compiled import stages

        self._prepare, self._run = stages(descriptor)
        self._ahead: dict[int, Future] = {}

    def __len__(self) -> int:
        return 2 * self._per_half

    def __getitem__(self, i: int) -> tuple[jax.Array, jax.Array]:
        if not 0 <= i < len(self):
            raise IndexError(i)
        size = self._config.batch_size
        if i >= self._per_half:
            j = i - self._per_half
            idx = self._clean_order[j * size : (j + 1) * size]
            return jnp.asarray(self._clean[idx]), targets(
                self._labels[idx], self._periods
            )
        import torch

        from rhythmic_jax.frames.features import to_jax

        ahead = self._ahead.pop(i, None)
        for late in self._ahead.values():  # taken out of order: start afresh
            late.cancel()
        self._ahead.clear()
        t = time.perf_counter()
        idx, batch = ahead.result() if ahead is not None else self._augmented(i)
        t_net = time.perf_counter()
        if i + 1 < self._per_half:
            self._ahead[i + 1] = _augmenter().submit(self._augmented, i + 1)
        with torch.inference_mode():
            x = to_jax(self._run(batch))
        if self._timings is not None:
            wait = self._timings.get("augment_wait", 0.0) + t_net - t
            self._timings["augment_wait"] = wait
            seconds = time.perf_counter() - t_net
            self._timings["describe"] = self._timings.get("describe", 0.0) + seconds
        return x, targets(self._labels[idx], self._periods)

    def _augmented(self, i: int):
        """Augmented batch ``i``, prepared for the network: ``(idx (b,), (b, 3,
        h, w))``; seconds spent go to ``timings["augment"]``."""
        import torch

        from rhythmic_jax.augment.kornia_ops import augmented_batch

        t = time.perf_counter()
        idx, batch = augmented_batch(
            self._images, self._order, self._aug, self._config.batch_size,
            self._config.seed, self._epoch, i,
        )  # fmt: skip
        with torch.inference_mode():
            batch = self._prepare(batch)
        if self._timings is not None:
            seconds = time.perf_counter() - t
            self._timings["augment"] = self._timings.get("augment", 0.0) + seconds
        return idx, batch


_POOL: list[ThreadPoolExecutor] = []


def _augmenter() -> ThreadPoolExecutor:
    """The one background thread that augments the next batch."""
    if not _POOL:
        _POOL.append(ThreadPoolExecutor(1, thread_name_prefix="rhythmic-augment"))
    return _POOL[0]


def _source(images, descriptor, config: AugmentedFit) -> str:
    """What the batches are, recorded with each checkpoint (a resume must agree)."""
    settings = getattr(descriptor, "settings", dict)()
    return json.dumps(
        {
            "augment": list(config.names),
            "p": config.p,
            "augment_settings": config.augment_settings,
            "descriptor": getattr(descriptor, "name", type(descriptor).__name__),
            "descriptor_settings": settings,
            "frames": list(np.shape(images)),
        },
        sort_keys=True,
        default=str,
    )


def fit_augmented(
    images: np.ndarray,
    clean: np.ndarray,
    labels: np.ndarray,
    periods: tuple[int, ...],
    init: Templates,
    c: float,
    descriptor,
    config: AugmentedFit = AugmentedFit(),
    *,
    progress: bool = False,
    checkpoint: str | os.PathLike | None = None,
) -> tuple[Templates, dict[str, float]]:
    """Minibatch optax training over ``config.epochs`` freshly augmented epochs.

    Args:
      images: uint8 (n, H, W, 3) reference frames; clean: (n, d) descriptors.
      labels: (n,) place of each frame; periods: every candidate period.
      init: start (e.g. the exact clean optimum), ``w`` (d, p), ``b`` (p,).
      c: the penalty C; descriptor: a ``rhythmic_jax.frames.features`` descriptor.
      checkpoint: a folder for orbax checkpoints of the run
        (:func:`~rhythmic_jax.solvers.resumable.train_run`: every
        ``config.checkpoint_every`` steps, at the end, and on a stop such as
        Ctrl-C). A folder that holds one resumes from it, and a run killed at any
        moment and resumed ends on the templates of an uninterrupted run.

    Returns:
      The templates and timings (seconds augmenting, describing, in optimiser
      steps; frames per second of the whole pipeline).
    """
    from rhythmic_jax.solvers.resumable import RunConfig, train_run

    if len(images) != len(clean):
        raise InputError(
            f"{len(images)} images but {len(clean)} clean descriptors; one per frame"
        )
    run = RunConfig(
        epochs=config.epochs,
        batch_size=config.batch_size,
        learning_rate=config.learning_rate,
        checkpoint_every=config.checkpoint_every,
        seed=config.seed,
        source=_source(images, descriptor, config),
    )
    timings: dict[str, float] = {}
    labels = np.asarray(labels)

    def epoch(e: int) -> AugmentedEpoch:
        return AugmentedEpoch(
            images, clean, labels, periods, descriptor, config, e, timings
        )

    t0 = time.perf_counter()
    # an augmented and a clean exemplar of every frame per epoch
    params = train_run(
        epoch, init, c, 2 * len(clean), run, checkpoint, progress, timings
    )
    total = time.perf_counter() - t0
    frames = 2 * len(clean) * config.epochs
    timings.update(total=total, frames=frames, frames_per_s=frames / max(total, 1e-9))
    return params, timings


def refining(
    images: np.ndarray,
    clean: np.ndarray,
    labels: np.ndarray,
    descriptor,
    config: AugmentedFit = AugmentedFit(),
    *,
    progress: bool = False,
    checkpoint: str | os.PathLike | None = None,
    timings: dict[str, float] | None = None,
):
    """The ``refine`` of :func:`rhythmic_jax.fitting.fit_map.fit` that trains
    every candidate over frames augmented on the fly (:func:`fit_augmented`,
    resumable from ``checkpoint``) after the exact solve on the clean
    descriptors (n, d) of ``images`` (n, H, W, 3), with place ``labels`` (n,);
    the pipeline's timings are added to ``timings`` when given."""

    def refine(params, cands, c):
        params, t = fit_augmented(
            images, clean, labels, cands, params, c, descriptor, config,
            progress=progress, checkpoint=checkpoint,
        )  # fmt: skip
        if timings is not None:
            timings.update(t)
        return params

    return refine


def fit_map_augmented(
    model,
    images: np.ndarray,
    clean: np.ndarray,
    descriptor,
    config: AugmentedFit = AugmentedFit(),
    labels: np.ndarray | None = None,
    *,
    progress: bool = False,
    checkpoint: str | os.PathLike | None = None,
    plan=None,
):
    """Fit a :class:`~rhythmic_jax.RhythmicMap` with augmented epochs, in place.

    Exact solve on the clean descriptors (n, d) of ``images`` (n, H, W, 3), then
    :func:`fit_augmented` over every candidate (resumable from ``checkpoint``),
    then the period choice (:func:`refining`). Returns the model;
    ``model.timings`` holds the pipeline's timings. ``plan``: the fit's
    :class:`~rhythmic_jax.fitting.fit_plan.FitPlan` when already made.
    """
    labels = np.arange(len(clean)) if labels is None else np.asarray(labels)
    timings: dict[str, float] = {}
    refine = refining(images, clean, labels, descriptor, config, progress=progress,
                      checkpoint=checkpoint, timings=timings)  # fmt: skip
    model.fit(clean, labels, progress=progress, refine=refine, plan=plan)
    model.timings = timings
    return model
