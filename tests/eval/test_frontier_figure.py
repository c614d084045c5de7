"""Recall per byte: the frontier's steps, its axes fitted to the points."""

from __future__ import annotations

import matplotlib
import numpy as np
import pytest

from rhythmic_jax.errors import InputError
from rhythmic_jax.eval.frontier_figure import plot_frontier

matplotlib.use("Agg")


def test_plot_frontier_writes_a_png(tmp_path):

    rows = [
        {"kind": "map", "share": 0.04, "recall@1 L=1": 0.1, "recall@1 L=5": 0.4},
        {"kind": "codes", "share": 0.03, "recall@1 L=1": 0.2, "recall@1 L=5": 0.5},
        {"kind": "hybrid", "share": 0.07, "recall@1 L=1": 0.3, "recall@1 L=5": 0.6},
        {"kind": "brute force", "share": 1.0, "recall@1 L=1": 0.5},
    ]
    fig = plot_frontier(rows, tmp_path / "f.png", (1, 5))
    assert (tmp_path / "f.png").stat().st_size > 1000
    assert len(fig.axes) == 2
    # the frontier steps through the codes (0.03), then the hybrid (0.07)
    xs = fig.axes[0].lines[0].get_xdata()
    np.testing.assert_allclose(xs, [3.0, 7.0, 100.0])
    with pytest.raises(InputError):
        plot_frontier([], tmp_path / "g.png")


def test_frontier_axes_fit_the_data_label_the_front_and_draw_the_budget(tmp_path):
    """Recall under 0.15 is not drawn on 0-1; a route spanning less than two
    decades of bytes gets written-out 1-2-5 ticks, no minor labels; each point
    of the front carries its name (periods left out); the budget is a line."""

    rows = [
        {"kind": "map", "name": "map r=2 level 1 (11, 13) int8", "share": 0.1,
         "bytes_per_place": 60.0, "recall@1 L=1": 0.02},
        {"kind": "codes", "name": "ITQ 64 bits", "share": 0.2,
         "bytes_per_place": 120.0, "recall@1 L=1": 0.09},
        {"kind": "codes", "name": "PQ 8x6 bits", "share": 0.3,
         "bytes_per_place": 200.0, "recall@1 L=1": 0.05},
        {"kind": "brute force", "name": "brute force", "share": 1.0,
         "bytes_per_place": 512.0, "recall@1 L=1": 0.12},
    ]  # fmt: skip
    fig = plot_frontier(rows, tmp_path / "f.png", (1,), per_place=True, budget=150)
    (ax,) = fig.axes
    assert ax.get_ylim() == pytest.approx((0, 0.15))
    labels = {t.get_text() for t in ax.texts}
    assert labels == {"map r=2 level 1 int8", "ITQ 64 bits", "brute force"}
    assert [line.get_xdata()[0] for line in ax.lines[1:]] == [150.0]  # the budget
    fig.canvas.draw()
    ticks = [t.get_text() for t in ax.get_xticklabels() if t.get_text()]
    assert "100" in ticks and "200" in ticks
    assert not [t for t in ax.xaxis.get_minorticklabels() if t.get_text()]
    assert 60 / 1.4 == pytest.approx(ax.get_xlim()[0])
    rows[0]["recall@1 L=1"] = 0.9
    assert plot_frontier(rows, per_place=True).axes[0].get_ylim()[1] > 1

