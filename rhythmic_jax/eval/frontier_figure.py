"""Recall per byte: recall@1 against storage, the upper frontier of the points
drawn as a step line (``rhythmic-jax frontier --plot``, and the last panel of
``evaluate --plot`` for a map with codes).

:func:`plot_frontier` draws one panel per sequence length; :func:`frontier_panel`
draws one on a given axes; :func:`fitted_recall_axis` and :func:`fitted_log_axis`
fit an axis to the points.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import Any

from rhythmic_jax.errors import InputError
from rhythmic_jax.eval.figure_canvas import finish, new_figure

__all__ = ["fitted_log_axis", "fitted_recall_axis", "frontier_panel", "plot_frontier"]


_KIND_STYLE = {
    "map": ("o", "tab:blue"),
    "codes": ("s", "tab:orange"),
    "hybrid": ("^", "tab:green"),
    "brute force": ("*", "black"),
    "SeqSLAM": ("P", "tab:red"),
}


def _short(name: str) -> str:
    """A row's name without its periods: ``map r=2 level 2 int8 + ITQ 64``."""
    import re

    return re.sub(r" \([\d, ]+\)", "", name)


def fitted_recall_axis(ax, values: Sequence[float]) -> None:
    """Recall from 0 to a little above the largest value: 0-1 when it passes
    0.6, else a tenth (0.05 below 0.3) rounded up past it."""
    top = max(values, default=1.0)
    if top > 0.6:
        ax.set_ylim(0, 1.02)
        return
    step = 0.05 if top < 0.3 else 0.1
    ax.set_ylim(0, step * (int(top / step) + 1))


def fitted_log_axis(axis, lo: float, hi: float) -> None:
    """A log axis whose labels do not run into each other: decades with no
    minor labels over two decades or more, else 1-2-5 steps written out."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    axis.set_minor_formatter(NullFormatter())
    if hi / max(lo, 1e-12) < 100:
        axis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
        axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:,.6g}"))


def frontier_panel(
    ax,
    rows: Sequence[Mapping[str, Any]],
    length: int = 1,
    per_place: bool = False,
    budget: float | None = None,
) -> None:
    """Draw recall@1 at sequence ``length`` against storage on ``ax``: one marker
    per kind, the upper frontier of the points as a step line and its points
    labelled with their names (where neighbours crowd, the first of them).
    Storage is the share of the float32 database in
    %, or bytes per place (``per_place``); ``budget`` (bytes per place, with
    ``per_place``) is drawn as a dashed line. The recall axis spans 0 to a
    little above the best value, the storage axis the points."""
    key = f"recall@1 L={length}"

    def size(r):
        return r["bytes_per_place"] if per_place else 100 * r["share"]

    pts = [r for r in rows if r.get(key) is not None]
    for kind, (marker, colour) in _KIND_STYLE.items():
        sel = [r for r in pts if r["kind"] == kind]
        if sel:
            ax.scatter(
                [size(r) for r in sel],
                [r[key] for r in sel],
                marker=marker,
                color=colour,
                label=kind,
                s=28,
            )
    best, front = -1.0, []
    for r in sorted(pts, key=lambda r: (r["share"], -r[key])):
        if r[key] > best:
            best = r[key]
            front.append(r)
    if front:
        xs, ys = [size(r) for r in front], [r[key] for r in front]
        ax.step(xs, ys, where="post", color="grey", lw=1.5, alpha=0.8,
                label="best within the bytes")  # fmt: skip
        span = max(ys) - min(ys) or 1.0
        last = None
        for i, r in enumerate(front):  # crowded neighbours keep one label
            x, y = size(r), r[key]
            if last is not None and x < 2 * last[0] and y - last[1] < 0.1 * span:
                continue
            last = (x, y)
            ax.annotate(_short(r.get("name", r["kind"])), (x, y), fontsize=5.5,
                        xytext=(4, -9 if i % 2 else 4), textcoords="offset points",
                        color="dimgrey")  # fmt: skip
    if budget is not None and per_place:
        ax.axvline(float(budget), ls="--", lw=1, color="tab:red",
                   label=f"budget {float(budget):,.6g} B/place")  # fmt: skip
    ax.set_xscale("log")
    if pts:
        sizes = [size(r) for r in pts] + ([float(budget)] if budget and per_place
                                          else [])  # fmt: skip
        lo, hi = min(sizes), max(sizes)
        ax.set_xlim(lo / 1.4, hi * 1.6)  # room for the labels
        fitted_log_axis(ax.xaxis, lo, hi)
    fitted_recall_axis(ax, [r[key] for r in pts])
    ax.set_xlabel(
        "bytes per place (log)" if per_place else "storage, % of the float32 database"
    )
    ax.set_ylabel(f"recall@1, L = {length}")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)


def plot_frontier(
    rows: Sequence[Mapping[str, Any]],
    path: str | os.PathLike | None = None,
    lengths: Sequence[int] = (1,),
    title: str = "",
    per_place: bool = False,
    budget: float | None = None,
):
    """Recall@1 against storage (share of the float32 database, log scale), one
    panel per sequence length, one marker per kind (map, codes, hybrid, brute force)
    and the upper frontier of every point drawn as a step line, its points
    labelled (:func:`frontier_panel`; ``budget``: bytes per place, drawn).

    Args:
      rows: ``{"kind", "share", "recall@1 L=<L>"}`` per representation (as
        :func:`rhythmic_jax.eval.frontier.frontier_rows` and ``rhythmic-jax evaluate``
        give them; a row without a length's recall is left out of that panel).
      per_place: storage as bytes per place (rows need ``bytes_per_place``).
    """
    if not rows:
        raise InputError("plot_frontier: no rows to plot")
    fig, axes = new_figure(len(lengths), width=5.2 if per_place else 4.4)
    for ax, length in zip(axes, lengths, strict=True):
        frontier_panel(ax, rows, length, per_place, budget)
    fig.suptitle(title or "recall per byte")
    return finish(fig, path)
