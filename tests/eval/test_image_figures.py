"""Frames as images: matches side by side, a caption above each frame."""

from __future__ import annotations

import matplotlib
import numpy as np
import pytest

from rhythmic_jax.errors import InputError
from rhythmic_jax.eval.image_figures import plot_matches

matplotlib.use("Agg")


def test_plot_matches_draws_three_frames_a_query(tmp_path):

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
