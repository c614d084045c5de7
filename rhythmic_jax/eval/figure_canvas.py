"""The canvas every figure is drawn on: a matplotlib Figure on Agg, its text
drawn literally, written as a PNG atomically.

Figures are built without ``pyplot``, so no global backend is switched and a
notebook can show the returned figure as it is; matplotlib is imported only when
a function is called. Text is shown as it is written: a file name such as
``$x^2$_{a}%`` in a title, a caption, a legend or an annotation is drawn
literally, never as mathtext or TeX (:func:`literal`, applied to every figure
before it is returned or saved); only the numbers the axes' formatters write
keep their markup.
"""

from __future__ import annotations

import os
from pathlib import Path

from rhythmic_jax.errors import InputError
from rhythmic_jax.io.atomic import atomic_path

__all__ = ["finish", "literal", "new_figure", "save_figure"]


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


def finish(fig, path: str | os.PathLike | None):
    """``fig`` with its text drawn literally, written to ``path`` (a PNG) unless
    None: the last step of every figure."""
    literal(fig)
    if path is not None:
        save_figure(fig, path)
    return fig
