"""Frames drawn as images: a grid of augmented examples, and matches side by side.

Each returns a ``matplotlib.figure.Figure`` on the Agg canvas
(:mod:`rhythmic_jax.eval.figure_canvas`) and writes a PNG when given ``path``.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import Any

from rhythmic_jax.errors import InputError
from rhythmic_jax.eval.figure_canvas import finish, new_figure

__all__ = ["plot_examples", "plot_matches"]


def plot_examples(
    rows: Mapping[str, Any], title: str = "", path: str | os.PathLike | None = None
):
    """A grid of frames: one row per label, uint8 (k, H, W, 3) images each.

    ``rows`` is e.g. ``{"original": frames, "hflip": ..., ...}`` from
    :func:`rhythmic_jax.augment.kornia_ops.augment_examples`.
    """
    if not rows:
        raise InputError("plot_examples: no rows to plot")
    count = max(len(images) for images in rows.values())
    fig, _ = new_figure(1, width=1.6 * count, height=0.8 * len(rows))
    fig.clear()
    axes = fig.subplots(len(rows), count, squeeze=False)
    for ax_row, (name, images) in zip(axes, rows.items(), strict=True):
        ax_row[0].set_ylabel(name, rotation=0, ha="right", fontsize=8)
        for ax, image in zip(ax_row, images, strict=False):
            ax.imshow(image)
        for ax in ax_row:
            ax.set_xticks([]), ax.set_yticks([])
    fig.suptitle(title)
    return finish(fig, path)


def plot_matches(
    rows: Sequence[Mapping[str, Any]],
    title: str = "",
    path: str | os.PathLike | None = None,
):
    """Matches side by side, one row per query: the query, the place chosen
    and the right place (``evaluate --matches``).

    ``rows``: ``{"query", "chosen", "right"}`` uint8 (H, W, 3) images (None:
    no match, or no right place in the map) and ``"titles"``, the three
    captions (query name, chosen place and its score, right place).
    """
    if not rows:
        raise InputError("plot_matches: no matches to draw")
    fig, _ = new_figure(1, width=7.0, height=1.6 * len(rows) + 0.4)
    fig.clear()
    axes = fig.subplots(len(rows), 3, squeeze=False)
    for ax_row, row in zip(axes, rows, strict=True):
        for ax, key, caption in zip(ax_row, ("query", "chosen", "right"),
                                    row["titles"], strict=True):  # fmt: skip
            image = row.get(key)
            if image is None:
                ax.text(0.5, 0.5, "none", ha="center", va="center", fontsize=8)
            else:
                ax.imshow(image)
            ax.set_title(caption, fontsize=6.5)
            ax.set_xticks([]), ax.set_yticks([])
    fig.suptitle(title or "query | place chosen | right place", fontsize=9)
    return finish(fig, path)
