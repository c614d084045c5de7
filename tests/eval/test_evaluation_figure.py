"""The evaluation's figure: PR curves, recall@N and the route hold the result's
numbers."""

from __future__ import annotations

import struct

import matplotlib
import pytest

from rhythmic_jax.errors import InputError
from rhythmic_jax.eval.evaluation_figure import plot_evaluation

matplotlib.use("Agg")

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def png_size(data: bytes) -> tuple[int, int]:
    """(width, height) from the IHDR chunk of a PNG."""
    assert data[:8] == PNG_MAGIC
    assert data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


def bar_heights(ax) -> list[float]:
    return [p.get_height() for p in ax.patches]


# -------------------------------------------------------------- plot_evaluation
def test_plot_evaluation_curves_bars_and_png(keep, tmp_path):
    def row(auc, r100, recalls, precision, recall):
        return {
            "pr_auc": auc,
            "recall@100p": r100,
            **{f"recall@{k}": v for k, v in zip((1, 5, 10), recalls, strict=True)},
            "pr_curve": {"precision": precision, "recall": recall},
        }

    result = {
        "decode": "hard",
        "sequence": 5,
        "ground_truth": {"source": "positions q.csv"},
        "methods": {
            "map": row(0.8, 0.3, (0.6, 0.8, 0.9), [0.5, 0.75, 1.0], [0.6, 0.3, 0.0]),
            "brute force": row(0.9, 0.4, (0.7, 0.9, 1.0), [0.7, 1.0], [0.7, 0.0]),
        },
    }
    fig = keep(plot_evaluation(result, path=tmp_path / "e.png"))
    left, right = fig.axes
    lines = left.get_lines()
    assert [list(ln.get_xdata()) for ln in lines] == [[0.6, 0.3, 0.0], [0.7, 0.0]]
    assert [list(ln.get_ydata()) for ln in lines] == [[0.5, 0.75, 1.0], [0.7, 1.0]]
    assert bar_heights(right) == [0.6, 0.8, 0.9, 0.7, 0.9, 1.0]
    assert [t.get_text() for t in right.get_xticklabels()] == ["R@1", "R@5", "R@10"]
    legend = [t.get_text() for t in left.get_legend().get_texts()]
    assert legend[0] == "map (AUC 0.800, R@100P 0.300)"
    assert "sequence=5" in fig._suptitle.get_text()
    assert png_size((tmp_path / "e.png").read_bytes())[0] > 0
    with pytest.raises(InputError, match="no PR curves"):
        plot_evaluation({"methods": {"map": {"pr_auc": 1.0}}})


def test_plot_evaluation_draws_recall_at_every_n_and_the_route(tmp_path):
    """With the curves evaluate keeps: recall@N for N = 1..20 as lines, and the
    predicted place against query index (right green, wrong red, no match as
    crosses) over the right places."""
    rows = {
        name: {
            "pr_auc": 0.5, "recall@100p": 0.1, "recall@1": curve[0],
            "pr_curve": {"precision": [1.0, 0.5], "recall": [0.0, 0.5]},
            "recall_curve": curve, "predictions": pred,
            "correct": [p == i for i, p in enumerate(pred)],
        }
        for name, curve, pred in (
            ("map", [0.25, 0.5, 0.75, 1.0], [0, 3, -1, 3]),
            ("brute force", [0.5] * 20, [0, 1, 2, 0]),
        )
    }  # fmt: skip
    result = {"n": 4, "methods": rows, "right_places": [[0], [1], [2], [3]]}
    fig = plot_evaluation(result, path=tmp_path / "e.png")
    assert len(fig.axes) == 3
    middle, route = fig.axes[1], fig.axes[2]
    curves = [list(line.get_ydata()) for line in middle.get_lines()]
    assert curves == [[0.25, 0.5, 0.75, 1.0], [0.5] * 20]
    assert list(middle.get_lines()[1].get_xdata()) == list(range(1, 21))
    grey, green, red, crosses = route.collections
    assert grey.get_offsets().tolist() == [[0, 0], [1, 1], [2, 2], [3, 3]]
    assert green.get_offsets().tolist() == [[0, 0], [3, 3]]
    assert red.get_offsets().tolist() == [[1, 3]]
    assert crosses.get_offsets()[:, 0].tolist() == [2]

