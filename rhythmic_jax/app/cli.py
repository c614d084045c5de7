"""The ``rhythmic-jax`` command line: argparse over :mod:`rhythmic_jax.app.jobs`.

Every command parses its arguments, makes its job (which checks itself: each
option in its domain, :data:`rhythmic_jax.app.jobs.DOMAINS`, and against the
others, the job's rules), runs it and prints what it returns; bad input ends
with one line on stderr (settings spelled as flags) and exit status 2, and
nothing half-written on disk.

The parser is built from light modules only (the jobs' settings and domains, the
map's configuration, the compile policy): ``rhythmic-jax --help`` imports no
numpy, JAX or torch. What a job needs is imported when it runs.
"""

from __future__ import annotations

import argparse
import gc
import json
import logging
import os
import sys
import textwrap
from pathlib import Path
from typing import TYPE_CHECKING

from rhythmic_jax.errors import InputError
from rhythmic_jax.frames.compile_policy import (
    BUILD_MIN_FRAMES,
    COMPILE_MODES,
    LOAD_MIN_FRAMES,
    CompilePolicy,
)
from rhythmic_jax.map.config import DECODERS, DTYPES, SOLVERS, MapConfig

if TYPE_CHECKING:  # imported where used: no numpy, but not the parser's either
    from rhythmic_jax.app import jobs

__all__ = ["main"]

DEFAULTS = MapConfig()  # the defaults of a map's settings, as fit offers them

EXAMPLES = {
    "fit": """
      rhythmic-jax fit ref.npy --out route.map
      rhythmic-jax fit ref.npy --out route.map --layout mixed:48,50
      rhythmic-jax fit summer/ --out route.map --layout hierarchical:50
      rhythmic-jax fit summer/ winter/ --out route.map --descriptor patchnorm
      rhythmic-jax fit big_aerial.png --tile 224 --stride 112 --out aerial.map
      rhythmic-jax fit run1/ run2/ --positions run1.csv run2.csv --places 500 \\
          --out route.map
      rhythmic-jax fit summer/ --descriptor efficientnet_lite0 --level 4 --codes 64 \\
        --out hybrid.map      (a map plus a 64-bit code per place)
      rhythmic-jax fit summer/ --out route.map --augment all --epochs 5
        (killed or stopped with Ctrl-C? run the same command again to resume)
      rhythmic-jax fit big.npy --out route.map --processes 2 --memory 1GiB
      rhythmic-jax fit shards/ --out route.map --dtype float16
      rhythmic-jax fit summer/ --out route.map --shards summer.shards --memory 2GiB
      on each of K hosts (process 0's host is the coordinator):
      rhythmic-jax fit ref.npy --out route.map --coordinator HOST:PORT
        --num-processes K --process-id i
        """,
    "learn": """
      rhythmic-jax learn summer_train.npy winter_train.npy --out route.emb
      rhythmic-jax learn summer/ winter/ --descriptor patchnorm --out route.emb \
          --method invariant
      rhythmic-jax info route.emb    (its descriptor and learned fusion weight)
      rhythmic-jax fit summer_test.npy --embedding route.emb --out route.map
      rhythmic-jax fit summer_test/ --embedding route.emb --codes int8 --out route.map
        (the embedding's descriptor and the fusion weight it learned for int8)
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
      rhythmic-jax evaluate ref.map DATASET/query --ground-truth \\
          DATASET/ground_truth_new.npy --plot pr.png
      rhythmic-jax evaluate route.map night/ --ground-truth night.csv --tolerance-m 25
      rhythmic-jax evaluate hybrid.map winter/ --tolerance 1 --plot frontier.png
    """,
    "demo": """
      rhythmic-jax demo
      rhythmic-jax demo --out demo_report --quick
    """,
    "frontier": """
      rhythmic-jax frontier summer.npy winter.npy --tolerance 1 --budget 2000
      rhythmic-jax frontier db.h5 q.h5 --ground-truth GT.npz --lengths 1 \\
          --csv frontier.csv --plot frontier.png
    """,
}


def _quiet_logs(verbose: bool) -> None:
    from rhythmic_jax.app import jobs

    jobs.quiet_io_threads()
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
    p.add_argument(
        "--tile",
        default=None,
        help="tile a large image: size (queries of a tiled map: the map's own)",
    )
    p.add_argument(
        "--stride",
        default=None,
        help="tile stride, with --tile (default size/2)",
    )
    p.add_argument(
        "--compile",
        default="auto",
        choices=COMPILE_MODES,
        help="run a network descriptor (efficientnet_lite0, vgg16_fc7) compiled "
        "for this CPU: about 1.5-1.8x the frames/s of the eager network, but building "
        "it costs up to a minute once per machine and settings (kept in the cache "
        "folder) and loading it about 0.2 s per job. auto (default): a job of "
        f">= {LOAD_MIN_FRAMES} frames loads the compiled network; the first such "
        "job on a machine runs eagerly and pays only for a background build "
        "(a niced process, about a minute of CPU beside it), so the next job "
        f"runs compiled; a job of >= {BUILD_MIN_FRAMES} frames builds it first "
        "(RHYTHMIC_JAX_NETWORK_BUILD=0: no background builds); always; "
        "never (the eager reference). Without a C++ compiler the job runs eagerly "
        "and says so",
    )
    p.add_argument(
        "--compile-min-frames",
        default=None,
        metavar="N",
        help="with --compile auto, compile from N frames on (built or not)",
    )
    p.add_argument("--no-progress", action="store_true", help="hide progress bars")


# What each command writes and reads, by destination: no path written may be,
# hold or lie inside another the job reads or writes.
WRITES = {
    "fit": ("out", "checkpoint", "shards"),
    "learn": ("out",),
    "query": ("out",),
    "evaluate": ("plot",),
}
READS = {
    "fit": ("sources", "embedding", "positions", "weights"),
    "learn": ("sources", "weights"),
    "query": ("map", "source", "weights"),
    "evaluate": ("map", "source", "reference", "ground_truth", "weights"),
}
ROLES = {"map": "the map", "source": "the queries", "sources": "the source"}
NAMES = ("names",)  # --positions / --ground-truth names: no file


def _flag(dest: str) -> str:
    return ROLES.get(dest) or "--" + dest.replace("_", "-")


def _paths(args, dests) -> list[tuple[str, str]]:
    """(dest, path) of every path given to ``dests`` (lists flattened)."""
    out = []
    for dest in dests:
        value = getattr(args, dest, None)
        for v in value if isinstance(value, list | tuple) else [value]:
            if v is not None and v not in NAMES:
                out.append((dest, str(v)))
    return out


def _clash(w: Path, r: Path) -> str | None:
    if w == r:
        return "the same path as"
    if r in w.parents and not r.is_file():  # under a file: no path (said later)
        return "inside"
    if w in r.parents:
        return "holding"
    return None


def check_paths(args) -> str | None:
    """The line refusing a path the job would write over something it reads
    (or writes twice), compared resolved (through links and ``..``), or None."""
    writes = _paths(args, WRITES.get(args.command, ()))
    if args.command == "fit" and args.checkpoint is None:
        writes.append(("checkpoint", str(args.out) + ".ckpt"))  # its default
    reads = _paths(args, READS.get(args.command, ()))
    for i, (dest, path) in enumerate(writes):
        w = Path(path).expanduser().resolve()
        others = [(d, p, "reads") for d, p in reads]
        others += [(d, p, "writes") for d, p in writes[i + 1 :]]
        for other, opath, verb in others:
            how = _clash(w, Path(opath).expanduser().resolve())
            if how is not None:
                return (
                    f"{_flag(dest)} {path}: {how} {_flag(other)} {opath}, which "
                    f"this job {verb}; give another path"
                )
    return None


def _stated(parser: argparse.ArgumentParser) -> None:
    """Give every numeric option its domain (:data:`DOMAINS`), stated in --help."""
    from rhythmic_jax.app.jobs import DOMAINS

    for action in parser._actions:
        domain = DOMAINS.get(action.dest)
        if domain is not None and action.option_strings:
            action.type = domain
            action.help = f"{action.help or ''} [{domain.text()}]".lstrip()


class _Parser(argparse.ArgumentParser):
    """Usage errors in one line, like every other refusal (exit status 2)."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _given_options(argv: list[str], parsed: argparse.Namespace) -> set[str]:
    """The destinations of the options ``argv`` gives (not left at a default)."""
    parser = _parser()
    for action in parser.commands[parsed.command]._actions:
        action.default = argparse.SUPPRESS  # left out: not in the namespace
    seen, _ = parser.parse_known_args(argv)
    return set(vars(seen))


def _parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="rhythmic-jax",
        description="Sub-linear-storage place recognition with rhythmic templates.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="run 'rhythmic-jax COMMAND --help' for examples\n\n"
        "compiled programs are kept in $RHYTHMIC_JAX_CACHE/jax (default\n"
        "~/.cache/rhythmic_jax/jax): later runs load them instead of compiling;\n"
        "RHYTHMIC_JAX_COMPILE_CACHE=0 turns that off, =FOLDER moves it",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    parser.commands = {}

    def add(name: str, help_: str) -> argparse.ArgumentParser:
        parser.commands[name] = sub.add_parser(
            name,
            help=help_,
            description=help_,
            epilog="examples:" + textwrap.dedent(EXAMPLES[name]),
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        return parser.commands[name]

    p = add("fit", "fit a map on reference frames (.npy, image folders, or --tile)")
    p.add_argument("sources", nargs="+", help="descriptor .npy, image folder(s), image")
    p.add_argument("--out", required=True, help="map folder to write")
    p.add_argument(
        "--r", default=DEFAULTS.r, help=f"number of periods (default {DEFAULTS.r})"
    )
    p.add_argument("--level", default=DEFAULTS.level, help="period level c (c*N^(1/r))")
    p.add_argument(
        "--count",
        default=DEFAULTS.count,
        help=f"candidate periods (default {DEFAULTS.count})",
    )
    p.add_argument("--c", default=DEFAULTS.c, help="SVM penalty (default log N)")
    p.add_argument("--solver", default=DEFAULTS.solver, choices=SOLVERS)
    p.add_argument(
        "--gap",
        default=DEFAULTS.gap,
        help="stop the solver at this estimated relative objective gap (default "
        "1e-7: the optimum; 1e-3 stops within about 0.1 %%, sooner)",
    )
    p.add_argument(
        "--layout",
        default=DEFAULTS.layout,
        help="how frames are labelled: periods (default, chosen by training error), "
        "periods:T1,T2, mixed or mixed:B1,..,Br (mixed-radix digits, most "
        "significant first: it classifies contiguous segments), hierarchical, "
        "hierarchical:SEG or hierarchical:SEG:T1,T2 (segments of SEG frames plus "
        "co-prime fine periods); sizes left out match the storage of --r/--level",
    )
    p.add_argument("--json", action="store_true", help="print the map's info as JSON")
    p.add_argument(
        "--augment",
        default=None,
        help="train over frames augmented on the fly (image sources): comma-"
        "separated names from gaussian_blur, hflip, random_crop, elastic, "
        "contrast, invert, grayscale, or 'all'",
    )
    p.add_argument("--epochs", default=None, help="augmented epochs (3)")
    p.add_argument(
        "--batch-size",
        default=None,
        help="augmented frames per step (128)",
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
        default=None,
        help="steps between checkpoints of an augmented fit (50)",
    )
    p.add_argument(
        "--pca",
        default=None,
        help="project descriptors to K dims (saved)",
    )
    p.add_argument(
        "--dtype",
        default=DEFAULTS.dtype,
        choices=DTYPES,
        help="how the map stores its templates (int8: a scale per template)",
    )
    scale = p.add_argument_group("scale (descriptor files or shard folders)")
    scale.add_argument(
        "--processes",
        default=1,
        help="start this many local processes for one fit (frames split by rows)",
    )
    scale.add_argument("--coordinator", default=None, help="HOST:PORT of process 0")
    scale.add_argument("--num-processes", default=None, help="K hosts")
    scale.add_argument("--process-id", default=None, help="this one's i")
    scale.add_argument(
        "--memory",
        default=None,
        help="bytes each process may use (1GiB, 800M); frames that do not fit "
        "are streamed from disk in blocks",
    )
    scale.add_argument(
        "--stream", action="store_true", help="stream the frames from disk always"
    )
    scale.add_argument(
        "--shards",
        default=None,
        help="image sources: describe them into this folder of .npy shards as "
        "they are read, then fit from the shards",
    )
    p.add_argument(
        "--positions",
        nargs="+",
        default=None,
        help="per-frame positions of the sources, one CSV/.npy per source "
        "(easting,northing metres or latitude,longitude), or 'names' for "
        "@easting@northing@ file names; saved for evaluate --ground-truth",
    )
    p.add_argument(
        "--places",
        default=None,
        help="group the frames into K places by k-means over --positions (the "
        "RobotCar protocol); traversals may then differ in length",
    )
    p.add_argument(
        "--codes",
        default=None,
        metavar="BITS|int8",
        help="also store a code per place: BITS-bit ITQ (1 <= BITS <= d), or int8 "
        "(a byte per dimension: d bytes a place, best on an --embedding); queries "
        "fuse the map's place scores with the code similarities",
    )
    p.add_argument(
        "--fusion",
        default=None,
        help="the map's share of the fused score with --codes (default: the weight "
        "the --embedding learned for these codes, else 0.5)",
    )
    _add_source_options(p)

    p.add_argument(
        "--embedding",
        default=None,
        help="embedding folder written by 'rhythmic-jax learn' (saved in the map "
        "and applied to every query; its descriptor unless --descriptor is given)",
    )

    p = add(
        "learn",
        "learn an embedding from two or more traversals of a training route",
    )
    p.add_argument("sources", nargs="+", help="one source per traversal (same places)")
    p.add_argument("--out", required=True, help="embedding folder to write")
    p.add_argument(
        "--method",
        default="invariant",
        choices=("invariant", "pca", "map", "infonce"),
        help="closed form (default), principal axes only, learned through the "
        "map, or InfoNCE",
    )
    p.add_argument("--head", default="linear", choices=("linear", "mlp"))
    p.add_argument("--k", default=256, help="output dimensions (256)")
    p.add_argument("--steps", default=300, help="gradient steps (300)")
    p.add_argument("--seed", default=0, help="PRNG seed (0)")
    p.add_argument(
        "--codes",
        default="int8",
        metavar="BITS|int8",
        help="codes a map's fusion weight is learned for on these traversals and "
        "saved with the embedding for fit --embedding (int8)",
    )
    _add_source_options(p)

    p = add("query", "localise queries against a map (-1 = no match)")
    p.add_argument("map", help="map folder")
    p.add_argument("source", help="query descriptors .npy, image folder or image")
    p.add_argument("--out", default=None, help="write predictions to this .npy")
    p.add_argument("--decode", default=None, choices=DECODERS)
    p.add_argument(
        "--sequence",
        default=None,
        help="sequence length L (at most the number of queries)",
    )
    p.add_argument(
        "--threshold",
        default=None,
        help="reject queries whose confidence is below this",
    )
    p.add_argument("--json", action="store_true", help="print predictions as JSON")
    _add_source_options(p)

    p = add(
        "info",
        "describe a map (n, d, periods, storage, candidate errors) or an embedding",
    )
    p.add_argument("map", help="map folder (or embedding folder)")
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
        "--tolerance",
        default=0,
        help="frame tolerance (default 0)",
    )
    p.add_argument("--decode", default=None, choices=DECODERS)
    p.add_argument(
        "--sequence",
        default=None,
        help="sequence length L, at most the number of queries (accuracy, PR and "
        "recall@K use the sequence scores)",
    )
    p.add_argument(
        "--ground-truth",
        nargs="+",
        default=None,
        metavar="FILE",
        help="VPR-Bench ground_truth_new.npy; or QUERY_POSITIONS (the map's from "
        "fit --positions); or REF_POSITIONS QUERY_POSITIONS; or 'names' "
        "(@easting@northing@ file names). Default: query i is place i",
    )
    p.add_argument(
        "--tolerance-m",
        default=25.0,
        help="radius of a right match for positions, metres (default 25)",
    )
    p.add_argument("--plot", default=None, help="write PR curves and recall@K (.png)")
    p.add_argument("--json", action="store_true", help="print JSON")
    _add_source_options(p)

    p = add("frontier", "recall against bytes per place of every representation")
    p.add_argument("reference", help="reference descriptors (.npy, .h5) or folder")
    p.add_argument("queries", help="query descriptors (.npy, .h5) or folder")
    p.add_argument(
        "--ground-truth",
        nargs="+",
        default=None,
        metavar="FILE",
        help="as evaluate reads it (default: query i is place i)",
    )
    p.add_argument("--tolerance", default=0, help="frame tolerance (default 0)")
    p.add_argument("--tolerance-m", default=25.0, help="radius for positions, m")
    p.add_argument(
        "--budget",
        default=None,
        metavar="BYTES_PER_PLACE",
        help="name the best representation within this many bytes",
    )
    p.add_argument(
        "--maps",
        default="2:1,2:2,2:3,2:4,3:1,3:2,3:3,3:4",
        help="maps as r:level,... (default every r=2,3 at levels 1-4)",
    )
    p.add_argument("--bits", default="32,64,128,256,512", help="ITQ code sizes")
    p.add_argument("--pq", default="8,16,32,64", help="PQ sub-quantisers ('': none)")
    p.add_argument("--lengths", default="1,5,10", help="sequence lengths L")
    p.add_argument("--descriptor", default=None, help="descriptor for image folders")
    p.add_argument("--cache", default="", help="folder keeping fitted maps and codes")
    p.add_argument("--csv", default=None, help="write the rows as CSV")
    p.add_argument("--plot", default=None, help="draw the frontier (.png)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.add_argument("--no-progress", action="store_true", help="hide progress bars")

    p = add("demo", "fit and query a map on built-in photographs; write a report")
    p.add_argument("--out", default="rhythmic_demo", help="report folder")
    p.add_argument("--quick", action="store_true", help="a smaller route (CI)")
    p.add_argument("--no-progress", action="store_true", help="hide progress bars")
    for command in parser.commands.values():
        _stated(command)
    return parser


def _reading(args) -> jobs.Reading:
    from rhythmic_jax.app import jobs

    compile_ = CompilePolicy(args.compile, args.compile_min_frames)
    return jobs.Reading(args.descriptor, args.weights, args.tile, args.stride, compile_)


def _fit_job(args, given: frozenset[str]) -> jobs.FitJob:
    from rhythmic_jax.app import jobs

    config = MapConfig(
        r=args.r, level=args.level, count=args.count, c=args.c, solver=args.solver,
        gap=args.gap, layout=args.layout, dtype=args.dtype, codes=args.codes,
    )  # fmt: skip
    scale = jobs.ScaleJob(
        processes=args.processes, coordinator=args.coordinator,
        num_processes=args.num_processes, process_id=args.process_id,
        memory=args.memory, stream=args.stream, shards=args.shards,
    )  # fmt: skip
    return jobs.FitJob(
        sources=tuple(args.sources), out=args.out, config=config, pca=args.pca,
        augment=args.augment, epochs=args.epochs, batch_size=args.batch_size,
        checkpoint=args.checkpoint, checkpoint_every=args.checkpoint_every,
        reading=_reading(args), places=args.places, fusion=args.fusion,
        positions=tuple(args.positions) if args.positions else None,
        embedding=args.embedding, scale=scale, given=given,
    )  # fmt: skip


def _learn_job(args, given: frozenset[str]) -> jobs.LearnJob:
    from rhythmic_jax.app import jobs

    config = jobs.learn_config(
        method=args.method, head=args.head, k=args.k, steps=args.steps, seed=args.seed
    )
    return jobs.LearnJob(
        tuple(args.sources), args.out, config, _reading(args), args.codes, given
    )


def _query_job(args, given: frozenset[str]) -> jobs.QueryJob:
    from rhythmic_jax.app import jobs

    return jobs.QueryJob(
        args.map, args.source, decode=args.decode, sequence=args.sequence,
        threshold=args.threshold, out=args.out, reading=_reading(args), given=given,
    )  # fmt: skip


def _evaluate_job(args, given: frozenset[str]) -> jobs.EvaluateJob:
    from rhythmic_jax.app import jobs

    return jobs.EvaluateJob(
        args.map, args.source, reference=args.reference, tolerance=args.tolerance,
        decode=args.decode, sequence=args.sequence, tolerance_m=args.tolerance_m,
        ground_truth=tuple(args.ground_truth) if args.ground_truth else None,
        plot=args.plot, reading=_reading(args), given=given,
    )  # fmt: skip


def _cmd_fit(args, job: jobs.FitJob) -> int:
    from rhythmic_jax.app import jobs

    run = None
    if jobs.wants_scale(job):
        model, run = jobs.fit_scaled(job, args.argv, not args.no_progress)
        if model is None:
            return 0
    else:
        model = jobs.fit(job, progress=not args.no_progress)
    info = model.info()
    if run is not None:
        info["fit"] = dict(run)
        if "pass_seconds" in run:  # every pass, to the millisecond
            info["fit"]["pass_seconds"] = [round(t, 3) for t in run["pass_seconds"]]
    print(json.dumps(info, indent=2) if args.json else jobs.fit_summary(args.out, info))
    return 0


def _cmd_query(args, job: jobs.QueryJob) -> int:
    from rhythmic_jax.app import jobs

    pred = jobs.query(job, progress=not args.no_progress)
    if args.json:
        print(json.dumps({"predictions": pred.tolist()}))
    elif not args.out:
        print("\n".join(str(int(v)) for v in pred))
    else:
        print(jobs.query_summary(pred, args.out))
    return 0


def _cmd_learn(args, job: jobs.LearnJob) -> int:
    from rhythmic_jax.app import jobs

    emb, info = jobs.learn(job, progress=not args.no_progress)
    print(jobs.learn_summary(args.out, emb, info))
    return 0


def _cmd_info(args, job: None) -> int:
    from rhythmic_jax.app import jobs

    info = jobs.info(args.map)
    print(json.dumps(info, indent=2) if args.json else jobs.info_lines(info))
    return 0


def _cmd_evaluate(args, job: jobs.EvaluateJob) -> int:
    from rhythmic_jax.app import jobs

    result = jobs.evaluate(job, progress=not args.no_progress)
    print(json.dumps(result, indent=2) if args.json else jobs.evaluate_summary(result))
    return 0


def _cmd_demo(args, job: None) -> int:
    from rhythmic_jax.app import jobs

    jobs.demo(args.out, quick=args.quick, progress=not args.no_progress)
    return 0


def _cmd_frontier(args, job: None) -> int:
    from rhythmic_jax.app.frontier import main as frontier_main

    return frontier_main(args)


# command -> (how its options make its job, what runs it)
COMMANDS = {
    "fit": (_fit_job, _cmd_fit),
    "learn": (_learn_job, _cmd_learn),
    "query": (_query_job, _cmd_query),
    "info": (None, _cmd_info),
    "evaluate": (_evaluate_job, _cmd_evaluate),
    "demo": (None, _cmd_demo),
    "frontier": (None, _cmd_frontier),
}


def _checked_job(args, prog: str):
    """The command's job, made (so checked) from the options; a refused option
    or a path written over one read ends in one usage line (InputError)."""
    from rhythmic_jax.app import jobs

    make = COMMANDS[args.command][0]
    job = make and make(args, frozenset(_given_options(args.argv, args)))
    line = check_paths(args)
    if line is not None:
        raise jobs.OptionRefused(line)
    for warning in getattr(job, "warnings", ()):
        print(f"{prog}: warning: {InputError(warning).as_flag()}", file=sys.stderr)
    return job


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``rhythmic-jax``; returns the exit status (2: bad input,
    one line on stderr; 0 after ``--help``; 141 when standard output is closed
    early, as by ``| head``: quietly, as a command killed by SIGPIPE)."""
    from rhythmic_jax.app import jobs

    try:
        args = _parser().parse_args(argv)
    except SystemExit as done:  # --help, or a usage error already printed
        return int(done.code or 0)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    prog = f"rhythmic-jax {args.command}"
    try:
        job = _checked_job(args, prog)
    except jobs.OptionRefused as err:
        print(f"{prog}: error: {err.as_flag()} (see {prog} --help)", file=sys.stderr)
        return 2
    except InputError as err:
        print(f"{prog}: error: {err.as_flag()}", file=sys.stderr)
        return 2
    _quiet_logs(args.verbose)
    if args.command != "info":
        from rhythmic_jax.jit_cache import enable_compile_cache

        enable_compile_cache()  # programs kept between runs; see the epilog
    try:
        status = COMMANDS[args.command][1](args, job)
        sys.stdout.flush()  # a closed pipe is found here, not at exit
        return status
    except InputError as err:
        print(f"rhythmic-jax {args.command}: error: {err.as_flag()}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as err:
        from rhythmic_jax.app.jobs import FitInterrupted

        if isinstance(err, FitInterrupted):
            print(f"rhythmic-jax {args.command}: {err.note}", file=sys.stderr)
        print(f"rhythmic-jax {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # the reader left (| head): nothing more to say
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141


def run() -> None:
    """The installed ``rhythmic-jax``: :func:`main`, then exit.

    Before the interpreter shuts down, every object still alive is moved out of
    the garbage collector's reach (``gc.freeze``): its last full collection would
    otherwise walk torch's and JAX's objects one by one, about 0.6 s on the
    reference machine, to free memory the process hands back on exit anyway.

    Ctrl-C and SIGTERM end the command at once, with one line and exit status
    130 (143), writing nothing more; a failed process of a multi-process fit
    ends at once too (:mod:`rhythmic_jax.app.signals`).
    """
    from rhythmic_jax.app import signals

    signals.install(next((a for a in sys.argv[1:] if a in COMMANDS), None))
    status = main()
    if any(a.split("=")[0] == "--coordinator" for a in sys.argv[1:]):
        signals.finish(status)  # failed: its cluster's peers must not be waited for
    gc.freeze()
    sys.exit(status)


if __name__ == "__main__":
    run()
