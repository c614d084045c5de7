"""The paper's figures hold the numbers they were given."""

from __future__ import annotations

import struct

import matplotlib
import numpy as np
import pytest
from matplotlib.colors import to_rgba

from rhythmic_jax.errors import InputError
from rhythmic_jax.eval.paper_figures import (
    plot_augmentation,
    plot_levels,
    plot_r,
    plot_storage_growth,
    plot_training_error,
)

matplotlib.use("Agg")

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def png_size(data: bytes) -> tuple[int, int]:
    """(width, height) from the IHDR chunk of a PNG."""
    assert data[:8] == PNG_MAGIC
    assert data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


def bar_heights(ax) -> list[float]:
    return [p.get_height() for p in ax.patches]


def texts(ax) -> list[str]:
    return [t.get_text() for t in ax.texts]

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


def test_plot_storage_growth_returns_the_figure_and_saves_it(keep, tmp_path):

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
