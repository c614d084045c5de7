"""Frames per second of the augmented training pipeline, and where the time goes.

python scripts/bench_pipeline.py [--frames 1024] [--descriptor patchnorm]
"""

import numpy as np
from _harness import header, load_average, main, nordland_images, table, timed


def library() -> tuple:
    """The augmented fit's modules (stream, features, images, newton) here, or in a
    baseline checkout's flat layout (``bench_frames.py`` runs them in either)."""
    try:
        from rhythmic_jax.augment import stream
        from rhythmic_jax.frames import features
        from rhythmic_jax.io import images
        from rhythmic_jax.solvers import newton
    except ImportError:
        from rhythmic_jax import augmented as stream
        from rhythmic_jax import data as images
        from rhythmic_jax import features, newton
    return stream, features, images, newton


def epochs(images, desc, key: str, variants, elastic="coarse") -> list[dict]:
    """One augmented epoch over ``images`` per variant (augmentation names; ``none``:
    describe and step only) from the clean fit, after a warm-up epoch (it compiles
    the optax step): each epoch's seconds by part, and its wall."""
    from rhythmic_jax.map.periods import candidate_periods
    from rhythmic_jax.solvers.objective import default_c, targets

    (stream, features, _, newton), n = library(), len(images)
    clean = features.cached_describe(images, desc, key=key, progress=False)
    periods, c, labels = candidate_periods(n, 2, 1, 7), default_c(n), np.arange(n)
    init, _ = newton.newton_fit(clean, targets(labels, periods), c, progress=False)
    plain = stream.AugmentedFit(names=("hflip",), p=0.0, epochs=1)

    def fit(x, cfg):
        m = len(x)
        args = x, clean[:m], labels[:m], periods, init, c, desc, cfg
        return stream.fit_augmented(*args, progress=False)[1]

    fit(images[:128], plain)
    out = []
    for names in variants:
        settings = {"elastic_impl": elastic}
        cfg = stream.AugmentedFit(names=names, epochs=1, augment_settings=settings)
        tm, wall, _ = timed(fit, images, plain if names == ("none",) else cfg)
        out.append(dict(tm, wall=wall))
    return out


def options(ap) -> None:
    ap.add_argument("--frames", type=int, default=1024)
    ap.add_argument("--descriptor", default="patchnorm")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--elastic", default="coarse", choices=("kornia", "coarse"))


def run(args) -> dict:
    import torch

    from rhythmic_jax.augment.kornia_ops import NAMES
    from rhythmic_jax.frames.features import get_descriptor
    from rhythmic_jax.map.periods import candidate_periods

    torch.set_num_threads(args.threads)
    variants = [("none",), *((k,) for k in NAMES), ("all",)]
    if args.quick:
        args.frames, variants = min(args.frames, 160), [("none",), ("hflip",)]
    own = "" if args.descriptor == "patchnorm" else "_" + args.descriptor
    args.stem = "pipeline" + own + ("_quick" if args.quick else "")
    (summer,) = nordland_images(args.root, ("summer",))
    images, desc = summer.images[: args.frames], get_descriptor(args.descriptor)
    n, load0, rows = len(images), load_average(), []
    times = epochs(images, desc, f"nordland-summer-{n}", variants, args.elastic)
    for names, tm in zip(variants, times, strict=True):
        # n augmented frames: half the epoch's frames, so half its step time
        fps = n / (tm["augment"] + tm["describe"] + tm["step"] / 2)
        rows.append(dict(augmentation=names[0], frames_per_s=fps,
                         augment_s=tm["augment"], describe_s=tm["describe"],
                         step_s=tm["step"], wall_s=tm["wall"]))  # fmt: skip
    for r in rows:
        r["ratio_to_plain"] = r["frames_per_s"] / rows[0]["frames_per_s"]
    return dict(descriptor=desc.settings() | {"name": args.descriptor}, frames=n,
                templates=sum(candidate_periods(n, 2, 1, 7)),
                torch_threads=torch.get_num_threads(), loadavg_start=load0,
                loadavg_end=load_average(), rows=rows)  # fmt: skip


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
