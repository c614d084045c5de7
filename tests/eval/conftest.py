"""Fixtures of the figure tests."""

from __future__ import annotations

import pytest


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
