"""Every figure, one import: the paper's, the evaluation's, recall per byte and
frames as images, each defined in the module of its figure.

Every function takes plain numbers (as ``scripts/reproduce.py`` stores them in
``reports/reproduction.json``, or as ``rhythmic-jax evaluate`` and ``frontier``
give them), returns a ``matplotlib.figure.Figure`` drawn on the Agg canvas, and
writes a PNG when given ``path`` (:mod:`rhythmic_jax.eval.figure_canvas`: no
``pyplot``, text drawn literally, written atomically).

- :mod:`rhythmic_jax.eval.paper_figures`: training error against period length
  (paper Fig. 3), r (Fig. 4), augmentations (Fig. 6), levels (Fig. 8), storage
  growth (Fig. 2 style) and the cost of a fit.
- :mod:`rhythmic_jax.eval.evaluation_figure`: PR curves, recall@N and the
  route, as ``rhythmic-jax evaluate --plot`` draws them.
- :mod:`rhythmic_jax.eval.frontier_figure`: recall@1 against storage.
- :mod:`rhythmic_jax.eval.image_figures`: augmented examples, matches side by side.
"""

from __future__ import annotations

from rhythmic_jax.eval.evaluation_figure import plot_evaluation as plot_evaluation
from rhythmic_jax.eval.evaluation_figure import recall_curve_panel as recall_curve_panel
from rhythmic_jax.eval.evaluation_figure import route_panel as route_panel
from rhythmic_jax.eval.figure_canvas import literal as literal
from rhythmic_jax.eval.figure_canvas import new_figure as new_figure
from rhythmic_jax.eval.figure_canvas import save_figure as save_figure
from rhythmic_jax.eval.frontier_figure import frontier_panel as frontier_panel
from rhythmic_jax.eval.frontier_figure import plot_frontier as plot_frontier
from rhythmic_jax.eval.image_figures import plot_examples as plot_examples
from rhythmic_jax.eval.image_figures import plot_matches as plot_matches
from rhythmic_jax.eval.paper_figures import plot_augmentation as plot_augmentation
from rhythmic_jax.eval.paper_figures import plot_cost as plot_cost
from rhythmic_jax.eval.paper_figures import plot_levels as plot_levels
from rhythmic_jax.eval.paper_figures import plot_r as plot_r
from rhythmic_jax.eval.paper_figures import plot_storage_growth as plot_storage_growth
from rhythmic_jax.eval.paper_figures import plot_training_error as plot_training_error

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
