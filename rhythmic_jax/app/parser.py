"""The parser of ``rhythmic-jax``: each command's options rendered from its job.

A command is its job's class (:mod:`rhythmic_jax.app.specs`), whose fields are
its options (:func:`rhythmic_jax.app.options.add_options`: help, defaults,
choices, domains), a line saying what it does, and its examples. Built from
light modules only: ``rhythmic-jax --help`` imports no numpy, JAX or torch.
"""

from __future__ import annotations

import argparse
import textwrap

from rhythmic_jax.app import specs
from rhythmic_jax.app.options import add_options
from rhythmic_jax.frames.compile_policy import BUILD_MIN_FRAMES, LOAD_MIN_FRAMES
from rhythmic_jax.version import __version__

__all__ = ["COMPILE_NOTE", "EXAMPLES", "JOBS", "given_options", "parser"]

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
      rhythmic-jax learn summer/ winter/ --descriptor patchnorm --out route.emb \\
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
      rhythmic-jax query route.map winter/ --csv results.csv --ground-truth names
        (and a 'correct' column)
      rhythmic-jax query route.map DATASET/query --pairs pairs.txt --top 20
        (hloc's retrieval pairs, for its local matching)
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
      rhythmic-jax evaluate hybrid.map winter/ --tolerance 1 --plot hybrid.png
      rhythmic-jax evaluate route.map winter/ --tolerance 1 --matches matches.png
      rhythmic-jax evaluate route.map winter.npy --tolerance 1 --per-query q.csv \\
          --num-preds 10 --recall-values 1,5,10,25
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


COMPILE_NOTE = textwrap.fill(
    "--compile (fit, learn, query, evaluate): a network descriptor "
    "(efficientnet_lite0, vgg16_fc7) compiled for this CPU gives about 1.5-1.8x the "
    "frames/s of the eager network, but building it costs up to a minute once per "
    "machine and settings (kept in the cache folder) and loading it about 0.2 s per "
    f"job. auto (default): a job of >= {LOAD_MIN_FRAMES} frames loads the compiled "
    "network; the first such job on a machine runs eagerly, at the eager network's "
    "speed, and a background build (a niced process, about a minute of CPU) starts "
    "once it is over, so the next job runs compiled; a job of >= "
    f"{BUILD_MIN_FRAMES} frames builds it first "
    "(RHYTHMIC_JAX_NETWORK_BUILD=0: no background builds); always; never (the eager "
    "reference). Without a C++ compiler the job runs eagerly and says so.",
    79,
)


class _Parser(argparse.ArgumentParser):
    """Usage errors in one line, like every other refusal (exit status 2)."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def given_options(argv: list[str], parsed: argparse.Namespace) -> set[str]:
    """The destinations of the options ``argv`` gives (not left at a default)."""
    built = parser()
    for action in built.commands[parsed.command]._actions:
        action.default = argparse.SUPPRESS  # left out: not in the namespace
    seen, _ = built.parse_known_args(argv)
    return set(vars(seen))


def parser() -> argparse.ArgumentParser:
    """The parser: each command's options rendered from its job's fields
    (:func:`rhythmic_jax.app.options.add_options`)."""
    top = _Parser(
        prog="rhythmic-jax",
        description="Sub-linear-storage place recognition with rhythmic templates.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="run 'rhythmic-jax COMMAND --help' for examples\n\n"
        "compiled programs are kept in $RHYTHMIC_JAX_CACHE/jax (default\n"
        "~/.cache/rhythmic_jax/jax): later runs load them instead of compiling;\n"
        "RHYTHMIC_JAX_COMPILE_CACHE=0 turns that off, =FOLDER moves it\n\n"
        + COMPILE_NOTE,
    )
    _verbose(top, False)
    top.add_argument("--version", action="version",
                     version=f"%(prog)s {__version__}")  # fmt: skip
    sub = top.add_subparsers(dest="command", required=True, parser_class=_Parser)
    top.commands = {}
    for name, (job, about) in JOBS.items():
        top.commands[name] = sub.add_parser(
            name, help=about, description=about,
            epilog="examples:" + textwrap.dedent(EXAMPLES[name]),
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )  # fmt: skip
        add_options(top.commands[name], job)
        _verbose(top.commands[name], argparse.SUPPRESS)  # keeps one given before
    return top


def _verbose(parser: argparse.ArgumentParser, default) -> None:
    """``-v/--verbose``, offered before the command's name and after it."""
    says = "log progress (before or after the command's name)"
    parser.add_argument("-v", "--verbose", action="store_true", default=default,
                        help=says)  # fmt: skip


# command -> (its job, whose fields are its options; what it does)
JOBS = {
    "fit": (specs.FitJob, "fit a map on reference frames (.npy, image folders, or "
            "--tile)"),
    "learn": (specs.LearnJob, "learn an embedding from two or more traversals of "
              "a training route"),
    "query": (specs.QueryJob, "localise queries against a map (-1 = no match)"),
    "info": (specs.InfoJob, "describe a map (n, d, periods, storage, candidate "
             "errors) or an embedding"),
    "evaluate": (specs.EvaluateJob, "accuracy, recall@K, storage and latency "
                 "beside brute force"),
    "demo": (specs.DemoJob, "fit and query a map on built-in photographs; write a "
             "report"),
    "describe": (specs.DescribeJob, "describe a route's frames once into a .npy "
                 "that fit, query, evaluate, learn and frontier read"),
    "frontier": (specs.FrontierJob, "recall against bytes per place of every "
                 "representation"),
}  # fmt: skip
