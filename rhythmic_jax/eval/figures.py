"""Plots of the paper's figures from a reproduction's numbers (matplotlib, Agg).

Every function takes plain numbers (as ``scripts/reproduce.py`` stores them in
``reports/reproduction.json``), returns a ``matplotlib.figure.Figure`` drawn on the
Agg canvas, and writes a PNG when given ``path``. Figures are built without
``pyplot``, so no global backend is switched and a notebook can show the returned
figure as it is. matplotlib is imported only when a function is called.

- :func:`plot_training_error`: training error against period length (paper
  Fig. 3), one series per level of candidates, chosen periods marked.
- :func:`plot_r`: compression ratio and accuracy against r (paper Fig. 4).
- :func:`plot_augmentation`: accuracy of each augmentation, alone and merged,
  beside the plain map and brute force (paper Fig. 6).
- :func:`plot_levels`: accuracy against the period level T = c sqrt N, with
  brute force as a reference line and the compression ratio (paper Fig. 8).

Text is shown as it is written: a file name such as ``$x^2$_{a}%`` in a title,
a caption, a legend or an annotation is drawn literally, never as mathtext or
TeX (:func:`literal`, applied to every figure before it is returned or saved);
only the numbers the axes' formatters write keep their markup.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from rhythmic_jax.errors import InputError
from rhythmic_jax.io.atomic import atomic_path

__all__ = [
    "literal",
    "new_figure",
    "plot_augmentation",
    "plot_cost",
    "plot_examples",
    "plot_evaluation",
    "frontier_panel",
    "plot_frontier",
    "plot_levels",
    "plot_matches",
    "plot_r",
    "plot_storage_growth",
    "plot_training_error",
    "recall_curve_panel",
    "route_panel",
    "save_figure",
]


def new_figure(ncols: int = 1, width: float = 5.0, height: float = 3.6):
    """A Figure on an Agg canvas with ``ncols`` axes side by side: (fig, axes)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width * ncols, height), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, ncols, squeeze=False)[0]
    return fig, list(axes)


def literal(fig):
    """``fig`` with every text but the axes' tick labels drawn literally
    (``parse_math`` and ``usetex`` off): titles, captions, labels, legends and
    annotations may hold file names, and a ``$``, ``\\``, ``_`` or ``^`` in
    one is a character to show, not markup to parse. Tick labels and offsets
    are the formatters' own (log axes write ``$10^{2}$``) and keep theirs."""
    from matplotlib.axis import Axis, Tick
    from matplotlib.text import Text

    keep = {id(a.offsetText) for a in fig.findobj(Axis)}
    keep |= {id(t) for tick in fig.findobj(Tick) for t in tick.get_children()}
    for text in fig.findobj(Text):
        if id(text) not in keep:
            text.set_parse_math(False)
            text.set_usetex(False)
    return fig


def save_figure(fig, path: str | os.PathLike, dpi: int = 120) -> Path:
    """Write ``fig`` as a PNG at ``path`` atomically (temporary file, then
    rename), its text drawn literally (:func:`literal`)."""
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise InputError(f"figure path {path} must end in .png")
    literal(fig)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    return path


def _finish(fig, path):
    literal(fig)
    if path is not None:
        save_figure(fig, path)
    return fig


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
    return _finish(fig, path)


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
    return _finish(fig, path)


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
    return _finish(fig, path)


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
    return _finish(fig, path)


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
    return _finish(fig, path)


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
    return _finish(fig, path)


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
    return _finish(fig, path)


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
    return _finish(fig, path)


def recall_curve_panel(ax, methods: Mapping[str, Mapping[str, Any]]) -> None:
    """Recall at every N = 1..20 (``row["recall_curve"]``) of each method as a
    curve, its values at N = 1, 5, 10, 20 written beside the points."""
    for name, row in methods.items():
        curve = row["recall_curve"]
        ns = list(range(1, len(curve) + 1))
        marker = "o" if len(curve) == 1 else None  # SeqSLAM: one match per query
        (line,) = ax.plot(ns, curve, marker=marker, ms=3, label=name)
        for n in (1, 5, 10, 20):
            if n <= len(curve):
                ax.annotate(f"{curve[n - 1]:.2f}", (n, curve[n - 1]), fontsize=6,
                            xytext=(0, 4), textcoords="offset points",
                            ha="center", color=line.get_color())  # fmt: skip
    ax.set_xlim(0.5, 20.5)
    ax.set_xticks([1, 5, 10, 15, 20])
    ax.set_xlabel("N (places retrieved)")
    ax.set_ylabel("recall@N")
    ax.set_ylim(0, 1.08)
    ax.legend(fontsize=7)


def route_panel(ax, result: Mapping[str, Any], method: str = "map") -> None:
    """Predicted place against query index along the route: the right places
    as a grey band, the method's predictions green where right and red where
    wrong; no match (-1) drawn as crosses below the route."""
    right = result["right_places"]
    row = result["methods"][method]
    xs = [i for i, places in enumerate(right) for _ in places]
    ys = [p for places in right for p in places]
    ax.scatter(xs, ys, s=6, color="lightgrey", label="right places", rasterized=True)
    pred, ok = row["predictions"], row["correct"]
    for good, colour, what in ((True, "tab:green", "right"),
                               (False, "tab:red", "wrong")):  # fmt: skip
        sel = [i for i, p in enumerate(pred) if ok[i] == good and p >= 0]
        if sel:
            ax.scatter(sel, [pred[i] for i in sel], s=5, color=colour,
                       label=f"{row.get('label', method)}: {what}",
                       rasterized=True)  # fmt: skip
    missed = [i for i, p in enumerate(pred) if p < 0]
    if missed:
        ax.scatter(missed, [-0.03 * result.get("n", 1)] * len(missed), s=8,
                   marker="x", color="tab:red", lw=0.6,
                   label=f"no match ({len(missed)})")  # fmt: skip
    ax.set_xlabel("query index (along the route)")
    ax.set_ylabel("predicted place")
    ax.legend(fontsize=7, markerscale=2)


def plot_evaluation(
    result: Mapping[str, Any],
    title: str = "",
    path: str | os.PathLike | None = None,
):
    """PR curves (left) and recall@N (N = 1..20 as curves, or recall@K bars
    for results without ``recall_curve``) of each method of
    :func:`rhythmic_jax.eval.report.evaluate_map` (run with ``curves=True``),
    the map beside brute force, as ``rhythmic-jax evaluate --plot`` draws
    them; then the map's predicted place against query index along the route
    (results with ``right_places``); for a map with codes a last panel, recall
    against storage of the templates alone, the codes alone, both fused and
    brute force (``result["frontier"]``).
    """
    methods = {k: v for k, v in result["methods"].items() if "pr_curve" in v}
    if not methods:
        raise InputError("plot_evaluation: no PR curves (evaluate with curves=True)")
    frontier = result.get("frontier")
    route = "right_places" in result and "predictions" in methods.get("map", {})
    fig, axes = new_figure(2 + route + bool(frontier), width=4.6)
    left, right = axes[:2]
    if route:
        route_panel(axes[2], result)
    if frontier:  # a map with codes: recall per byte of its parts and of both
        frontier_panel(axes[-1], frontier, result.get("sequence") or 1)
    for name, row in methods.items():
        pr = row["pr_curve"]
        left.plot(
            pr["recall"],
            pr["precision"],
            label=f"{row.get('label', name)} (AUC {row['pr_auc']:.3f}, "
            f"R@100P {row['recall@100p']:.3f})",
        )
    if all("recall_curve" in row for row in methods.values()):
        recall_curve_panel(right, {row.get("label", k): row
                                   for k, row in methods.items()})  # fmt: skip
    else:
        _recall_bars(right, methods)
    left.set_xlabel("recall")
    left.set_ylabel("precision")
    left.set_xlim(0, 1.02)
    left.set_ylim(0, 1.02)
    left.legend(fontsize=7)
    for ax in axes:
        ax.grid(alpha=0.3)
    seq = result.get("sequence")
    fig.suptitle(
        title
        or f"decode={result.get('decode')} sequence={seq or 'off'}; "
        f"{(result.get('ground_truth') or {}).get('source', '')}",
        fontsize=9,
    )
    return _finish(fig, path)


def _recall_bars(ax, methods: Mapping[str, Mapping[str, Any]]) -> None:
    """recall@K bars of each method, for results that keep no curve."""
    ks = sorted(
        int(c.split("@")[1])
        for c in next(iter(methods.values()))
        if c.startswith("recall@") and c[7:].isdigit()
    )
    width = 0.8 / len(methods)
    for i, (name, row) in enumerate(methods.items()):
        xs = [j + (i - (len(methods) - 1) / 2) * width for j in range(len(ks))]
        # SeqSLAM gives one match per query: no bar beyond its recall@1
        vals = [row.get(f"recall@{k}", float("nan")) for k in ks]
        bars = ax.bar(xs, vals, width, label=name)
        text = ["" if v != v else f"{v:.2f}" for v in vals]  # NaN: no bar
        ax.bar_label(bars, labels=text, fontsize=7)
    ax.set_xticks(range(len(ks)), [f"R@{k}" for k in ks])
    ax.set_ylim(0, 1.1)
    ax.set_ylabel("recall@K")
    ax.legend(fontsize=7)


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
    return _finish(fig, path)
