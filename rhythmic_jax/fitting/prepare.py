"""Fitting a map on frames as scikit-learn's estimators take them.

:func:`fit_frames` is :func:`rhythmic_jax.fitting.fit_map.fit` with what an
estimator's ``fit(X, y)`` adds before it: the settings checked as the command
line checks its options, X refused in scikit-learn's words, place labels ``y``
(any integers >= 0, numbered in their order and kept as ``place_labels``), and
features not of order one standardized or refused as ``scale`` says (the
scaling kept as ``scale_mean`` / ``scale_std``). The map's queries then take
both into account (:mod:`rhythmic_jax.decoding.held`).
:class:`rhythmic_jax.RhythmicMap` fits through it, as do the demo and the
frontier's and ablation's maps.

Shapes: n_frames reference frames of d features, n places.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.estimator_inputs import (
    SCALE_KEYS,
    SCALES,
    check_settings,
    not_of_order_one,
    place_labels,
    shape_checked,
    standardize,
    standardized,
)
from rhythmic_jax.fitting.fit_map import fit as fit_map
from rhythmic_jax.map.config import MapConfig
from rhythmic_jax.map.embedding import Embedding
from rhythmic_jax.map.pytree import Map
from rhythmic_jax.validate import check_features

__all__ = ["FIT_KEYS", "fit_frames"]

FIT_KEYS = (*SCALE_KEYS, "place_labels")  # extra arrays each fit makes anew


def fit_frames(
    X,
    config: MapConfig,
    y=None,
    *,
    scale: str = "auto",
    embedding: Embedding | None = None,
    extra: dict | None = None,
    reference: str = "{}",
    progress: bool = False,
    refine=None,
    plan=None,
) -> Map:
    """The map of reference frames X (n_frames, d), one place per row or per
    label of ``y`` (n_frames,), as ``config`` says.

    ``scale``: "refuse" features not of order one in one line (the command
    line's way), "standardize" every feature over the frames, or "auto":
    standardize the frames "refuse" would refuse (never with an embedding,
    which takes the descriptors as they are). ``extra``: arrays kept with the
    map besides those the fit makes (:data:`FIT_KEYS`, dropped from it);
    ``reference``: the map's provenance (JSON text). ``progress``, ``refine``
    and ``plan`` are :func:`rhythmic_jax.fitting.fit_map.fit`'s.
    """
    name = "reference features"
    check_settings(config)  # as the command line checks its options
    x = check_features(shape_checked(X, name), name)
    if scale not in SCALES:
        raise InputError(f"scale must be one of {SCALES}, got {scale!r}")
    kept = {k: v for k, v in (extra or {}).items() if k not in FIT_KEYS}
    if scale == "standardize" and embedding is not None:
        raise InputError(
            "scale='standardize' with an embedding: the embedding takes "
            "the descriptors as they are; use scale='refuse' or 'auto'"
        )
    unscaled = scale == "auto" and embedding is None and not_of_order_one(x)
    if scale == "standardize" or unscaled:
        kept.update(standardize(x))
        x = standardized(x, kept)
    labels = None
    if y is not None:  # places numbered in the order of their labels
        places, labels = np.unique(place_labels(y, len(x)), return_inverse=True)
        if not np.array_equal(places, np.arange(len(places))):
            kept["place_labels"] = places
    n = len(x) if labels is None else int(labels.max()) + 1
    if n < 2:
        raise InputError(
            f"{name}: {n} place (n_samples = {len(x)}); a map needs at least 2"
        )
    got = fit_map(x, config, labels=labels, embedding=embedding,
                  progress=progress, refine=refine, plan=plan)  # fmt: skip
    return replace(got, extra=kept, reference=reference)
