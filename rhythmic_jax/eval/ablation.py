"""Augmentation ablation: maps trained plainly and over each augmentation,
judged on other-appearance queries beside brute force (paper Fig. 6; the
notebook ``notebooks/augmentation_ablation.ipynb`` draws it with
:func:`rhythmic_jax.eval.figures.plot_augmentation` and
:func:`rhythmic_jax.eval.figures.plot_cost`)."""

from __future__ import annotations

import time

import numpy as np

from rhythmic_jax.augment.stream import AugmentedFit, refining
from rhythmic_jax.decoding.held import HeldMap
from rhythmic_jax.eval.report import evaluate_map
from rhythmic_jax.fitting.prepare import fit_frames
from rhythmic_jax.frames.features import cached_describe
from rhythmic_jax.map.config import MapConfig

__all__ = ["augmentation_ablation"]


def augmentation_ablation(
    routes: dict[str, tuple[np.ndarray, np.ndarray, int]],
    variants: dict[str, tuple[str, ...]],
    descriptor,
    *,
    level: int = 1,
    epochs: int = 3,
    seed: int = 0,
) -> tuple[dict[str, dict[str, dict]], dict[str, dict[str, dict]]]:
    """Maps trained plainly and over each augmentation, judged on other-appearance
    queries beside brute force (paper Fig. 6).

    Args:
      routes: name -> (map frames uint8 (n, H, W, 3), query frames of the same
        places, frame tolerance).
      variants: label -> augmentation names (``("all",)``: the seven merged).
      descriptor: a :mod:`rhythmic_jax.frames.features` descriptor (cached per route).

    Returns:
      ``(results, timings)``: route -> label -> the map's metrics of
      :func:`rhythmic_jax.eval.report.evaluate_map` (``"plain map"``, ``"brute
      force"`` and each variant), and route -> label -> seconds (``"fit"`` and the
      augmented fit's own parts).
    """
    results: dict[str, dict[str, dict]] = {}
    timings: dict[str, dict[str, dict]] = {}
    for route, (frames, queries, tol) in routes.items():
        x_map = cached_describe(
            frames, descriptor, key=f"nb-{route}-map", progress=False
        )
        x_qry = cached_describe(
            queries, descriptor, key=f"nb-{route}-qry", progress=False
        )
        t0 = time.perf_counter()
        plain = HeldMap(fit_frames(x_map, MapConfig(level=level)))
        timings[route] = {"plain map": {"fit": time.perf_counter() - t0}}
        judged = evaluate_map(
            plain, x_qry, reference=x_map, tolerance=tol, timing=False
        )
        results[route] = {
            "plain map": judged["methods"]["map"],
            "brute force": judged["methods"]["brute force"],
        }
        for label, names in variants.items():
            config = AugmentedFit(names=names, epochs=epochs, seed=seed)
            t0 = time.perf_counter()
            spent: dict[str, float] = {}
            refine = refining(frames, x_map, np.arange(len(x_map)), descriptor,
                              config, timings=spent)  # fmt: skip
            model = HeldMap(fit_frames(x_map, MapConfig(level=level), refine=refine))
            timings[route][label] = {**spent, "fit": time.perf_counter() - t0}
            judged = evaluate_map(model, x_qry, tolerance=tol, timing=False)
            results[route][label] = judged["methods"]["map"]
    return results, timings
