"""Frames per second of the augmented training pipeline, and where the time goes.

One epoch of :func:`rhythmic_jax.augment.stream.fit_augmented` on Nordland summer
frames: kornia augmentation (torch), the descriptor (torch), the DLPack hand-over
and the optax minibatch step of the vmapped objective (JAX), for each
augmentation alone and all seven merged, at the descriptor's native input size.
The peer in the same run is the same epoch with no augmentation (descriptors
only), so the ratio says what augmenting costs.

    python scripts/bench_pipeline.py [--frames 1024] [--descriptor patchnorm]

Writes reports/pipeline.json and reports/pipeline.md (``pipeline_<descriptor>.*``
for another descriptor) and prints the table.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("RHYTHMIC_DATA", ROOT.parent / "shared" / "data"))


def main() -> None:
    import torch

    from rhythmic_jax.augment.kornia_ops import NAMES
    from rhythmic_jax.augment.stream import AugmentedFit, fit_augmented
    from rhythmic_jax.frames.features import cached_describe, get_descriptor
    from rhythmic_jax.io.images import nordland
    from rhythmic_jax.objective import default_c, targets
    from rhythmic_jax.periods import candidate_periods
    from rhythmic_jax.solvers.newton import newton_fit

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=1024)
    ap.add_argument("--descriptor", default="patchnorm")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--elastic", default="coarse", choices=("kornia", "coarse"))
    ap.add_argument("--out", default=str(ROOT / "reports"))
    args = ap.parse_args()
    torch.set_num_threads(args.threads)

    summer = nordland(DATA / "nordland_64x32", seasons=("summer",), progress=False)[0]
    images = summer.images[: args.frames]
    desc = get_descriptor(args.descriptor)
    clean = cached_describe(images, desc, key=f"nordland-summer-{len(images)}")
    n = len(images)
    periods = candidate_periods(n, 2, 1, 7)
    c = default_c(n)
    init, _ = newton_fit(clean, targets(np.arange(n), periods), c, progress=False)
    # warm-up: compile the optax step and the descriptor's first batches once
    warm = AugmentedFit(names=("hflip",), p=0.0, epochs=1)
    fit_augmented(
        images[:128], clean[:128], np.arange(128), periods, init, c, desc, warm,
        progress=False,
    )  # fmt: skip
    load0 = os.getloadavg()
    rows = []
    for names in [("none",), *((k,) for k in NAMES), ("all",)]:
        settings = {"elastic_impl": args.elastic}
        cfg = AugmentedFit(names=names, epochs=1, augment_settings=settings)
        if names == ("none",):  # the peer: describe and step, no augmentation
            cfg = AugmentedFit(names=("hflip",), p=0.0, epochs=1)
        t = time.perf_counter()
        _, tm = fit_augmented(
            images, clean, np.arange(n), periods, init, c, desc, cfg, progress=False
        )
        aug_frames = n  # half the epoch's frames are augmented
        rows.append(
            {
                "augmentation": names[0],
                "frames_per_s": aug_frames
                / (tm["augment"] + tm["describe"] + tm["step"] / 2),
                "augment_s": tm["augment"],
                "describe_s": tm["describe"],
                "step_s": tm["step"],
                "wall_s": time.perf_counter() - t,
            }
        )
        print(rows[-1], flush=True)
    base = rows[0]["frames_per_s"]
    for r in rows:
        r["ratio_to_plain"] = r["frames_per_s"] / base
    report = {
        "command": "python scripts/bench_pipeline.py "
        + " ".join(f"--{k} {v}" for k, v in vars(args).items() if k != "out"),
        "descriptor": desc.settings() | {"name": args.descriptor},
        "frames": n,
        "templates": sum(periods),
        "torch_threads": torch.get_num_threads(),
        "loadavg_start": load0,
        "loadavg_end": os.getloadavg(),
        "rows": rows,
    }
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    stem = (
        "pipeline" if args.descriptor == "patchnorm" else f"pipeline_{args.descriptor}"
    )
    (out / f"{stem}.json").write_text(json.dumps(report, indent=2))
    lines = [
        "# Augmented training pipeline",
        "",
        f"`{report['command']}`: {n} Nordland frames, {args.descriptor} at its native "
        f"size, {sum(periods)} templates, {report['torch_threads']} torch threads, "
        f"load average {load0[0]:.1f} -> {report['loadavg_end'][0]:.1f} (shared "
        "machine: timings are pessimistic). Frames/s counts augmented frames through "
        "augmentation, descriptor, DLPack and the optax step (the step time of the "
        "augmented half of each epoch taken as half the epoch's step time).",
        "",
        "| augmentation | frames/s | x plain | augment s | describe s | JAX step s |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['augmentation']} | {r['frames_per_s']:.0f} "
            f"| {r['ratio_to_plain']:.2f} "
            f"| {r['augment_s']:.2f} | {r['describe_s']:.2f} | {r['step_s']:.2f} |"
        )
    (out / f"{stem}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
