"""Descriptor benchmark on Nordland: winter queries against the summer map.

For each descriptor, brute-force cosine nearest neighbour of every winter frame
among the summer frames; recall@1 counts the exact index, and within +-1 index
(the usual tolerance at this frame stride). Frames/s is timed on a fixed subset
of frames, uncached; the full descriptors come from the disk cache
(``$RHYTHMIC_JAX_CACHE`` or ``~/.cache/rhythmic_jax``).

    python scripts/bench_descriptors.py            # writes reports/descriptors.*

Measured (recall@1, exact index): patchnorm 0.126, HOG 0.212, EfficientNet-Lite0
block-10 map 0.477 at 224x112 and 0.547 at 224x224, PCA-512 of the 224x112 map
0.451.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import platform
import time
from pathlib import Path

import jax
import numpy as np
import torch
from skimage.io import imread
from tqdm.auto import tqdm

from rhythmic_jax.frames.features import cached_describe, describe, get_descriptor
from rhythmic_jax.io.atomic import write_file
from rhythmic_jax.projection import fit_pca, project

log = logging.getLogger("bench_descriptors")
REPO = Path(__file__).resolve().parents[1]
DEFAULT_ROOT = Path(os.environ.get("RHYTHMIC_DATA", REPO.parent / "shared" / "data"))

# (row label, registry name, settings)
DESCRIPTORS = (
    ("patchnorm 64x32", "patchnorm", {}),
    ("hog 64x32", "hog", {}),
    ("efficientnet_lite0 b10 224x112", "efficientnet_lite0", {}),
    ("efficientnet_lite0 b10 224x224", "efficientnet_lite0", {"height": 224}),
)
PCA_OF = "efficientnet_lite0 b10 224x112"


def load_season(root: Path, season: str, progress: bool) -> np.ndarray:
    """uint8 (n, 32, 64, 3): the season's PNG frames sorted by name (route order)."""
    files = sorted((root / season).glob("*.png"))
    if not files:
        raise SystemExit(f"no PNG frames under {root / season}")
    frames = [imread(f)[..., :3] for f in tqdm(files, season, disable=not progress)]
    return np.stack(frames)


def recall_at_1(queries: np.ndarray, reference: np.ndarray) -> tuple[float, float]:
    """Unit-norm rows; ground truth is the same index. (exact, within +-1)."""
    nearest = np.argmax(queries @ reference.T, axis=1)
    err = np.abs(nearest - np.arange(len(queries)))
    return float(np.mean(err == 0)), float(np.mean(err <= 1))


def frames_per_second(images: np.ndarray, descriptor, batch_size: int) -> float:
    describe(images[:batch_size], descriptor, batch_size, progress=False)  # warm up
    start = time.perf_counter()
    describe(images, descriptor, batch_size, progress=False)
    return len(images) / (time.perf_counter() - start)


def run(args: argparse.Namespace) -> tuple[list[dict], int, int]:
    """Rows of the table, the number of map frames and of queries."""
    root = args.root / "nordland_64x32"
    summer = load_season(root, "summer", args.progress)
    winter = load_season(root, "winter", args.progress)
    timing = np.concatenate([summer[::20], winter[::20]])[: args.timing_frames]
    log.info(
        "summer %s, winter %s, timing on %d frames",
        summer.shape,
        winter.shape,
        len(timing),
    )
    rows, kept = [], {}
    for label, name, settings in DESCRIPTORS:
        d = get_descriptor(name, **settings)
        kw = dict(
            cache_dir=args.cache_dir, batch_size=args.batch_size, progress=args.progress
        )
        ref = cached_describe(summer, d, "nordland64x32-summer", **kw)
        qry = cached_describe(winter, d, "nordland64x32-winter", **kw)
        exact, tol1 = recall_at_1(qry, ref)
        fps = frames_per_second(timing, d, args.batch_size)
        rows.append(
            dict(
                descriptor=label,
                name=name,
                settings=d.settings(),
                dim=d.dim,
                recall_at_1=exact,
                recall_at_1_tol1=tol1,
                frames_per_s=fps,
            )
        )
        log.info(
            "%s: recall@1 %.4f (+-1: %.4f), %.1f frames/s", label, exact, tol1, fps
        )
        kept[label] = (ref, qry, fps)
    ref, qry, fps = kept[PCA_OF]
    start = time.perf_counter()
    pca = jax.block_until_ready(fit_pca(ref, args.pca_dim))
    fit_s = time.perf_counter() - start
    ref_p = np.asarray(project(pca, ref, normalize=True))
    qry_p = np.asarray(project(pca, qry, normalize=True))
    exact, tol1 = recall_at_1(qry_p, ref_p)
    rows.append(
        dict(
            descriptor=f"PCA-{args.pca_dim} of {PCA_OF}",
            name="pca",
            settings={
                "of": PCA_OF,
                "k": args.pca_dim,
                "fit_on": "summer",
                "fit_s": round(fit_s, 2),
            },
            dim=args.pca_dim,
            recall_at_1=exact,
            recall_at_1_tol1=tol1,
            frames_per_s=fps,
        )
    )
    log.info(
        "PCA-%d: recall@1 %.4f (+-1: %.4f), fit %.1f s",
        args.pca_dim,
        exact,
        tol1,
        fit_s,
    )
    return rows, len(summer), len(winter)


def table(rows: list[dict]) -> str:
    lines = [
        "| descriptor | dim | recall@1 | recall@1 (±1) | frames/s |",
        "|---|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['descriptor']} | {r['dim']} | {r['recall_at_1']:.4f} |"
            f" {r['recall_at_1_tol1']:.4f} | {r['frames_per_s']:.1f} |"
        )
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--root", type=Path, default=DEFAULT_ROOT, help="shared data dir")
    p.add_argument("--out", type=Path, default=REPO / "reports")
    p.add_argument("--cache-dir", type=Path, default=None)
    p.add_argument("--threads", type=int, default=os.cpu_count() or 1)
    p.add_argument("--batch-size", type=int, default=64)
    p.add_argument("--timing-frames", type=int, default=256)
    p.add_argument("--pca-dim", type=int, default=512)
    p.add_argument("--no-progress", dest="progress", action="store_false")
    args = p.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    torch.set_num_threads(args.threads)
    env = dict(
        torch=torch.__version__,
        jax=jax.__version__,
        threads=args.threads,
        cpu=platform.processor() or platform.machine(),
        cpus=os.cpu_count(),
        load_average_at_start=round(os.getloadavg()[0], 2),
    )
    log.info("environment %s", env)
    rows, n_reference, n_queries = run(args)
    report = dict(
        dataset="nordland_64x32: winter queries vs summer map",
        n_reference=n_reference,
        n_queries=n_queries,
        metric="cosine, brute force",
        environment=env,
        results=rows,
    )
    md = (
        "# Descriptors on Nordland 64x32 (winter queries vs summer map)\n\n"
        "Brute-force cosine nearest neighbour; recall@1 counts the exact index,"
        " (±1) a neighbour within one index. Frames/s on "
        f"{args.timing_frames} frames, {args.threads} torch threads"
        f" ({env['cpus']} CPUs, load average {env['load_average_at_start']} at"
        " start: other work on the machine slows these). Command:"
        " `python scripts/bench_descriptors.py`.\n\n" + table(rows) + "\n"
    )
    write_file(args.out / "descriptors.json", json.dumps(report, indent=2) + "\n")
    write_file(args.out / "descriptors.md", md)
    print(table(rows))


if __name__ == "__main__":
    main()
