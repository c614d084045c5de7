"""The ``rhythmic-jax`` command line: argparse over :mod:`rhythmic_jax.app.jobs`.

Every command parses its arguments, makes its job (:mod:`rhythmic_jax.app.specs`:
it checks itself, each option in its domain and against the others, the job's
rules), runs it (:mod:`rhythmic_jax.app.jobs`) and prints what it returns
(:mod:`rhythmic_jax.app.render`); bad input ends with one line on stderr
(settings spelled as flags) and exit status 2, and nothing half-written on disk.

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

from rhythmic_jax.app import specs
from rhythmic_jax.errors import InputError
from rhythmic_jax.frames.compile_policy import (
    BUILD_MIN_FRAMES,
    COMPILE_MODES,
    LOAD_MIN_FRAMES,
    CompilePolicy,
)
from rhythmic_jax.map.config import DECODERS, DTYPES, SOLVERS, MapConfig
from rhythmic_jax.version import __version__

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
      rhythmic-jax query route.map winter/ --top 5 --csv results.csv
        (per query: its file name, the place chosen and its name, score,
        confidence, and the 5 best places with their scores)
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
      rhythmic-jax evaluate route.map winter/ --tolerance 1 --matches matches.png
    """,
    "demo": """
      rhythmic-jax demo
      rhythmic-jax demo --out demo_report --quick
    """,
    "describe": """
      rhythmic-jax describe summer/ --descriptor efficientnet_lite0 --out summer.npy
      rhythmic-jax describe winter/ --descriptor efficientnet_lite0 --out winter.npy
      rhythmic-jax fit summer.npy --out route.map    (no image described again)
      rhythmic-jax frontier summer.npy winter.npy --tolerance 1
      rhythmic-jax describe city.png --tile 224 --stride 112 --out city.npy
    """,
    "frontier": """
      rhythmic-jax frontier summer.npy winter.npy --tolerance 1 --budget 2000
      rhythmic-jax frontier db.h5 q.h5 --ground-truth GT.npz --lengths 1 \\
          --csv frontier.csv --plot frontier.png
    """,
}


def _opt(flags: str, help_: str | None = None, **settings) -> tuple[list[str], dict]:
    """One row of :data:`OPTIONS`: the flags (or a positional's name) and what
    ``add_argument`` takes (``group``: the title of the option's group)."""
    return flags.split(), {"help": help_, **settings}


FLAG = {"action": "store_true"}
SOURCE = (  # how the frames of image sources are read (fit, learn, query, evaluate)
    _opt("--descriptor", "descriptor for image sources (patchnorm, hog, "
         "efficientnet_lite0, vgg16_fc7; default patchnorm, or an --embedding's); a "
         "map remembers its own"),
    _opt("--weights", "weights file of vgg16_fc7 (a state dict); when querying a "
         "map, a moved copy of the file it was fitted with (its sha256 is checked)"),
    _opt("--tile", "tile a large image: size (queries of a tiled map: the map's own)"),
    _opt("--stride", "tile stride, with --tile (default size/2)"),
    _opt("--compile", "when a network descriptor (efficientnet_lite0, vgg16_fc7) "
         "runs compiled for this CPU (see the main --help)", default="auto",
         choices=COMPILE_MODES),
    _opt("--compile-min-frames", "with --compile auto, compile from N frames on "
         f"(built or not; default {LOAD_MIN_FRAMES})", metavar="N"),
    _opt("--no-progress", "hide progress bars", **FLAG),
)  # fmt: skip
QUERIES = "query descriptors .npy, image folder or image"
SELECT = "only the queries of an hloc .h5 whose names start with PREFIX (query/)"
GT_FORMAT = ("the --ground-truth file's format (default: read from what it holds; "
             "its name only breaks a tie)")  # fmt: skip
RECALL_OVER = ("recall@K's denominator: the queries with a right place (matched, "
               "VPR_Tutorial's; default) or every query (all, "
               "VPR-methods-evaluation's); the table says which")  # fmt: skip
DECODE = ("how a query's place is read from the map's scores: hard (the best "
          "phase of each period, joined by the Chinese remainder; -1, no match, "
          "when they name no place of the route), soft (the place of the highest "
          "summed phase scores), topm (soft among the m best phases of each "
          "period); default the map's own (fit: hard)")
COMPILE_NOTE = textwrap.fill(
    "--compile (fit, learn, query, evaluate): a network descriptor "
    "(efficientnet_lite0, vgg16_fc7) compiled for this CPU gives about 1.5-1.8x the "
    "frames/s of the eager network, but building it costs up to a minute once per "
    "machine and settings (kept in the cache folder) and loading it about 0.2 s per "
    f"job. auto (default): a job of >= {LOAD_MIN_FRAMES} frames loads the compiled "
    "network; the first such job on a machine runs eagerly and pays only for a "
    "background build (a niced process, about a minute of CPU beside it), so the "
    f"next job runs compiled; a job of >= {BUILD_MIN_FRAMES} frames builds it first "
    "(RHYTHMIC_JAX_NETWORK_BUILD=0: no background builds); always; never (the eager "
    "reference). Without a C++ compiler the job runs eagerly and says so.",
    79,
)
SCALE = "scale (descriptor files or shard folders)"
CODES = {"metavar": "BITS|int8"}

# command -> (what it does, its options in the order --help lists them); a
# numeric option's type and the domain --help states come from specs.DOMAINS
OPTIONS = {
    "fit": ("fit a map on reference frames (.npy, image folders, or --tile)", (
        _opt("sources", "descriptor .npy, image folder(s), image", nargs="+"),
        _opt("--select", "only the images of hloc .h5 sources whose names start "
             "with PREFIX (db/; the map keeps it for brute force)", metavar="PREFIX"),
        _opt("--out", "map folder to write", required=True),
        _opt("--r", f"number of periods (default {DEFAULTS.r})", default=DEFAULTS.r),
        _opt("--level", "period level c (c*N^(1/r))", default=DEFAULTS.level),
        _opt("--count", f"candidate periods (default {DEFAULTS.count})",
             default=DEFAULTS.count),
        _opt("--c", "SVM penalty (default log N)", default=DEFAULTS.c),
        _opt("--solver", "how the SVMs are solved (newton: Newton-CG to --gap)",
             default=DEFAULTS.solver, choices=SOLVERS),
        _opt("--gap", "stop the solver at this estimated relative objective gap "
             "(default %(default)g: the optimum; 1e-3 stops within about 0.1 %%, "
             "sooner)",
             default=DEFAULTS.gap),
        _opt("--layout", "how frames are labelled: periods (default, chosen by "
             "training error), periods:T1,T2, mixed or mixed:B1,..,Br (mixed-radix "
             "digits, most significant first: it classifies contiguous segments), "
             "hierarchical, hierarchical:SEG or hierarchical:SEG:T1,T2 (segments of "
             "SEG frames plus co-prime fine periods); sizes left out match the "
             "storage of --r/--level", default=DEFAULTS.layout),
        _opt("--json", "print the map's info as JSON", **FLAG),
        _opt("--augment", "train over frames augmented on the fly (image sources): "
             "comma-separated names from gaussian_blur, hflip, random_crop, elastic, "
             "contrast, invert, grayscale, or 'all'"),
        _opt("--epochs", "augmented epochs (default 3)"),
        _opt("--batch-size", "augmented frames per step (default 128)"),
        _opt("--checkpoint", "checkpoint folder of an augmented fit (default "
             "OUT.ckpt, removed once the map is saved); a killed or interrupted fit "
             "resumes from it when the same command runs again"),
        _opt("--checkpoint-every", "steps between checkpoints of an augmented fit "
             "(default 50)"),
        _opt("--pca", "project descriptors to K dims (saved)"),
        _opt("--dtype", "how the map stores its templates (int8: a scale per "
             "template)", default=DEFAULTS.dtype, choices=DTYPES),
        _opt("--processes", "start this many local processes for one fit (frames "
             "split by rows)", default=1, group=SCALE),
        _opt("--coordinator", "HOST:PORT of process 0", group=SCALE),
        _opt("--num-processes", "K hosts", group=SCALE),
        _opt("--process-id", "this one's i", group=SCALE),
        _opt("--memory", "bytes each process may use (1GiB, 800M); frames that do "
             "not fit are streamed from disk in blocks", group=SCALE),
        _opt("--stream", "stream the frames from disk always", group=SCALE, **FLAG),
        _opt("--shards", "image sources: describe them into this folder of .npy "
             "shards as they are read, then fit from the shards", group=SCALE),
        _opt("--positions", "per-frame positions of the sources, one CSV/.npy per "
             "source (easting,northing metres or latitude,longitude), or 'names' for "
             "@easting@northing@ file names; saved for evaluate --ground-truth",
             nargs="+"),
        _opt("--places", "group the frames into K places by k-means over "
             "--positions (the RobotCar protocol); traversals may then differ in "
             "length"),
        _opt("--codes", "also store a code per place: BITS-bit ITQ (1 <= BITS <= "
             "d), or int8 (a byte per dimension: d bytes a place, best on an "
             "--embedding); queries fuse the map's place scores with the code "
             "similarities", **CODES),
        _opt("--fusion", "the map's share of the fused score with --codes "
             "(default: the weight the --embedding learned for these codes, else "
             "0.5)"),
        *SOURCE,
        _opt("--embedding", "embedding folder written by 'rhythmic-jax learn' "
             "(saved in the map and applied to every query; its descriptor unless "
             "--descriptor is given)"),
    )),
    "learn": ("learn an embedding from two or more traversals of a training route", (
        _opt("sources", "one source per traversal (same places)", nargs="+"),
        _opt("--out", "embedding folder to write", required=True),
        _opt("--method", "invariant: closed form, pca: principal axes only, map: "
             "learned through the map, infonce: InfoNCE", default="invariant",
             choices=("invariant", "pca", "map", "infonce")),
        _opt("--head", "the learned head of --method map or infonce: linear (k x k) "
             "or mlp (plus a residual ReLU layer)", default="linear",
             choices=("linear", "mlp")),
        _opt("--k", "output dimensions", default=256),
        _opt("--steps", "gradient steps", default=300),
        _opt("--seed", "PRNG seed", default=0),
        _opt("--codes", "codes a map's fusion weight is learned for on these "
             "traversals and saved with the embedding for fit --embedding",
             default="int8", **CODES),
        *SOURCE,
    )),
    "query": ("localise queries against a map (-1 = no match)", (
        _opt("map", "map folder"),
        _opt("source", QUERIES),
        _opt("--select", SELECT, metavar="PREFIX"),
        _opt("--out", "write predictions to this .npy"),
        _opt("--decode", DECODE, choices=DECODERS),
        _opt("--sequence", "sequence length L (at most the number of queries; "
             "default off: single frames)"),
        _opt("--threshold", "reject queries whose confidence is below this "
             "(default none: every query gets a place)"),
        _opt("--json", "print JSON: the predictions, and per query its name (file "
             "name, else row), the place chosen (and its name where the map's "
             "reference names it), its score and confidence, and the --top best "
             "places with their scores", **FLAG),
        _opt("--top", "best places listed per query (--json, --csv)", default=5),
        _opt("--csv", "write the results per query as CSV (query, place, "
             "place_name, score, confidence, top1, top1_name, top1_score, ...)"),
        *SOURCE,
    )),
    "info": ("describe a map (n, d, periods, storage, candidate errors) or an "
             "embedding", (
        _opt("map", "map folder (or embedding folder)"),
        _opt("--json", "print JSON", **FLAG),
    )),
    "evaluate": ("accuracy, recall@K, storage and latency beside brute force", (
        _opt("map", "map folder"),
        _opt("source", QUERIES),
        _opt("--select", SELECT + " (an .h5 reference: the map's prefix)",
             metavar="PREFIX"),
        _opt("--reference", "reference source for the brute-force line (default: "
             "the sources the map was fitted on, when they are still there)"),
        _opt("--tolerance", "frame tolerance (default 0)", default=0),
        _opt("--decode", DECODE, choices=DECODERS),
        _opt("--sequence", "sequence length L, at most the number of queries "
             "(accuracy, PR and recall@K use the sequence scores; default off)"),
        _opt("--ground-truth", "VPR-Bench ground_truth_new.npy; or QUERY_POSITIONS "
             "(the map's from fit --positions); or REF_POSITIONS QUERY_POSITIONS; or "
             "'names' (@easting@northing@ file names). Default: query i is place i",
             nargs="+", metavar="FILE"),
        _opt("--ground-truth-format", GT_FORMAT, choices=specs.GROUND_TRUTH_FORMATS),
        _opt("--tolerance-m", "radius of a right match for positions, metres "
             "(default %(default)g)", default=25.0),
        _opt("--recall-over", RECALL_OVER, default="matched",
             choices=specs.RECALL_OVER),
        _opt("--plot", "write PR curves, recall@N (N = 1..20) and the predicted "
             "place against query index along the route (.png)"),
        _opt("--matches", "draw queries beside the place chosen and the right "
             "place, 4 successes and the 4 most confident failures (.png; the "
             "queries and the reference as image folders)"),
        _opt("--json", "print JSON", **FLAG),
        *SOURCE,
    )),
    "demo": ("fit and query a map on built-in photographs; write a report", (
        _opt("--out", "report folder", default="rhythmic_demo"),
        _opt("--quick", "a smaller route (CI)", **FLAG),
        _opt("--no-progress", "hide progress bars", **FLAG),
    )),
    "describe": ("describe a route's frames once into a .npy that fit, query, "
                 "evaluate, learn and frontier read", (
        _opt("source", "image folder (frames sorted by name), or one large image "
             "with --tile"),
        _opt("--out", "descriptor file to write (.npy, float32, one row per frame)",
             required=True),
        *SOURCE,
    )),
    "frontier": ("recall against bytes per place of every representation", (
        _opt("reference", "reference descriptors (.npy, .h5) or folder"),
        _opt("queries", "query descriptors (.npy, .h5) or folder"),
        _opt("--select", "the images of hloc .h5 files whose names start with "
             "REF_PREFIX, QUERY_PREFIX ('' takes all): one file split in two",
             nargs=2, metavar=("REF_PREFIX", "QUERY_PREFIX")),
        _opt("--ground-truth", "as evaluate reads it (default: query i is place i)",
             nargs="+", metavar="FILE"),
        _opt("--ground-truth-format", GT_FORMAT, choices=specs.GROUND_TRUTH_FORMATS),
        _opt("--recall-over", RECALL_OVER, default="matched",
             choices=specs.RECALL_OVER),
        _opt("--tolerance", "frame tolerance (default 0)", default=0),
        _opt("--tolerance-m", "radius for positions, m (default %(default)g)",
             default=25.0),
        _opt("--budget", "name the best representation within this many bytes",
             metavar="BYTES_PER_PLACE"),
        _opt("--grid", "the representations fitted unless --maps, --bits or --pq "
             f"say otherwise: small ({specs.grid_text('small')}: a couple of "
             f"minutes on a few thousand places), full ({specs.grid_text('full')})",
             default="small", choices=tuple(specs.GRIDS)),
        _opt("--maps", "maps as r:level,... (default: the --grid's)"),
        _opt("--bits", "ITQ code sizes, comma-separated (default: the --grid's)"),
        _opt("--pq", "PQ sub-quantisers ('': none; default: the --grid's)"),
        _opt("--lengths", "sequence lengths L", default="1,5,10"),
        _opt("--descriptor", "descriptor for image folders (default patchnorm)"),
        _opt("--cache", "folder keeping fitted maps and codes (default none)",
             default=""),
        _opt("--csv", "write the rows as CSV"),
        _opt("--plot", "draw the frontier (.png)"),
        _opt("--json", "print JSON", **FLAG),
        _opt("--no-progress", "hide progress bars", **FLAG),
    )),
}  # fmt: skip


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


def _state_default(action: argparse.Action) -> None:
    """An option's help ends with its default, unless it says it already: a
    declared default (not None, False or '') is stated from the declaration."""
    default = action.default
    if not action.option_strings or default is None or default is False:
        return
    if default == "":
        return
    if "default" not in (action.help or ""):
        action.help = f"{action.help or ''} (default %(default)s)".lstrip()


def _parser() -> argparse.ArgumentParser:
    """The parser rendered from :data:`OPTIONS`; every numeric option parsed
    with its domain (:data:`rhythmic_jax.app.specs.DOMAINS`), stated in --help."""
    parser = _Parser(
        prog="rhythmic-jax",
        description="Sub-linear-storage place recognition with rhythmic templates.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="run 'rhythmic-jax COMMAND --help' for examples\n\n"
        "compiled programs are kept in $RHYTHMIC_JAX_CACHE/jax (default\n"
        "~/.cache/rhythmic_jax/jax): later runs load them instead of compiling;\n"
        "RHYTHMIC_JAX_COMPILE_CACHE=0 turns that off, =FOLDER moves it\n\n"
        + COMPILE_NOTE,
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress")
    parser.add_argument("--version", action="version",
                        version=f"%(prog)s {__version__}")  # fmt: skip
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    parser.commands = {}
    for name, (help_, options) in OPTIONS.items():
        p = parser.commands[name] = sub.add_parser(
            name, help=help_, description=help_,
            epilog="examples:" + textwrap.dedent(EXAMPLES[name]),
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )  # fmt: skip
        groups = {}
        for flags, settings in options:
            settings = dict(settings)
            title = settings.pop("group", None)
            if title is not None and title not in groups:
                groups[title] = p.add_argument_group(title)
            action = groups.get(title, p).add_argument(*flags, **settings)
            _state_default(action)
            domain = specs.DOMAINS.get(action.dest)
            if domain is not None and action.option_strings:
                action.type = domain
                action.help = f"{action.help or ''} [{domain.text()}]".lstrip()
    return parser


def _take(args, names: str) -> dict:
    """``{name: option}`` of the space-separated ``names`` (lists as tuples)."""
    values = {name: getattr(args, name) for name in names.split()}
    return {k: tuple(v) if isinstance(v, list) else v for k, v in values.items()}


# command -> (its job's class in specs, the options that are the job's own)
JOBS = {
    "fit": ("FitJob", "sources out pca augment epochs batch_size checkpoint "
            "checkpoint_every fusion positions places embedding"),
    "learn": ("LearnJob", "sources out codes"),
    "query": ("QueryJob", "map source decode sequence threshold out top csv json"),
    "evaluate": ("EvaluateJob", "map source reference tolerance decode sequence "
                 "ground_truth tolerance_m plot matches"),
    "describe": ("DescribeJob", "source out"),
}  # fmt: skip


def _job(args, given: frozenset[str]):
    """The command's job made (so checked) from its options; None for info and
    demo, which take no settings a rule could refuse."""
    if args.command not in JOBS:
        return None
    kind, own = JOBS[args.command]
    parts = {"reading": specs.Reading(
        compile=CompilePolicy(args.compile, args.compile_min_frames),
        **_take(args, "descriptor weights tile stride"),
        select=getattr(args, "select", None),
    )}  # fmt: skip
    if args.command == "fit":
        parts["config"] = MapConfig(
            **_take(args, "r level count c solver gap layout dtype codes")
        )
        parts["scale"] = specs.ScaleJob(**_take(
            args, "processes coordinator num_processes process_id memory stream shards"
        ))  # fmt: skip
    elif args.command == "learn":
        parts["config"] = specs.learn_config(**_take(args, "method head k steps seed"))
    elif args.command == "evaluate":  # how the ground truth is read and counted
        parts.update(_take(args, "ground_truth_format recall_over"))
    return getattr(specs, kind)(**_take(args, own), **parts, given=given)


def _fit(args, job, progress: bool) -> str | None:
    from rhythmic_jax.app import jobs, render, scale_jobs

    run = None
    if scale_jobs.wants_scale(job):
        model, run = scale_jobs.fit_scaled(job, args.argv, progress)
        if model is None:
            return None
    else:
        model = jobs.fit(job, progress=progress)
    info = model.info()
    if run is not None:
        info["fit"] = dict(run)
        if "pass_seconds" in run:  # every pass, to the millisecond
            info["fit"]["pass_seconds"] = [round(t, 3) for t in run["pass_seconds"]]
    return (
        json.dumps(info, indent=2) if args.json else render.fit_summary(args.out, info)
    )


def _query(args, job, progress: bool) -> str:
    import numpy as np

    from rhythmic_jax.app import jobs, render

    if args.json or args.csv:
        result = jobs.query_results(job, progress=progress)
        if args.json:
            return json.dumps(result, indent=1)
        pred = np.asarray(result["predictions"])
        return render.query_summary(pred, args.out, args.csv)
    pred = jobs.query(job, progress=progress)
    if not args.out:
        return "\n".join(str(int(v)) for v in pred)
    return render.query_summary(pred, args.out)


def _learn(args, job, progress: bool) -> str:
    from rhythmic_jax.app import jobs, render

    return render.learn_summary(args.out, *jobs.learn(job, progress=progress))


def _info(args, job, progress: bool) -> str:
    from rhythmic_jax.app import jobs, render

    info = jobs.info(args.map)
    return json.dumps(info, indent=2) if args.json else render.info_lines(info)


def _evaluate(args, job, progress: bool) -> str:
    from rhythmic_jax.app import jobs, render

    result = jobs.evaluate(job, progress=progress)
    return (
        json.dumps(result, indent=2) if args.json else render.evaluate_summary(result)
    )


def _describe(args, job, progress: bool) -> str:
    from rhythmic_jax.app import jobs, render

    return render.describe_summary(job, jobs.describe(job, progress=progress))


def _demo(args, job, progress: bool) -> None:
    from rhythmic_jax.app.demo import run_demo

    run_demo(args.out, quick=args.quick, progress=progress)


def _frontier(args, job, progress: bool) -> None:
    from rhythmic_jax.app.frontier import main as frontier

    frontier(args)  # prints its table itself, before its files are written


# command -> what runs its job and returns the text it prints (None: nothing)
COMMANDS = {"fit": _fit, "learn": _learn, "query": _query, "info": _info,
            "evaluate": _evaluate, "demo": _demo, "frontier": _frontier,
            "describe": _describe}  # fmt: skip


def _checked_job(args, prog: str):
    """The command's job, made (so checked) from the options; a refused option
    or a path written over one read ends in one usage line (InputError)."""
    job = _job(args, frozenset(_given_options(args.argv, args)))
    line = specs.check_paths(args)
    if line is not None:
        raise specs.OptionRefused(line)
    for warning in getattr(job, "warnings", ()):
        print(f"{prog}: warning: {InputError(warning).as_flag()}", file=sys.stderr)
    return job


def _quiet_logs(verbose: bool) -> None:
    from rhythmic_jax.app.jobs import quiet_io_threads

    quiet_io_threads()
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")
    logging.basicConfig(
        level=logging.INFO if verbose else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
    )
    for name in ("absl", "jax", "orbax", "jax._src.xla_bridge"):
        logging.getLogger(name).setLevel(logging.ERROR)


def _say(line: str) -> None:
    from rhythmic_jax.app.signals import readable

    print(readable(line), file=sys.stderr)


def _gib(nbytes: int) -> str:
    return f"{nbytes / 2**30:.2f} GiB"


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``rhythmic-jax``; returns the exit status (2: bad input,
    one line on stderr; 0 after ``--help``; 141 when standard output is closed
    early, as by ``| head``: quietly, as a command killed by SIGPIPE).

    The process's environment ends in a result or one line with status 2: a
    closed standard output is refused before any work (what the command prints
    would be lost), a closed standard error is silent, non-ASCII and non-UTF-8
    paths print on any stream, and memory running out (``ulimit -v`` below
    ``signals.MIN_ADDRESS_SPACE``, a ``MemoryError``, XLA's ``RESOURCE_EXHAUSTED``)
    says so."""
    from rhythmic_jax.app import signals

    stdout_open = signals.standard_streams()
    try:
        args = _parser().parse_args(argv)
    except SystemExit as done:  # --help, or a usage error already printed
        return int(done.code or 0)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    prog = f"rhythmic-jax {args.command}"
    if not stdout_open:
        _say(f"{prog}: error: standard output is closed; give it a place "
             "(> FILE, or > /dev/null to drop what is printed)")  # fmt: skip
        return 2
    signals.library_folders()
    limit = signals.memory_limit()
    if limit is not None and limit < signals.MIN_ADDRESS_SPACE:
        least = _gib(signals.MIN_ADDRESS_SPACE)
        _say(f"{prog}: error: memory ran out: the address-space limit (ulimit -v) "
             f"is {_gib(limit)}; the command needs at least {least}")  # fmt: skip
        return 2
    try:
        return _main(args, prog)
    except Exception as err:  # noqa: BLE001 - only memory's failures are said here
        if not signals.out_of_memory(err):
            raise
        where = "" if limit is None else f" (ulimit -v: {_gib(limit)})"
        _say(f"{prog}: error: memory ran out{where}; free some or give the "
             "command less to hold (see --memory where it is offered)")  # fmt: skip
        return 2


def _main(args, prog: str) -> int:
    """The command of the parsed ``args``: its job made, run and printed."""
    try:
        job = _checked_job(args, prog)
    except specs.OptionRefused as err:
        _say(f"{prog}: error: {err.as_flag()} (see {prog} --help)")
        return 2
    except InputError as err:
        _say(f"{prog}: error: {err.as_flag()}")
        return 2
    _quiet_logs(args.verbose)
    if args.command != "info":
        from rhythmic_jax.jit_cache import enable_compile_cache

        enable_compile_cache()  # programs kept between runs; see the epilog
    try:
        text = COMMANDS[args.command](args, job, not getattr(args, "no_progress", 0))
        if text is not None:
            from rhythmic_jax.app.signals import readable

            print(readable(text))
        sys.stdout.flush()  # a closed pipe is found here, not at exit
        return 0
    except InputError as err:
        _say(f"{prog}: error: {err.as_flag()}")
        return 2
    except specs.Reported as done:  # a worker process said why
        return done.status
    except KeyboardInterrupt as err:
        if isinstance(err, specs.FitInterrupted):
            _say(f"{prog}: {err.note}")
        _say(f"{prog}: interrupted")
        return 130
    except BrokenPipeError:  # the reader left (| head): nothing more to say
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141


def run() -> None:
    """The installed ``rhythmic-jax``: :func:`main`, then exit.

    Before the interpreter shuts down, every object still alive is moved out of
    the garbage collector's reach (``gc.freeze``): its last full collection would
    otherwise walk torch's and JAX's objects one by one, a noticeable part of a
    short command's wall time (``reports/compile.md``), to free memory the
    process hands back on exit anyway.

    Ctrl-C and SIGTERM end the command at once, with one line and exit status
    130 (143), writing nothing more; a failed process of a multi-process fit
    ends at once too (:mod:`rhythmic_jax.app.signals`).
    """
    from rhythmic_jax.app import signals

    signals.standard_streams()  # before the signals' pipe takes a closed 0, 1 or 2
    signals.install(next((a for a in sys.argv[1:] if a in COMMANDS), None))
    status = main()
    if any(a.split("=")[0] == "--coordinator" for a in sys.argv[1:]):
        signals.finish(status)  # failed: its cluster's peers must not be waited for
    gc.freeze()
    sys.exit(status)


if __name__ == "__main__":
    run()
