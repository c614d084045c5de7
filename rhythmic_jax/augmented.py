"""Training over frames that kornia augments on the fly (paper Sec. III-D).

Every epoch draws freshly augmented copies of the reference frames
(:func:`rhythmic_jax.augment.augmented_batches`), describes them with the map's
descriptor in torch, hands the descriptors to JAX through DLPack (no copy) and
takes optax minibatch steps of the same vmapped objective
(:func:`rhythmic_jax.train.minibatch_step`). The clean descriptors, from the
cache, join every epoch as one more exemplar of each place, so the objective is
that of a multi-exemplar map whose second traversal is drawn anew each epoch.

The start is the exact optimum on the clean frames (Newton), so the minibatch
steps only have to move the templates towards the augmented exemplars. Candidate
errors and the period choice are then measured on the clean frames.

Names: n places, d features, p templates, b batch.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from rhythmic_jax.objective import Templates, targets
from rhythmic_jax.train import adam, init_state, minibatch_step

__all__ = ["AugmentedFit", "augmented_epoch", "fit_augmented"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class AugmentedFit:
    """Settings of an augmented fit.

    Attributes:
      names: augmentations (``rhythmic_jax.augment.NAMES`` or ``"all"``).
      p: probability of each operation per frame.
      epochs: passes over the route, each with fresh augmentations.
      batch_size: frames per optax step.
      learning_rate: Adam step size.
      seed: seeds the augmentations (replayable) and the batch order.
      augment_settings: other :class:`~rhythmic_jax.augment.AugmentConfig` fields.
    """

    names: tuple[str, ...] = ("all",)
    p: float = 0.5
    epochs: int = 3
    batch_size: int = 128
    learning_rate: float = 1e-3
    seed: int = 0
    augment_settings: dict = field(default_factory=dict, hash=False)


def augmented_epoch(
    images: np.ndarray,
    clean: np.ndarray,
    labels: np.ndarray,
    periods: tuple[int, ...],
    descriptor,
    config: AugmentedFit,
    epoch: int,
    timings: dict[str, float] | None = None,
) -> Iterator[tuple[jnp.ndarray, jnp.ndarray]]:
    """Batches ``(x (b, d), y (b, p))`` of one epoch: augmented frames, then clean.

    ``images`` uint8 (n, H, W, 3); ``clean`` (n, d) cached descriptors; ``labels``
    (n,) place of each frame. ``timings`` accumulates seconds spent augmenting
    and describing.
    """
    import torch

    from rhythmic_jax.augment import AugmentConfig, augmented_batches
    from rhythmic_jax.features import to_jax

    aug = AugmentConfig(names=config.names, p=config.p, **config.augment_settings)
    t = time.perf_counter()
    for idx, batch in augmented_batches(
        images, aug, config.batch_size, config.seed, epoch
    ):
        t_aug = time.perf_counter()
        with torch.inference_mode():
            feats = descriptor(batch)
        x = to_jax(feats)
        t_desc = time.perf_counter()
        if timings is not None:
            timings["augment"] = timings.get("augment", 0.0) + t_aug - t
            timings["describe"] = timings.get("describe", 0.0) + t_desc - t_aug
        yield x, targets(labels[idx], periods)
        t = time.perf_counter()
    order = np.random.default_rng([config.seed, epoch, 1]).permutation(len(clean))
    for start in range(0, len(clean), config.batch_size):
        idx = order[start : start + config.batch_size]
        yield jnp.asarray(clean[idx]), targets(labels[idx], periods)


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
    progress: bool = True,
    on_step: Callable | None = None,
) -> tuple[Templates, dict[str, float]]:
    """Minibatch optax training over ``config.epochs`` freshly augmented epochs.

    Args:
      images: uint8 (n, H, W, 3) reference frames; clean: (n, d) descriptors.
      labels: (n,) place of each frame; periods: every candidate period.
      init: start (e.g. the exact clean optimum), ``w`` (d, p), ``b`` (p,).
      c: the penalty C; descriptor: a ``rhythmic_jax.features`` descriptor.
      on_step: ``on_step(state, loss)`` after every step.

    Returns:
      The templates and timings (seconds augmenting, describing, stepping; frames
      per second of the whole pipeline).
    """
    optimizer = adam(config.learning_rate)
    state = init_state(init, optimizer)
    n_epoch = 2 * len(clean)  # an augmented and a clean exemplar of every frame
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    steps = config.epochs * 2 * -(-len(clean) // config.batch_size)
    bar = tqdm(total=steps, desc="augmented fit", disable=not progress)
    frames = 0
    for epoch in range(config.epochs):
        batches = augmented_epoch(
            images, clean, labels, periods, descriptor, config, epoch, timings
        )
        for x, y in batches:
            t = time.perf_counter()
            state, loss = minibatch_step(
                state, x, y, c, n_epoch / x.shape[0], optimizer
            )
            loss.block_until_ready()
            timings["step"] = timings.get("step", 0.0) + time.perf_counter() - t
            frames += x.shape[0]
            bar.update()
            bar.set_postfix(loss=f"{float(loss):.4g}")
            if on_step is not None:
                on_step(state, float(loss))
    bar.close()
    total = time.perf_counter() - t0
    timings.update(total=total, frames=frames, frames_per_s=frames / max(total, 1e-9))
    return state.params, timings


def fit_map_augmented(
    model,
    images: np.ndarray,
    clean: np.ndarray,
    descriptor,
    config: AugmentedFit = AugmentedFit(),
    labels: np.ndarray | None = None,
    *,
    progress: bool = True,
):
    """Fit a :class:`~rhythmic_jax.RhythmicMap` with augmented epochs, in place.

    Exact solve on the clean descriptors (n, d) of ``images`` (n, H, W, 3), then
    :func:`fit_augmented` over every candidate, then the period choice. Returns
    the model; ``model.timings`` holds the pipeline's timings.
    """
    labels = np.arange(len(clean)) if labels is None else np.asarray(labels)
    timings: dict[str, float] = {}

    def refine(params, cands, c):
        params, t = fit_augmented(
            images, clean, labels, cands, params, c, descriptor, config,
            progress=progress,
        )  # fmt: skip
        timings.update(t)
        return params

    model.fit(clean, labels, progress=progress, refine=refine)
    model.timings = timings
    return model
