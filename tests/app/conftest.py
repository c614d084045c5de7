"""Fixtures of the command-line tests: a corridor-like layout of real frames."""

from __future__ import annotations

import pytest


@pytest.fixture()
def corridor(nordland_root, tmp_path):
    """A corridor-like layout of real frames: ``ref/`` 60 Nordland summer frames
    (every 8th of the first 480) and ``query/`` the winter frames of the same
    places, PNGs under the same names."""
    import shutil

    names = sorted(p.name for p in (nordland_root / "summer").iterdir())[:480:8]
    for folder, season in (("ref", "summer"), ("query", "winter")):
        (tmp_path / folder).mkdir()
        for name in names:
            shutil.copy(nordland_root / season / name, tmp_path / folder / name)
    return tmp_path
