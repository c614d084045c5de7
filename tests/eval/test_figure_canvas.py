"""The canvas: Agg figures of the asked size, and save_figure writes real PNGs."""

from __future__ import annotations

import struct

import matplotlib
import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg

from rhythmic_jax.errors import InputError
from rhythmic_jax.eval.figure_canvas import new_figure, save_figure

matplotlib.use("Agg")

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def png_size(data: bytes) -> tuple[int, int]:
    """(width, height) from the IHDR chunk of a PNG."""
    assert data[:8] == PNG_MAGIC
    assert data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


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
