"""Frames per second of the augmented training pipeline, and where the time goes.

python scripts/bench_pipeline.py [--frames 1024] [--descriptor patchnorm]
"""

from __future__ import annotations

import time

import numpy as np
from _harness import header, load_average, main, nordland_images, table


def options(ap) -> None:
    ap.add_argument("--frames", type=int, default=1024)
    ap.add_argument("--descriptor", default="patchnorm")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--elastic", default="coarse", choices=("kornia", "coarse"))


def run(args) -> dict:
    import torch

    from rhythmic_jax.augment.kornia_ops import NAMES
    from rhythmic_jax.augment.stream import AugmentedFit, fit_augmented
    from rhythmic_jax.frames.features import cached_describe, get_descriptor
    from rhythmic_jax.objective import default_c, targets
    from rhythmic_jax.periods import candidate_periods
    from rhythmic_jax.solvers.newton import newton_fit

    torch.set_num_threads(args.threads)
    names_all = [("none",), *((k,) for k in NAMES), ("all",)]
    if args.quick:
        args.frames, names_all = min(args.frames, 160), [("none",), ("hflip",)]
    own = "" if args.descriptor == "patchnorm" else "_" + args.descriptor
    args.stem = "pipeline" + own + ("_quick" if args.quick else "")
    (summer,) = nordland_images(args.root, ("summer",))
    images = summer.images[: args.frames]
    desc = get_descriptor(args.descriptor)
    clean = cached_describe(images, desc, key=f"nordland-summer-{len(images)}")
    n = len(images)
    periods = candidate_periods(n, 2, 1, 7)
    c = default_c(n)
    init, _ = newton_fit(clean, targets(np.arange(n), periods), c, progress=False)
    # warm-up: compile the optax step and the descriptor's first batches once
    warm = AugmentedFit(names=("hflip",), p=0.0, epochs=1)
    fit_augmented(images[:128], clean[:128], np.arange(128), periods, init, c, desc,
                  warm, progress=False)  # fmt: skip
    load0, rows = load_average(), []
    for names in names_all:
        settings = {"elastic_impl": args.elastic}
        cfg = AugmentedFit(names=names, epochs=1, augment_settings=settings)
        if names == ("none",):  # the peer: describe and step, no augmentation
            cfg = AugmentedFit(names=("hflip",), p=0.0, epochs=1)
        t = time.perf_counter()
        _, tm = fit_augmented(images, clean, np.arange(n), periods, init, c, desc,
                              cfg, progress=False)  # fmt: skip
        # n augmented frames: half the epoch's frames, so half its step time
        fps = n / (tm["augment"] + tm["describe"] + tm["step"] / 2)
        rows.append(dict(
            augmentation=names[0], frames_per_s=fps, augment_s=tm["augment"],
            describe_s=tm["describe"], step_s=tm["step"],
            wall_s=time.perf_counter() - t,
        ))  # fmt: skip
        print(rows[-1], flush=True)
    for r in rows:
        r["ratio_to_plain"] = r["frames_per_s"] / rows[0]["frames_per_s"]
    return dict(descriptor=desc.settings() | {"name": args.descriptor}, frames=n,
                templates=sum(periods), torch_threads=torch.get_num_threads(),
                loadavg_start=load0, loadavg_end=load_average(), rows=rows)  # fmt: skip


def markdown(r: dict) -> str:
    rows = [[x["augmentation"], round(x["frames_per_s"]), f"{x['ratio_to_plain']:.2f}",
             f"{x['augment_s']:.2f}", f"{x['describe_s']:.2f}", f"{x['step_s']:.2f}"]
            for x in r["rows"]]  # fmt: skip
    return "\n".join(header("Augmented training pipeline", r) + [
        f"{r['frames']} Nordland frames, {r['descriptor']['name']} at its native"
        f" size, {r['templates']} templates, {r['torch_threads']} torch threads."
        " Frames/s counts augmented frames through augmentation, descriptor, DLPack"
        " and the optax step (the step time of the augmented half of each epoch"
        " taken as half the epoch's step time).",
        "",
        table(["augmentation", "frames/s", "x plain", "augment s", "describe s",
               "JAX step s"], rows),  # fmt: skip
    ])  # fmt: skip


if __name__ == "__main__":
    main(__doc__, run, markdown, options, stem="pipeline")
