"""Strict JAX for every test, and the location of the shared real data."""

from __future__ import annotations

import os
from pathlib import Path

import jax
import pytest

jax.config.update("jax_numpy_rank_promotion", "raise")

DATA_ROOT = Path(
    os.environ.get(
        "RHYTHMIC_DATA", Path(__file__).resolve().parents[1].parent / "shared" / "data"
    )
)
NORDLAND = DATA_ROOT / "nordland_64x32"
AERIAL = DATA_ROOT / "aerial_pairs"


@pytest.fixture(scope="session")
def nordland_root() -> Path:
    """``../shared/data/nordland_64x32``; the test is skipped when it is absent."""
    if not (NORDLAND / "summer").is_dir():
        pytest.skip(f"real Nordland frames not found at {NORDLAND} (set RHYTHMIC_DATA)")
    return NORDLAND


@pytest.fixture(scope="session")
def aerial_root() -> Path:
    """``../shared/data/aerial_pairs``; the test is skipped when it is absent."""
    if not AERIAL.is_dir():
        pytest.skip(f"real aerial pairs not found at {AERIAL} (set RHYTHMIC_DATA)")
    return AERIAL


@pytest.fixture(scope="session")
def nordland_patchnorm(nordland_root):
    """Patch-normalised 64x32 Nordland descriptors: (summer, winter), (3576, 2048)."""
    from rhythmic_jax.data import nordland
    from rhythmic_jax.features import describe, get_descriptor

    desc = get_descriptor("patchnorm")
    summer, winter = nordland(nordland_root, progress=False)
    return (
        describe(summer.images, desc, progress=False),
        describe(winter.images, desc, progress=False),
    )
