"""The ``rhythmic-jax`` command line: a thin layer over the library.

Every command parses its arguments and calls library functions; bad input ends
with one line on stderr and exit status 2, and nothing half-written on disk.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import shutil
import sys
import textwrap
from pathlib import Path

from rhythmic_jax.errors import InputError

__all__ = ["main"]

EXAMPLES = {
    "fit": """
      rhythmic-jax fit ref.npy --out route.map
      rhythmic-jax fit summer/ winter/ --out route.map --descriptor patchnorm
      rhythmic-jax fit big_aerial.png --tile 224 --stride 112 --out aerial.map
      rhythmic-jax fit summer/ --out route.map --augment all --epochs 5
        (killed or stopped with Ctrl-C? run the same command again to resume)
    """,
    "query": """
      rhythmic-jax query route.map queries.npy --out pred.npy
      rhythmic-jax query route.map winter/ --decode soft --sequence 10 --json
    """,
    "info": """
      rhythmic-jax info route.map --json
    """,
    "evaluate": """
      rhythmic-jax evaluate route.map winter/ --tolerance 1
      rhythmic-jax evaluate route.map winter/ --reference summer/ --json
      rhythmic-jax evaluate route.map queries.npy --json
    """,
    "demo": """
      rhythmic-jax demo
      rhythmic-jax demo --out demo_report --quick
    """,
}


def _quiet_logs(verbose: bool) -> None:
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")
    logging.basicConfig(
        level=logging.INFO if verbose else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
    )
    for name in ("absl", "jax", "orbax", "jax._src.xla_bridge"):
        logging.getLogger(name).setLevel(logging.ERROR)


def _add_source_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--descriptor",
        default=None,
        help="descriptor for image sources (patchnorm, hog, efficientnet_lite0, "
        "vgg16_fc7); a map remembers its own",
    )
    p.add_argument(
        "--weights",
        default=None,
        help="weights file of vgg16_fc7 (a state dict); when querying a map, a "
        "moved copy of the file it was fitted with (its sha256 is checked)",
    )
    p.add_argument("--tile", type=int, default=None, help="tile a large image: size")
    p.add_argument(
        "--stride", type=int, default=None, help="tile stride (default size/2)"
    )
    p.add_argument("--no-progress", action="store_true", help="hide progress bars")


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="rhythmic-jax",
        description="Sub-linear-storage place recognition with rhythmic templates.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="run 'rhythmic-jax COMMAND --help' for examples",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress")
    sub = parser.add_subparsers(dest="command", required=True)

    def add(name: str, help_: str) -> argparse.ArgumentParser:
        return sub.add_parser(
            name,
            help=help_,
            description=help_,
            epilog="examples:" + textwrap.dedent(EXAMPLES[name]),
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )

    p = add("fit", "fit a map on reference frames (.npy, image folders, or --tile)")
    p.add_argument("sources", nargs="+", help="descriptor .npy, image folder(s), image")
    p.add_argument("--out", required=True, help="map folder to write")
    p.add_argument("--r", type=int, default=2, help="number of periods (default 2)")
    p.add_argument("--level", type=int, default=1, help="period level c (c*N^(1/r))")
    p.add_argument("--count", type=int, default=7, help="candidate periods (default 7)")
    p.add_argument("--c", type=float, default=None, help="SVM penalty (default log N)")
    p.add_argument("--solver", default="newton", choices=("newton", "lbfgs"))
    p.add_argument(
        "--gap",
        type=float,
        default=1e-7,
        help="stop the solver at this estimated relative objective gap (default "
        "1e-7: the optimum; 1e-3 stops within about 0.1 %%, sooner)",
    )
    p.add_argument("--json", action="store_true", help="print the map's info as JSON")
    p.add_argument(
        "--augment",
        default=None,
        help="train over frames augmented on the fly (image sources): comma-"
        "separated names from gaussian_blur, hflip, random_crop, elastic, "
        "contrast, invert, grayscale, or 'all'",
    )
    p.add_argument("--epochs", type=int, default=3, help="augmented epochs (3)")
    p.add_argument(
        "--batch-size", type=int, default=128, help="augmented frames per step (128)"
    )
    p.add_argument(
        "--checkpoint",
        default=None,
        help="checkpoint folder of an augmented fit (default OUT.ckpt, removed once "
        "the map is saved); a killed or interrupted fit resumes from it when the "
        "same command runs again",
    )
    p.add_argument(
        "--checkpoint-every",
        type=int,
        default=50,
        help="steps between checkpoints of an augmented fit (50)",
    )
    p.add_argument(
        "--pca", type=int, default=None, help="project descriptors to K dims (saved)"
    )
    _add_source_options(p)

    p = add("query", "localise queries against a map (-1 = no match)")
    p.add_argument("map", help="map folder")
    p.add_argument("source", help="query descriptors .npy, image folder or image")
    p.add_argument("--out", default=None, help="write predictions to this .npy")
    p.add_argument("--decode", default=None, choices=("hard", "soft", "topm"))
    p.add_argument("--sequence", type=int, default=None, help="sequence length L")
    p.add_argument("--threshold", type=float, default=None, help="reject below this")
    p.add_argument("--json", action="store_true", help="print predictions as JSON")
    _add_source_options(p)

    p = add("info", "describe a map: n, d, periods, storage, candidate errors")
    p.add_argument("map", help="map folder")
    p.add_argument("--json", action="store_true", help="print JSON")

    p = add("evaluate", "accuracy, recall@K, storage and latency beside brute force")
    p.add_argument("map", help="map folder")
    p.add_argument("source", help="query descriptors .npy, image folder or image")
    p.add_argument(
        "--reference",
        default=None,
        help="reference source for the brute-force line (default: the sources the "
        "map was fitted on, when they are still there)",
    )
    p.add_argument(
        "--tolerance", type=int, default=0, help="frame tolerance (default 0)"
    )
    p.add_argument("--decode", default=None, choices=("hard", "soft", "topm"))
    p.add_argument("--sequence", type=int, default=None, help="sequence length L")
    p.add_argument("--json", action="store_true", help="print JSON")
    _add_source_options(p)

    p = add("demo", "fit and query a map on built-in photographs; write a report")
    p.add_argument("--out", default="rhythmic_demo", help="report folder")
    p.add_argument("--quick", action="store_true", help="a smaller route (CI)")
    p.add_argument("--no-progress", action="store_true", help="hide progress bars")
    return parser


def _cmd_fit(args) -> int:
    from rhythmic_jax.io.checkpoint import check_target
    from rhythmic_jax.io.sources import check_sources_memory, load_sources
    from rhythmic_jax.rhythmic_map import RhythmicMap

    check_target(args.out)  # before the fit, not after it
    augmented = _augmented_fit(args) if args.augment else None
    check_sources_memory(args.sources, args.r, args.level, args.count)
    feats = load_sources(
        args.sources,
        args.descriptor,
        args.tile,
        args.stride,
        not args.no_progress,
        pca=args.pca,
        weights=args.weights,
    )
    model = RhythmicMap(
        r=args.r,
        level=args.level,
        count=args.count,
        c=args.c,
        solver=args.solver,
        gap=args.gap,
        descriptor=feats.descriptor,
        descriptor_settings=feats.settings,
    )
    if augmented is not None:
        _fit_augmented(model, feats, *augmented, progress=not args.no_progress)
    else:
        model.fit(feats.x, feats.labels, progress=not args.no_progress)
    model.extra.update(feats.extra)
    model.reference = {
        "sources": [str(Path(src).expanduser().absolute()) for src in args.sources],
        "tile": args.tile,
        "stride": args.stride,
    }
    model.save(args.out)
    if augmented is not None and args.checkpoint is None:
        shutil.rmtree(augmented[1], ignore_errors=True)  # the map holds the result
    info = model.info()
    if args.json:
        print(json.dumps(info, indent=2))
    else:
        print(
            f"map {args.out}: n={info['n']} d={info['d']} "
            f"periods={tuple(info['periods'])} "
            f"storage={info['storage_bytes']:,} B "
            f"(ratio {info['compression_ratio']:.4f} of {info['database_bytes']:,} B)"
        )
    return 0


def _augmented_fit(args):
    """The augmented fit's settings and checkpoint folder, checked before any work."""
    from rhythmic_jax.augment.kornia_ops.kornia_ops import AugmentConfig
    from rhythmic_jax.augment.kornia_ops.stream import AugmentedFit

    if args.pca is not None:
        raise InputError("--augment and --pca together are not supported")
    for flag in ("epochs", "batch_size", "checkpoint_every"):
        if getattr(args, flag) < 1:
            value = getattr(args, flag)
            raise InputError(f"{{opt:{flag}}} must be >= 1, got {value}")
    names = tuple(args.augment.split(","))
    AugmentConfig(names=names)  # unknown names end here, not after describing
    config = AugmentedFit(
        names=names,
        epochs=args.epochs,
        batch_size=args.batch_size,
        checkpoint_every=args.checkpoint_every,
    )
    ckpt = Path(args.checkpoint or str(Path(args.out)) + ".ckpt").absolute()
    if ckpt.exists() and not ckpt.is_dir():
        raise InputError(f"--checkpoint {ckpt}: a file, not a folder")
    return config, ckpt


def _fit_augmented(model, feats, config, ckpt: Path, progress: bool) -> None:
    """Fit over augmented frames, checkpointed in ``ckpt``."""
    from rhythmic_jax.augment.kornia_ops.stream import fit_map_augmented
    from rhythmic_jax.features import get_descriptor

    if feats.images is None:
        raise InputError("--augment needs image sources (folders or --tile), not .npy")
    descriptor = get_descriptor(feats.descriptor, **feats.settings)
    try:
        fit_map_augmented(
            model, feats.images, feats.x, descriptor, config, feats.labels,
            progress=progress, checkpoint=ckpt,
        )  # fmt: skip
    except KeyboardInterrupt:
        print(
            f"rhythmic-jax fit: the augmented fit's checkpoint is kept in {ckpt}; "
            "run the same command again to resume",
            file=sys.stderr,
        )
        raise


def _load_queries(args):
    from rhythmic_jax.io.sources import load_query_source
    from rhythmic_jax.rhythmic_map import RhythmicMap

    model = RhythmicMap.load(args.map)
    feats = load_query_source(
        args.source,
        model,
        args.descriptor,
        args.tile,
        args.stride,
        not args.no_progress,
        weights=args.weights,
    )
    return model, feats


def _cmd_query(args) -> int:
    import numpy as np

    if args.out and not Path(args.out).parent.is_dir():
        raise InputError(f"--out {args.out}: folder {Path(args.out).parent} not found")
    model, feats = _load_queries(args)
    pred = model.predict(
        feats.x, args.decode, sequence=args.sequence, threshold=args.threshold
    )
    if args.out:
        from rhythmic_jax.io.atomic import save_npy

        save_npy(args.out, pred.astype(np.int64))
    if args.json:
        print(json.dumps({"predictions": pred.tolist()}))
    elif not args.out:
        print("\n".join(str(int(v)) for v in pred))
    else:
        print(
            f"{len(pred)} predictions ({int((pred < 0).sum())} no match) -> {args.out}"
        )
    return 0


def _cmd_info(args) -> int:
    from rhythmic_jax.rhythmic_map import RhythmicMap

    info = RhythmicMap.load(args.map).info()
    if args.json:
        print(json.dumps(info, indent=2))
    else:
        for key in ("n", "d", "periods", "storage_bytes", "compression_ratio", "c"):
            print(f"{key:>18}: {info[key]}")
        for t, e in zip(info["candidates"], info["candidate_errors"], strict=True):
            print(f"{'period ' + str(t):>18}: training error {e:.4f}")
    return 0


def _cmd_evaluate(args) -> int:
    from rhythmic_jax.eval.report import evaluate_map, format_evaluation
    from rhythmic_jax.io.sources import reference_features

    model, feats = _load_queries(args)
    ref, labels, note = reference_features(
        model, args.reference, args.descriptor, args.tile, args.stride,
        not args.no_progress, weights=args.weights,
    )  # fmt: skip
    result = evaluate_map(
        model,
        feats.x,
        reference=ref,
        reference_labels=labels,
        tolerance=args.tolerance,
        method=args.decode,
        sequence=args.sequence,
    )
    result["reference_note"] = note
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(format_evaluation(result) + "\n" + note)
    return 0


def _cmd_demo(args) -> int:
    from rhythmic_jax.demo import run_demo

    run_demo(args.out, quick=args.quick, progress=not args.no_progress)
    return 0


COMMANDS = {
    "fit": _cmd_fit,
    "query": _cmd_query,
    "info": _cmd_info,
    "evaluate": _cmd_evaluate,
    "demo": _cmd_demo,
}


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``rhythmic-jax``; returns the exit status."""
    args = _parser().parse_args(argv)
    _quiet_logs(args.verbose)
    try:
        return COMMANDS[args.command](args)
    except InputError as err:
        print(f"rhythmic-jax {args.command}: error: {err.as_flag()}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"rhythmic-jax {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
