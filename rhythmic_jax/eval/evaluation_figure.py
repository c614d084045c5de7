"""The figure of ``rhythmic-jax evaluate --plot``: PR curves, recall@N and the
route, for each method of :func:`rhythmic_jax.eval.report.evaluate_map`.

:func:`plot_evaluation` draws the panels; :func:`recall_curve_panel` and
:func:`route_panel` draw one each on a given axes (a script's own figure).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import Any

from rhythmic_jax.errors import InputError
from rhythmic_jax.eval.figure_canvas import finish, new_figure
from rhythmic_jax.eval.frontier_figure import frontier_panel

__all__ = ["plot_evaluation", "recall_curve_panel", "route_panel"]


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
    return finish(fig, path)


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
