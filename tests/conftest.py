"""Strict JAX for every test, the location of the shared real data, and small
images written to disk."""

from __future__ import annotations

import os
from pathlib import Path

import jax
import numpy as np
import pytest
import skimage.io

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


@pytest.fixture
def rgb():
    """``rgb(h, w)``: a random uint8 (h, w, 3) image (seeded per test)."""
    rng = np.random.default_rng(0)
    return lambda h, w: rng.integers(0, 256, (h, w, 3), dtype=np.uint8)


@pytest.fixture
def write_image():
    """``write_image(folder, name, image) -> path``: save it, making the folder."""

    def write(folder: Path, name: str, image: np.ndarray) -> Path:
        folder.mkdir(parents=True, exist_ok=True)
        skimage.io.imsave(folder / name, image, check_contrast=False)
        return folder / name

    return write
