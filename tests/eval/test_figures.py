"""Figures hold the numbers they were given, and save_figure writes real PNGs."""

from __future__ import annotations

import struct

import matplotlib
import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import to_rgba

from rhythmic_jax.errors import InputError
from rhythmic_jax.eval.figures import (
    new_figure,
    plot_augmentation,
    plot_evaluation,
    plot_levels,
    plot_r,
    plot_training_error,
    save_figure,
)

matplotlib.use("Agg")

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture
def keep():
    """Collects the figures a test makes and clears them afterwards."""
    figures = []

    def add(fig):
        figures.append(fig)
        return fig

    yield add
    for fig in figures:
        fig.clear()


def png_size(data: bytes) -> tuple[int, int]:
    """(width, height) from the IHDR chunk of a PNG."""
    assert data[:8] == PNG_MAGIC
    assert data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


def bar_heights(ax) -> list[float]:
    return [p.get_height() for p in ax.patches]


def texts(ax) -> list[str]:
    return [t.get_text() for t in ax.texts]


# ------------------------------------------------------------------- new_figure
@pytest.mark.parametrize("ncols", [1, 3])
def test_new_figure_has_ncols_axes_on_agg(keep, ncols):
    fig, axes = new_figure(ncols, width=2.0, height=1.5)
    keep(fig)
    assert isinstance(fig.canvas, FigureCanvasAgg)
    assert isinstance(axes, list) and len(axes) == ncols
    assert fig.axes == axes
    np.testing.assert_allclose(fig.get_size_inches(), [2.0 * ncols, 1.5])
    # side by side, left to right
    lefts = [ax.get_position().x0 for ax in axes]
    assert lefts == sorted(lefts)


# ------------------------------------------------------------------ save_figure
def test_save_figure_writes_png_and_creates_folders(keep, tmp_path):
    fig, (ax,) = new_figure(width=5.0, height=3.6)
    keep(fig)
    ax.plot([0, 1], [1, 0])
    path = tmp_path / "a" / "b" / "fig.png"
    out = save_figure(fig, path, dpi=100)
    assert out == path and path.is_file()
    data = path.read_bytes()
    assert len(data) > 1000
    assert png_size(data) == (500, 360)
    assert sorted(p.name for p in path.parent.iterdir()) == ["fig.png"]  # no temp


def test_save_figure_dpi_overwrite_and_str_path(keep, tmp_path):
    fig, _ = new_figure(width=2.0, height=1.0)
    keep(fig)
    path = tmp_path / "f.PNG"
    save_figure(fig, str(path), dpi=50)
    assert png_size(path.read_bytes()) == (100, 50)
    save_figure(fig, path, dpi=80)  # replaced in place
    assert png_size(path.read_bytes()) == (160, 80)
    assert [p.name for p in tmp_path.iterdir()] == ["f.PNG"]


@pytest.mark.parametrize("name", ["fig.jpg", "fig", "fig.png.txt"])
def test_save_figure_refuses_other_suffixes(keep, tmp_path, name):
    fig, _ = new_figure()
    keep(fig)
    path = tmp_path / "sub" / name
    with pytest.raises(InputError, match=r"^figure path .* must end in \.png$"):
        save_figure(fig, path)
    assert not (tmp_path / "sub").exists()


# ---------------------------------------------------------- plot_training_error
def test_plot_training_error_lines_and_chosen_markers(keep):
    series = {
        "level 1": ([10, 11, 12, 13], [0.1, 0.2, 0.05, 0.3], [12, 10]),
        "level 2": ([20, 21], [0.4, 0.25], []),
    }
    fig = keep(plot_training_error(series))
    (ax,) = fig.axes
    lines = ax.get_lines()
    assert len(lines) == 3  # two series, one set of chosen markers
    main1, picked, main2 = lines
    np.testing.assert_array_equal(main1.get_xdata(), [10, 11, 12, 13])
    np.testing.assert_allclose(main1.get_ydata(), [10, 20, 5, 30])
    np.testing.assert_array_equal(picked.get_xdata(), [10, 12])
    np.testing.assert_allclose(picked.get_ydata(), [10, 5])
    np.testing.assert_array_equal(main2.get_xdata(), [20, 21])
    np.testing.assert_allclose(main2.get_ydata(), [40, 25])
    assert to_rgba(picked.get_color()) == to_rgba(main1.get_color())
    assert to_rgba(main1.get_color()) != to_rgba(main2.get_color())
    assert main1.get_markerfacecolor() == "none"  # hollow candidates
    assert picked.get_linestyle() == "None"  # chosen: markers only
    assert [t.get_text() for t in ax.get_legend().get_texts()] == [
        "level 1",
        "level 2",
    ]
    assert ax.get_xlabel() == "period length tau (frames)"
    assert ax.get_ylabel() == "training error (%)"
    assert ax.get_title() == "training error against period length (filled: chosen)"


def test_plot_training_error_title_and_path(keep, tmp_path):
    path = tmp_path / "out" / "fig3.png"
    fig = keep(plot_training_error({"a": ([5, 6], [0.5, 0.5], [6])}, "T", path))
    assert fig.axes[0].get_title() == "T"
    assert path.read_bytes()[:8] == PNG_MAGIC


def test_plot_training_error_refusals():
    with pytest.raises(InputError, match=r"^plot_training_error: no series to plot$"):
        plot_training_error({})
    with pytest.raises(InputError, match=r"^series 'bad': 3 periods, 2 errors$"):
        plot_training_error({"bad": ([1, 2, 3], [0.1, 0.2], [])})


# ----------------------------------------------------------------------- plot_r
def test_plot_r_bars_annotations_and_labels(keep):
    rs, ratios, accs = [2, 3, 5], [0.0123, 0.0045, 0.0012], [0.93, 0.8, 0.555]
    fig = keep(plot_r(rs, ratios, accs))
    left, right = fig.axes
    np.testing.assert_allclose(bar_heights(left), ratios)
    np.testing.assert_allclose(bar_heights(right), accs)
    fig.canvas.draw()
    for ax in (left, right):
        assert [t.get_text() for t in ax.get_xticklabels()] == ["2", "3", "5"]
        assert ax.get_xlabel() == "r (number of periods)"
    assert texts(left) == ["0.0123", "0.0045", "0.0012"]
    assert texts(right) == ["0.930", "0.800", "0.555"]
    np.testing.assert_allclose([t.xy[1] for t in right.texts], accs)
    assert left.get_ylabel() == "compression ratio (map / database)"
    assert right.get_ylabel() == "accuracy (queries from the map)"
    assert right.get_ylim() == pytest.approx((0, 1.05))
    assert fig.get_suptitle() == "r periods: compression against accuracy"


def test_plot_r_title_and_path(keep, tmp_path):
    path = tmp_path / "r.png"
    fig = keep(plot_r([2], [0.5], [1.0], title="Fig. 4", path=path))
    assert fig.get_suptitle() == "Fig. 4"
    assert path.read_bytes()[:8] == PNG_MAGIC


@pytest.mark.parametrize(
    ("rs", "ratios", "accs"),
    [([2, 3], [0.1], [0.5, 0.6]), ([2], [0.1], [0.5, 0.6]), ([], [], [])],
)
def test_plot_r_refuses_unequal_or_empty(rs, ratios, accs):
    msg = r"^plot_r: rs, ratios and accuracies must have one equal length$"
    with pytest.raises(InputError, match=msg):
        plot_r(rs, ratios, accs)


# ----------------------------------------------------------- plot_augmentation
def test_plot_augmentation_bars_ticks_and_references(keep):
    labels = ["none", "crop", "all merged"]
    accs = [0.5, 0.625, 0.75]
    refs = {"brute force": 0.9, "plain": 0.25}
    fig = keep(plot_augmentation(labels, accs, refs, ylabel="acc"))
    (ax,) = fig.axes
    np.testing.assert_allclose(bar_heights(ax), accs)
    np.testing.assert_allclose(
        [p.get_x() + p.get_width() / 2 for p in ax.patches], [0, 1, 2]
    )
    assert [t.get_text() for t in ax.get_xticklabels()] == labels
    assert texts(ax) == ["0.500", "0.625", "0.750"]
    np.testing.assert_allclose(
        [t.xy for t in ax.texts], [[0, 0.5], [1, 0.625], [2, 0.75]]
    )
    lines = ax.get_lines()
    assert [list(line.get_ydata()) for line in lines] == [[0.9, 0.9], [0.25, 0.25]]
    assert [line.get_linestyle() for line in lines] == ["--", ":"]
    assert [t.get_text() for t in ax.get_legend().get_texts()] == [
        "brute force 0.900",
        "plain 0.250",
    ]
    assert ax.get_ylabel() == "acc"
    assert ax.get_title() == "training with augmented frames"


def test_plot_augmentation_without_references(keep, tmp_path):
    path = tmp_path / "deep" / "fig6.png"
    fig = keep(plot_augmentation(["a"], [0.4], title="Fig. 6", path=path))
    (ax,) = fig.axes
    assert ax.get_lines() == [] and ax.get_legend() is None
    assert ax.get_ylabel() == "accuracy" and ax.get_title() == "Fig. 6"
    np.testing.assert_allclose(bar_heights(ax), [0.4])
    assert path.read_bytes()[:8] == PNG_MAGIC


@pytest.mark.parametrize(("labels", "accs"), [(["a", "b"], [0.1]), ([], [])])
def test_plot_augmentation_refusals(labels, accs):
    msg = r"^plot_augmentation: labels and accuracies must match$"
    with pytest.raises(InputError, match=msg):
        plot_augmentation(labels, accs)


# ------------------------------------------------------------------ plot_levels
def test_plot_levels_lines_reference_and_ticks(keep):
    series = {
        "summer": {
            "levels": [1, 2, 4],
            "accuracy": [0.9, 0.95, 0.97],
            "ratio": [0.02, 0.04, 0.08],
            "brute_force": 0.99,
        },
        "winter": {
            "levels": [1, 3],
            "accuracy": [0.3, 0.4],
            "ratio": [0.021, 0.06],
            "brute_force": None,
        },
    }
    fig = keep(plot_levels(series))
    left, right = fig.axes
    map_s, bf_s, map_w = left.get_lines()
    np.testing.assert_array_equal(map_s.get_xdata(), [1, 2, 4])
    np.testing.assert_allclose(map_s.get_ydata(), [0.9, 0.95, 0.97])
    np.testing.assert_allclose(bf_s.get_ydata(), [0.99, 0.99])
    assert bf_s.get_linestyle() == "--"
    assert to_rgba(bf_s.get_color()) == to_rgba(map_s.get_color())
    np.testing.assert_array_equal(map_w.get_xdata(), [1, 3])
    np.testing.assert_allclose(map_w.get_ydata(), [0.3, 0.4])
    ratio_s, ratio_w = right.get_lines()
    np.testing.assert_allclose(ratio_s.get_ydata(), [0.02, 0.04, 0.08])
    np.testing.assert_allclose(ratio_w.get_ydata(), [0.021, 0.06])
    assert to_rgba(ratio_s.get_color()) == to_rgba(map_s.get_color())
    assert to_rgba(ratio_w.get_color()) == to_rgba(map_w.get_color())
    assert [t.get_text() for t in left.get_legend().get_texts()] == [
        "map, summer",
        "brute force, summer",
        "map, winter",
    ]
    assert [t.get_text() for t in right.get_legend().get_texts()] == [
        "summer",
        "winter",
    ]
    for ax in (left, right):
        np.testing.assert_array_equal(ax.get_xticks(), [1, 2, 3, 4])
        assert ax.get_xlabel() == "level c (T = c sqrt N)"
    assert left.get_ylim()[0] == 0
    assert left.get_ylabel() == "accuracy"
    assert right.get_ylabel() == "compression ratio (map / database)"
    assert fig.get_suptitle() == "longer periods: accuracy against compression"


def test_plot_levels_title_and_path_and_refusal(keep, tmp_path):
    path = tmp_path / "x" / "fig8.png"
    one = {"s": {"levels": [1], "accuracy": [0.5], "ratio": [0.1]}}
    fig = keep(plot_levels(one, title="Fig. 8", path=path))
    assert fig.get_suptitle() == "Fig. 8"
    assert len(fig.axes[0].get_lines()) == 1  # no brute_force key: no line
    assert path.read_bytes()[:8] == PNG_MAGIC
    with pytest.raises(InputError, match=r"^plot_levels: no series to plot$"):
        plot_levels({})


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


def test_plot_frontier_writes_a_png(tmp_path):
    from rhythmic_jax.eval.figures import plot_frontier

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
    from rhythmic_jax.eval.figures import plot_frontier

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


def test_plot_storage_growth_returns_the_figure_and_saves_it(keep, tmp_path):
    from rhythmic_jax.eval.figures import plot_storage_growth

    ns = [100, 1000, 10000]
    curves = {"brute force": [4e5, 4e6, 4e7], "rhythmic map, r = 2": [8e4, 2.5e5, 8e5]}
    fig = keep(
        plot_storage_growth(
            ns, curves, 1024, (1000, [2e5], "fitted"), tmp_path / "s.png"
        )
    )
    assert png_size((tmp_path / "s.png").read_bytes())[0] > 0
    (ax,) = fig.axes
    labels = [line.get_label() for line in ax.lines]
    assert labels == ["brute force", "rhythmic map, r = 2", "slope 1/2", "fitted"]
    # the guide has slope 1/2 on log-log axes
    guide = ax.lines[2].get_ydata()
    np.testing.assert_allclose(np.log10(guide[-1] / guide[0]), 1.0)
    with pytest.raises(InputError, match="no curves"):
        plot_storage_growth(ns, {}, 1024)


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


def test_plot_matches_draws_three_frames_a_query(tmp_path):
    from rhythmic_jax.eval.figures import plot_matches

    frame = np.zeros((8, 16, 3), np.uint8)
    rows = [{"query": frame, "chosen": frame, "right": frame,
             "titles": ("query 0: right", "chosen: place 0", "right: place 0")},
            {"query": frame, "chosen": None, "right": frame,
             "titles": ("query 1: wrong", "chosen: no match", "right: place 1")}]
    fig = plot_matches(rows, path=tmp_path / "m.png")
    assert len(fig.axes) == 6 and (tmp_path / "m.png").stat().st_size > 1000
    assert [ax.get_title() for ax in fig.axes[3:]] == list(rows[1]["titles"])
    assert len(fig.axes[4].images) == 0 and fig.axes[4].texts[0].get_text() == "none"
    with pytest.raises(InputError):
        plot_matches([])
