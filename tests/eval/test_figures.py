"""The one import of every figure gives each figure module's own functions."""

from __future__ import annotations

import importlib

from rhythmic_jax.eval import figures

MODULES = (
    "figure_canvas",
    "paper_figures",
    "evaluation_figure",
    "frontier_figure",
    "image_figures",
)


def test_every_figure_is_its_modules_own_object():
    """Each public name of ``figures`` is defined in one figure module (its
    ``__module__``) and is that module's object; every plot of those modules is
    importable from ``figures``."""
    owners = {}
    for name in figures.__all__:
        value = getattr(figures, name)
        module = importlib.import_module(value.__module__)
        assert module.__name__.rsplit(".", 1)[1] in MODULES, name
        assert getattr(module, name) is value, name
        owners[name] = module.__name__
    plots = {
        name
        for short in MODULES
        for name in importlib.import_module(f"rhythmic_jax.eval.{short}").__all__
        if name.startswith("plot_")
    }
    assert plots <= set(figures.__all__)
    assert len(set(owners.values())) == len(MODULES)
