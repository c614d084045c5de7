"""``rhythmic-jax demo``: a real-image route that needs no download.

Photographs bundled with scikit-image are laid out as one large mosaic and cut into
overlapping tiles in raster order, like the paper's aerial protocol: tile i is
place i. A second "traversal" of the same ground is the mosaic after a fixed
change of appearance (darker, lower contrast, blurred, sensor noise, shifted by a
few pixels). The demo fits a map on the first, localises the tiles of the second
and of the first, and prints storage, compression, accuracy and speed beside exact
brute-force search and a baseline at the map's own bytes (PCA or int8 per place,
:mod:`rhythmic_jax.eval.budget_peers`), then writes a report with a plot.
"""

from __future__ import annotations

import json
import logging
import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.io.atomic import atomic_path, write_file

__all__ = ["DemoConfig", "changed_appearance", "demo_mosaic", "run_demo"]

log = logging.getLogger(__name__)

PHOTOS = (
    "astronaut", "coffee", "chelsea", "rocket", "hubble_deep_field",
    "immunohistochemistry", "camera", "brick", "grass", "gravel", "coins",
    "moon", "clock", "horse", "page", "text",
)  # fmt: skip


@dataclass(frozen=True)
class DemoConfig:
    """The demo's route and map.

    ``rhythmic-jax demo`` uses the defaults: a 2 x 2 mosaic of 256-pixel photos cut
    into 32-pixel tiles every 16 pixels (961 places), patch-normalised 32 x 32
    descriptors (1024-d), r = 2 at level 2. ``--quick`` uses 192-pixel photos
    (529 places).
    """

    grid: int = 2
    photo: int = 256
    tile: int = 32
    stride: int = 16
    level: int = 2
    thumb: int = 32
    tolerance: int = 1

    @classmethod
    def quick(cls) -> DemoConfig:
        return cls(photo=192)


def demo_mosaic(grid: int = 3, photo: int = 384) -> np.ndarray:
    """A (grid*photo, grid*photo, 3) uint8 mosaic of scikit-image's photographs."""
    from skimage import data
    from skimage.color import gray2rgb
    from skimage.transform import resize

    tiles = []
    for name in PHOTOS[: grid * grid]:
        img = np.asarray(getattr(data, name)())
        if img.ndim == 2:
            img = gray2rgb(img)
        img = img[..., :3]
        side = min(img.shape[:2])
        img = img[:side, :side]
        tiles.append(
            resize(img, (photo, photo), anti_aliasing=True, preserve_range=True)
        )
    rows = [
        np.concatenate(tiles[r * grid : (r + 1) * grid], axis=1) for r in range(grid)
    ]
    return np.clip(np.concatenate(rows, axis=0), 0, 255).astype(np.uint8)


def changed_appearance(image: np.ndarray, seed: int = 0) -> np.ndarray:
    """The same ground at "another time": darker, flatter, blurred, noisy, shifted.

    Deterministic for a seed: gamma 1.25, contrast 0.85, Gaussian blur sigma 0.8,
    sensor noise sigma 4 grey levels, a shift of 1 pixel down and right.
    """
    from skimage.filters import gaussian

    x = image.astype(np.float64) / 255.0
    x = 0.85 * (x**1.25 - 0.5) + 0.5
    x = gaussian(x, sigma=0.8, channel_axis=-1)
    x = x + np.random.default_rng(seed).normal(0.0, 4.0 / 255.0, x.shape)
    x = np.roll(x, (1, 1), axis=(0, 1))
    return np.clip(x * 255.0, 0, 255).astype(np.uint8)


def _report_plot(path: Path, d: int, r: int, level: int, bars: dict) -> None:
    """Left: storage against N, map and brute force; right: the accuracies.

    Drawn on a bare Agg figure (no pyplot, no GUI backend) with fixed margins:
    ``tight_layout`` measured every tick label of both log axes again, which cost
    more than drawing the figure; the margins are those it chose for this
    figure's labels."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from rhythmic_jax.map.periods import (
        candidate_periods,
        database_bytes,
        storage_bytes,
    )

    ns = np.unique(np.logspace(2, 8, 40).astype(int))
    brute = [database_bytes(n, d) for n in ns]
    ours = [storage_bytes(candidate_periods(int(n), r, level)[:r], d) for n in ns]
    fig = Figure(figsize=(11, 4))
    FigureCanvasAgg(fig)
    fig.subplots_adjust(left=0.069, right=0.986, bottom=0.152, top=0.909, wspace=0.696)
    left, right = fig.subplots(1, 2)
    left.loglog(ns, brute, label="brute force: N d floats")
    left.loglog(ns, ours, label=f"rhythmic map: r={r}, level {level}")
    left.set_xlabel("places N")
    left.set_ylabel("bytes")
    left.set_title(f"storage growth, d = {d}")
    left.grid(True, which="both", alpha=0.3)
    left.legend()
    names = list(bars)
    colours = ["tab:orange" if ": map" in k else "grey" for k in names]
    right.barh(names, [bars[k] for k in names], color=colours)
    for i, k in enumerate(names):
        right.text(bars[k] + 0.01, i, f"{bars[k]:.3f}", va="center", fontsize=8)
    right.invert_yaxis()
    right.set_xlim(0, 1.1)
    right.set_xlabel("accuracy (within the tolerance)")
    right.set_title("localisation on this route")
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")


def fresh_folder(stem: str) -> Path:
    """A new folder ``STEM-K`` under the system's temporary folder, K the first
    number whose folder does not exist yet (made here, so never another's)."""
    import tempfile

    base = Path(tempfile.gettempdir())
    for k in range(1, 1_000_000):
        try:
            (base / f"{stem}-{k}").mkdir(mode=0o700)
        except FileExistsError:
            continue
        return base / f"{stem}-{k}"
    raise InputError(f"{base}: no fresh {stem}-K folder left; give {{opt:out}}")


def run_demo(
    out: str | Path | None = None,
    *,
    quick: bool = False,
    config: DemoConfig | None = None,
    progress: bool = False,
) -> dict:
    """Build the route, fit, query, compare with brute force, write the report
    in ``out`` (None: a fresh folder under the system's temporary folder).

    Turns on the compile cache (:func:`rhythmic_jax.enable_compile_cache`), so a
    second demo loads its programs instead of compiling them."""
    from rhythmic_jax.decoding.held import HeldMap
    from rhythmic_jax.eval.report import evaluate_map, format_evaluation
    from rhythmic_jax.fitting.prepare import fit_frames
    from rhythmic_jax.frames.sources import describe_images
    from rhythmic_jax.io.tiles import tile_image
    from rhythmic_jax.jit_cache import enable_compile_cache
    from rhythmic_jax.map import map_file
    from rhythmic_jax.map.config import MapConfig

    enable_compile_cache()

    cfg = config or (DemoConfig.quick() if quick else DemoConfig())
    if out is None:  # the checkout stays clean; the report line says where
        out = fresh_folder("rhythmic_demo")
    out = Path(out).expanduser().absolute()  # its place checked by the command line
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    mosaic = demo_mosaic(cfg.grid, cfg.photo)
    ref = tile_image(mosaic, cfg.tile, cfg.stride).tiles
    qry = tile_image(changed_appearance(mosaic), cfg.tile, cfg.stride).tiles
    settings = {"width": cfg.thumb, "height": cfg.thumb, "patch": 8}
    tag = f"demo-{cfg.grid}x{cfg.photo}-{cfg.tile}-{cfg.stride}"
    x_ref, settings = describe_images(ref, "patchnorm", settings, tag + "-a", progress)
    x_qry, _ = describe_images(qry, "patchnorm", settings, tag + "-b", progress)
    side = mosaic.shape[1]
    print(f"route: {len(ref)} places ({cfg.tile}-pixel tiles of a {side}-pixel "
          f"mosaic), {x_ref.shape[1]}-d patchnorm descriptors")  # fmt: skip
    t1 = time.perf_counter()
    made = MapConfig(level=cfg.level, descriptor="patchnorm",
                     descriptor_settings=settings)  # fmt: skip
    model = HeldMap(fit_frames(x_ref, made, progress=progress))
    fit_s = time.perf_counter() - t1
    map_file.save(out / "map", model.value)
    same = evaluate_map(model, x_ref, reference=x_ref, tolerance=cfg.tolerance)
    changed = evaluate_map(model, x_qry, reference=x_ref, tolerance=cfg.tolerance)
    decodes = {}
    for method, length in (("hard", 1), ("soft", 1), ("soft", 5), ("soft", 10)):
        if length == 1 and method == changed["decode"]:  # evaluated just above
            decodes[f"{method}, sequence 1"] = changed["methods"]["map"]["accuracy_tol"]
            continue
        decodes[f"{method}, sequence {length}"] = evaluate_map(
            model, x_qry, tolerance=cfg.tolerance, method=method, sequence=length,
            timing=False,
        )["methods"]["map"]["accuracy_tol"]  # fmt: skip
    result = {
        "config": asdict(cfg),
        "n": model.n,
        "d": model.d,
        "periods": list(model.periods),
        "storage_bytes": model.storage_bytes,
        "database_bytes": same["database_bytes"],
        "compression_ratio": model.compression_ratio,
        "fit_seconds": fit_s,
        "total_seconds": time.perf_counter() - t0,
        "same_appearance": same,
        "changed_appearance": changed,
        "changed_appearance_decodes": decodes,
    }
    write_file(out / "report.json", json.dumps(result, indent=2))
    bars = {
        "same appearance: map": same["methods"]["map"]["accuracy_tol"],
        "same appearance: brute force": same["methods"]["brute force"]["accuracy_tol"],
        **{f"changed: map, {k}": v for k, v in decodes.items()},
        "changed: brute force": changed["methods"]["brute force"]["accuracy_tol"],
        **{f"changed: {k} (map's bytes)": row["accuracy_tol"]
           for k, row in changed["methods"].items()
           if k not in ("map", "brute force")},
    }  # fmt: skip
    _report_plot(out / "report.png", model.d, model.config.r, cfg.level, bars)
    text = [
        f"map: periods {model.periods}, {model.storage_bytes:,} bytes "
        f"= {model.compression_ratio:.4f} of the {same['database_bytes']:,}-byte "
        f"database; fitted in {fit_s:.1f} s",
        "",
        "queries = the reference tiles (paper's Table 2 protocol):",
        format_evaluation(same),
        "",
        "queries = the tiles after a change of appearance:",
        format_evaluation(changed),
        "",
        f"the map's decodes after the change (accuracy within ±{cfg.tolerance}; "
        "sequences run along the raster order):",
        *(f"  {k:<18} {v:.4f}" for k, v in decodes.items()),
    ]
    write_file(
        out / "report.md",
        "# rhythmic-jax demo\n\n```\n"
        + "\n".join(text)
        + "\n```\n\n![storage growth and accuracy](report.png)\n",
    )
    print("\n".join(text))
    shown = _shown(out)
    print(f"\nreport: {shown / 'report.md'} (plot {shown / 'report.png'}, map "
          f"{shown / 'map'})")  # fmt: skip
    return result


def _shown(path: Path) -> Path:
    """``path`` as the user would type it here: relative to the current folder
    when it lies inside it, else whole."""
    rel = os.path.relpath(path)
    return Path(rel) if not rel.startswith("..") else Path(path)
