"""Strict JAX for every test, the compile cache shared by the suite's processes,
the location of the shared real data, and small images written to disk."""

from __future__ import annotations

import os
from pathlib import Path

import jax
import numpy as np
import pytest
import skimage.io

from rhythmic_jax.jit_cache import ENV, enable_compile_cache

jax.config.update("jax_numpy_rank_promotion", "raise")
# One compile cache for every worker and every command a test starts (they
# inherit the folder); RHYTHMIC_JAX_COMPILE_CACHE=0 runs the suite without it.
_COMPILE_CACHE = enable_compile_cache()
if _COMPILE_CACHE is not None:
    os.environ[ENV] = str(_COMPILE_CACHE)
# No background builds of the compiled network from tests that describe frames
# in private cache folders (minutes of CPU each); tests/frames/test_compiled.py turns
# them on where it tests them.
os.environ.setdefault("RHYTHMIC_JAX_NETWORK_BUILD", "0")

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


def _run_folder(tmp_path_factory, worker_id) -> Path:
    """The temporary folder of the whole run, shared by its pytest-xdist workers
    (a worker's own is one level down); not an older run's."""
    run = tmp_path_factory.getbasetemp()
    return run.parent if worker_id != "master" else run


def _described_once(nordland_root, tmp_path_factory, worker_id, name, desc, **kw):
    """(summer, winter) rows of every Nordland frame described by ``desc``, once
    for the whole run: the pytest-xdist workers share one cache folder and take
    turns under a file lock, so a worker that needs them while another computes
    them waits and then reads the other's files (``kw``: ``cached_describe``'s)."""
    import fcntl

    from rhythmic_jax.frames.features import cached_describe
    from rhythmic_jax.io.images import nordland

    shared = _run_folder(tmp_path_factory, worker_id)
    folder = shared / name
    folder.mkdir(exist_ok=True)
    with open(shared / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        return tuple(
            cached_describe(t.images, desc, f"nordland-{s}", cache_dir=folder, **kw)
            for t, s in zip(nordland(nordland_root), ("summer", "winter"), strict=True)
        )


@pytest.fixture(scope="session")
def nordland_patchnorm(nordland_root, tmp_path_factory, worker_id):
    """Patch-normalised 64x32 Nordland descriptors: (summer, winter), (3576, 2048),
    computed once for the whole run (:func:`_described_once`)."""
    from rhythmic_jax.frames.features import get_descriptor

    desc = get_descriptor("patchnorm")
    return _described_once(
        nordland_root, tmp_path_factory, worker_id, "nordland_patchnorm", desc
    )


@pytest.fixture(scope="session")
def nordland_lite0(nordland_root, tmp_path_factory, worker_id):
    """EfficientNet-Lite0 descriptors (default settings, the eager network) of every
    Nordland frame: (summer, winter), (3576, 10976) each, computed once for the
    whole run (:func:`_described_once`). Rows are those ``rhythmic-jax`` computes
    for the same frames in a cache folder of its own (the eager network runs in
    slices of 4 frames; any 4-aligned run of frames gives the same bits).
    """
    from rhythmic_jax.frames.compiled import CompilePolicy
    from rhythmic_jax.frames.features import get_descriptor

    desc = get_descriptor("efficientnet_lite0")
    return _described_once(
        nordland_root, tmp_path_factory, worker_id, "nordland_lite0", desc,
        compile=CompilePolicy("never"),
    )  # fmt: skip


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


@pytest.fixture(scope="session")
def small_vgg16():
    """``small_vgg16(path, seed=0) -> path``: a loadable VGG16 state dict of 0.7 MB.

    Every weight matrix (rows x fan-in) is a strided view ``base[7 i + j]`` of a
    short random vector (He-scaled), so the file stores the short vectors while
    the network gets full-size, distinct, non-degenerate layers.
    """
    import torch

    from rhythmic_jax.frames.nets import VGG16

    def make(path: Path, seed: int = 0) -> Path:
        with torch.device("meta"):
            own = VGG16().state_dict()
        gen = torch.Generator().manual_seed(seed)
        state = {}
        for key, v in own.items():
            if v.ndim == 1:
                state[key] = 0.01 * torch.randn(v.shape, generator=gen)
                continue
            rows, cols = v.shape[0], v[0].numel()
            base = torch.randn(7 * (rows - 1) + cols, generator=gen)
            base *= (2.0 / cols) ** 0.5
            state[key] = base.as_strided((rows, cols), (7, 1)).view(v.shape)
        path.parent.mkdir(parents=True, exist_ok=True)
        torch.save(state, path)
        return path

    return make


@pytest.fixture(scope="session")
def liblinear_objectives():
    """``f(x, y, c) -> (p,)``: liblinear's primal objective at LinearSVC's
    optimum for every ±1 column of y (p,): the intercept regularised as the
    weights and C unchanged, which is this package's objective."""
    from sklearn.svm import LinearSVC

    def objectives(x, y, c) -> np.ndarray:
        out = []
        for j in range(y.shape[1]):
            svc = LinearSVC(C=c, loss="squared_hinge", tol=1e-10, max_iter=200_000)
            svc.fit(x, y[:, j])
            w, b = svc.coef_[0], svc.intercept_[0]
            hinge = np.maximum(0.0, 1.0 - y[:, j] * (x @ w + b))
            out.append(0.5 * (w @ w + b * b) + c * np.sum(hinge * hinge))
        return np.array(out)

    return objectives
