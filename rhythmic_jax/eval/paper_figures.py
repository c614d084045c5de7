"""The paper's figures from a reproduction's numbers, and the costs beside them.

Every function takes plain numbers (as ``scripts/reproduce.py`` stores them in
``reports/reproduction.json``), returns a ``matplotlib.figure.Figure`` on the
Agg canvas (:mod:`rhythmic_jax.eval.figure_canvas`) and writes a PNG when given
``path``.

- :func:`plot_training_error`: training error against period length (paper
  Fig. 3), one series per level of candidates, chosen periods marked.
- :func:`plot_r`: compression ratio and accuracy against r (paper Fig. 4).
- :func:`plot_augmentation`: accuracy of each augmentation, alone and merged,
  beside the plain map and brute force (paper Fig. 6).
- :func:`plot_levels`: accuracy against the period level T = c sqrt N, with
  brute force as a reference line and the compression ratio (paper Fig. 8).
- :func:`plot_storage_growth`: bytes against places N (paper Fig. 2 style).
- :func:`plot_cost`: seconds per fit split into its parts (the augmentation
  ablation's cost).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import Any

from rhythmic_jax.errors import InputError
from rhythmic_jax.eval.figure_canvas import finish, new_figure

__all__ = [
    "plot_augmentation",
    "plot_cost",
    "plot_levels",
    "plot_r",
    "plot_storage_growth",
    "plot_training_error",
]


def plot_training_error(
    series: Mapping[str, tuple[Sequence[int], Sequence[float], Sequence[int]]],
    title: str = "",
    path: str | os.PathLike | None = None,
):
    """Training error (%) against period length, paper Fig. 3.

    Args:
      series: label -> (candidate periods (c,), training errors (c,) as fractions,
        chosen periods); one line per label (e.g. ``"level 1"``), the chosen
        periods drawn as filled markers.
      title: axes title.
      path: PNG to write, or None.
    """
    if not series:
        raise InputError("plot_training_error: no series to plot")
    fig, (ax,) = new_figure()
    for label, (periods, errors, chosen) in series.items():
        if len(periods) != len(errors):
            raise InputError(
                f"series {label!r}: {len(periods)} periods, {len(errors)} errors"
            )
        pct = [100 * e for e in errors]
        (line,) = ax.plot(periods, pct, "o-", mfc="none", label=label)
        picked = [(t, e) for t, e in zip(periods, pct, strict=True) if t in set(chosen)]
        if picked:
            ax.plot(*zip(*picked, strict=True), "o", color=line.get_color())
    ax.set_xlabel("period length tau (frames)")
    ax.set_ylabel("training error (%)")
    ax.set_title(title or "training error against period length (filled: chosen)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return finish(fig, path)


def plot_r(
    rs: Sequence[int],
    ratios: Sequence[float],
    accuracies: Sequence[float],
    title: str = "",
    path: str | os.PathLike | None = None,
):
    """Compression ratio (left) and accuracy (right) against r, paper Fig. 4.

    Args:
      rs: numbers of periods (k,); ratios: map bytes over database bytes (k,);
      accuracies: self-query accuracy (k,).
    """
    if not len(rs) == len(ratios) == len(accuracies) or not len(rs):
        raise InputError("plot_r: rs, ratios and accuracies must have one equal length")
    fig, (left, right) = new_figure(2, width=4.2)
    labels = [str(r) for r in rs]
    left.bar(labels, ratios, color="tab:blue")
    left.set_ylabel("compression ratio (map / database)")
    right.bar(labels, accuracies, color="tab:orange")
    right.set_ylabel("accuracy (queries from the map)")
    right.set_ylim(0, 1.05)
    for ax, values, fmt in ((left, ratios, "{:.4f}"), (right, accuracies, "{:.3f}")):
        ax.set_xlabel("r (number of periods)")
        for x, v in zip(labels, values, strict=True):
            ax.annotate(fmt.format(v), (x, v), ha="center", va="bottom", fontsize=8)
    fig.suptitle(title or "r periods: compression against accuracy")
    return finish(fig, path)


def plot_augmentation(
    labels: Sequence[str],
    accuracies: Sequence[float],
    references: Mapping[str, float] | None = None,
    title: str = "",
    ylabel: str = "accuracy",
    path: str | os.PathLike | None = None,
):
    """Accuracy of each training variant as bars, paper Fig. 6.

    Args:
      labels: variants (k,), e.g. ``"none"``, each augmentation, ``"all merged"``.
      accuracies: their accuracies (k,).
      references: name -> accuracy drawn as horizontal lines (e.g. brute force).
    """
    if len(labels) != len(accuracies) or not len(labels):
        raise InputError("plot_augmentation: labels and accuracies must match")
    fig, (ax,) = new_figure(width=6.4)
    bars = ax.bar(range(len(labels)), accuracies, color="tab:green")
    ax.set_xticks(range(len(labels)), labels, rotation=35, ha="right", fontsize=8)
    for rect, v in zip(bars, accuracies, strict=True):
        ax.annotate(
            f"{v:.3f}",
            (rect.get_x() + rect.get_width() / 2, v),
            ha="center",
            va="bottom",
            fontsize=7,
        )
    styles = iter(("--", ":", "-."))
    for name, value in (references or {}).items():
        ax.axhline(
            value, ls=next(styles, "--"), color="k", lw=1, label=f"{name} {value:.3f}"
        )
    if references:
        ax.legend(fontsize=8)
    ax.set_ylabel(ylabel)
    ax.set_title(title or "training with augmented frames")
    ax.grid(axis="y", alpha=0.3)
    return finish(fig, path)


def plot_levels(
    series: Mapping[str, dict[str, Any]],
    title: str = "",
    path: str | os.PathLike | None = None,
):
    """Accuracy (left) and compression ratio (right) against the level c of
    ``T = c sqrt N``, paper Fig. 8.

    Args:
      series: label -> ``{"levels": (k,), "accuracy": (k,), "ratio": (k,),
        "brute_force": float or None}``; brute force is drawn as a dashed line
        in the series' colour.
    """
    if not series:
        raise InputError("plot_levels: no series to plot")
    fig, (left, right) = new_figure(2, width=4.6)
    for label, s in series.items():
        (line,) = left.plot(s["levels"], s["accuracy"], "o-", label=f"map, {label}")
        if s.get("brute_force") is not None:
            left.axhline(
                s["brute_force"],
                ls="--",
                color=line.get_color(),
                lw=1,
                label=f"brute force, {label}",
            )
        right.plot(s["levels"], s["ratio"], "o-", color=line.get_color(), label=label)
    left.set_ylabel("accuracy")
    left.set_ylim(bottom=0)
    left.legend(fontsize=7)
    right.set_ylabel("compression ratio (map / database)")
    right.legend(fontsize=7)
    levels = sorted({lv for s in series.values() for lv in s["levels"]})
    for ax in (left, right):
        ax.set_xticks(levels)
        ax.set_xlabel("level c (T = c sqrt N)")
        ax.grid(alpha=0.3)
    fig.suptitle(title or "longer periods: accuracy against compression")
    return finish(fig, path)


def plot_cost(
    timings: Mapping[str, Mapping[str, float]],
    path: str | os.PathLike | None = None,
):
    """Seconds per fit split into its parts, and augmented frames per second.

    ``timings``: label -> ``{"fit": s, "total": s, "augment": s, "describe": s,
    "step": s, "frames_per_s": f}`` (a plain fit has ``fit`` only), as
    :func:`rhythmic_jax.eval.ablation.augmentation_ablation` returns them.
    """
    if not timings:
        raise InputError("plot_cost: no timings to plot")
    names, rows = list(timings), list(timings.values())
    parts = {
        "exact solve + period choice": [r["fit"] - r.get("total", 0.0) for r in rows],
        "augment": [r.get("augment", 0.0) for r in rows],
        "describe": [r.get("describe", 0.0) for r in rows],
        "optimiser steps": [r.get("step", 0.0) for r in rows],
    }
    used = [sum(p[i] for p in parts.values()) for i in range(len(rows))]
    parts["other"] = [r["fit"] - u for r, u in zip(rows, used, strict=True)]
    fig, (left, right) = new_figure(2, width=5.5, height=1 + 0.3 * len(names))
    start = [0.0] * len(names)
    for part, seconds in parts.items():
        left.barh(names, seconds, left=start, label=part)
        start = [a + b for a, b in zip(start, seconds, strict=True)]
    right.barh(names, [r.get("frames_per_s", 0.0) for r in rows], color="grey")
    right.sharey(left)
    left.invert_yaxis()
    fig.legend(loc="outside lower center", ncols=len(parts), fontsize=8)
    left.set_xlabel("seconds per fit")
    right.set_xlabel("augmented epochs: frames per second")
    return finish(fig, path)


def plot_storage_growth(
    ns: Sequence[int],
    curves: Mapping[str, Sequence[float]],
    d: int,
    fitted: tuple[int, Sequence[float], str] | None = None,
    path: str | os.PathLike | None = None,
):
    """Bytes against places N on log-log axes (paper Fig. 2 style).

    ``curves``: label -> bytes at every N of ``ns``; a label ``"... r = R"`` that
    starts with ``"rhythmic"`` gets a dotted ``N^(1/R)`` guide. ``fitted``:
    ``(N, bytes of each fitted map, label)`` drawn as points.
    """
    if not curves:
        raise InputError("plot_storage_growth: no curves to plot")
    fig, (ax,) = new_figure(width=6.5, height=4.5)
    for label, values in curves.items():
        (line,) = ax.loglog(ns, values, label=label)
        if label.startswith("rhythmic"):
            r = int(label.rsplit("=", 1)[1])
            guide = [0.4 * values[-1] * (n / ns[-1]) ** (1 / r) for n in ns]
            ax.loglog(
                ns, guide, ":", color=line.get_color(), lw=1, label=f"slope 1/{r}"
            )
    if fitted is not None:
        n, sizes, label = fitted
        ax.plot([n] * len(sizes), sizes, "ko", ms=4, label=label)
    ax.set_xlabel("places N")
    ax.set_ylabel("bytes")
    ax.set_title(f"storage growth at d = {d}")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    return finish(fig, path)
