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
import contextlib
import gc
import json
import logging
import os
import re
import sys
import textwrap

from rhythmic_jax.app import specs
from rhythmic_jax.app.options import (
    OptionRefused,
    add_options,
    check_paths,
    make,
    written,
)
from rhythmic_jax.errors import InputError
from rhythmic_jax.frames.compile_policy import BUILD_MIN_FRAMES, LOAD_MIN_FRAMES
from rhythmic_jax.version import __version__

__all__ = ["main"]

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


def _given_options(argv: list[str], parsed: argparse.Namespace) -> set[str]:
    """The destinations of the options ``argv`` gives (not left at a default)."""
    parser = _parser()
    for action in parser.commands[parsed.command]._actions:
        action.default = argparse.SUPPRESS  # left out: not in the namespace
    seen, _ = parser.parse_known_args(argv)
    return set(vars(seen))


def _parser() -> argparse.ArgumentParser:
    """The parser: each command's options rendered from its job's fields
    (:func:`rhythmic_jax.app.options.add_options`)."""
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
    _verbose(parser, False)
    parser.add_argument("--version", action="version",
                        version=f"%(prog)s {__version__}")  # fmt: skip
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    parser.commands = {}
    for name, (job, about) in JOBS.items():
        parser.commands[name] = sub.add_parser(
            name, help=about, description=about,
            epilog="examples:" + textwrap.dedent(EXAMPLES[name]),
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )  # fmt: skip
        add_options(parser.commands[name], job)
        _verbose(parser.commands[name], argparse.SUPPRESS)  # keeps one given before
    return parser


def _verbose(parser: argparse.ArgumentParser, default) -> None:
    """``-v/--verbose``, offered before the command's name and after it."""
    says = "log progress (before or after the command's name)"
    parser.add_argument("-v", "--verbose", action="store_true", default=default,
                        help=says)  # fmt: skip


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
    note = worth_note(info, job.sources)
    if note is not None:
        _say(f"rhythmic-jax fit: note: {note}")
    if run is not None:
        info["fit"] = dict(run)
        if "pass_seconds" in run:  # every pass, to the millisecond
            info["fit"]["pass_seconds"] = [round(t, 3) for t in run["pass_seconds"]]
    return json.dumps(info, indent=2) if job.json else render.fit_summary(job.out, info)


#: ``fit`` says so when the map holds more than this share of the database's
#: bytes, or a chosen period's classifiers miss more than this share of their
#: own training frames.
WORTH_SHARE, WORTH_ERROR = 0.15, 0.10


def worth_note(info: dict, sources) -> str | None:
    """The line ``fit`` adds when the map may buy nothing: its share of the
    database's bytes (templates, codes and embedding) above
    :data:`WORTH_SHARE`, or the training error of its periods (the largest of
    the chosen periods' ``candidate_errors``) above :data:`WORTH_ERROR`;
    None otherwise."""
    share = (info["storage_bytes"] + (info.get("embedding_bytes") or 0)) / max(
        info["database_bytes"], 1
    )
    errors = dict(zip(info.get("candidates") or [], info.get("candidate_errors") or [],
                      strict=False))  # fmt: skip
    chosen = [errors[p] for p in info.get("periods") or [] if p in errors]
    error = max(chosen, default=0.0)
    why = []
    if share > WORTH_SHARE:
        why.append(f"holds {100 * share:.1f} % of the database's bytes (above "
                   f"{100 * WORTH_SHARE:g} %)")  # fmt: skip
    if error > WORTH_ERROR:
        why.append(f"its periods miss {100 * error:.1f} % of their training frames")
    if not why:
        return None
    ref = " ".join(sources) if len(sources) == 1 else "REF"
    return (f"this map {' and '.join(why)}; 'rhythmic-jax frontier {ref} QUERIES' "
            "shows which representation fits this route")  # fmt: skip


def _query(args, job, progress: bool) -> str:
    import numpy as np

    from rhythmic_jax.app import jobs, render

    if job.json or job.csv or job.pairs:
        result = jobs.query_results(job, progress=progress)
        if job.json:
            return json.dumps(result, indent=1)
        pred = np.asarray(result["predictions"])
        line = render.query_summary(pred, job.out, job.csv)
        if job.pairs:  # "-> " alone when only the pairs are written
            line += "" if line.endswith("-> ") else " and "
            line += f"{job.pairs} (hloc retrieval pairs, {job.top} per query)"
        return line
    pred = jobs.query(job, progress=progress)
    if not job.out:
        return "\n".join(str(int(v)) for v in pred)
    return render.query_summary(pred, job.out)


def _learn(args, job, progress: bool) -> str:
    from rhythmic_jax.app import jobs, render

    return render.learn_summary(job.out, *jobs.learn(job, progress=progress))


def _info(args, job, progress: bool) -> str:
    from rhythmic_jax.app import jobs, render

    info = jobs.info(job.map)
    return json.dumps(info, indent=2) if job.json else render.info_lines(info)


def _evaluate(args, job, progress: bool) -> str:
    from rhythmic_jax.app import jobs, render

    result = jobs.evaluate(job, progress=progress)
    if job.json:
        return json.dumps(result, indent=2)
    text = render.evaluate_summary(result)
    if result.get("per_query"):
        text += f"\neach query's result and its {job.num_preds} best -> {job.per_query}"
    return text


def _describe(args, job, progress: bool) -> str:
    from rhythmic_jax.app import jobs, render

    return render.describe_summary(job, jobs.describe(job, progress=progress))


def _demo(args, job, progress: bool) -> None:
    from rhythmic_jax.app.demo import run_demo

    run_demo(job.out, quick=job.quick, progress=progress)


def _frontier(args, job, progress: bool) -> None:
    from rhythmic_jax.app.frontier import main as frontier

    frontier(args, job.given)  # prints its table itself, before its files are written


# command -> what runs its job and returns the text it prints (None: nothing)
COMMANDS = {"fit": _fit, "learn": _learn, "query": _query, "info": _info,
            "evaluate": _evaluate, "demo": _demo, "frontier": _frontier,
            "describe": _describe}  # fmt: skip
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


def _checked_job(args, prog: str):
    """The command's job, made (so checked) from the options; a refused option
    or a path written over one read ends in one usage line (InputError)."""
    given = frozenset(_given_options(args.argv, args))
    job = make(JOBS[args.command][0], args, given=given)
    line = check_paths(job)
    if line is not None:
        raise OptionRefused(line)
    for warning in job.warnings:
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
    closed standard output is refused before any work where the command writes
    no file (what it prints would be lost; with ``--out`` the work is done and
    only the printing dropped, :func:`_main`), a closed standard error is
    silent, non-ASCII and non-UTF-8 paths print on any stream, and memory
    running out (``ulimit -v`` below ``signals.MIN_ADDRESS_SPACE``, a
    ``MemoryError``, XLA's ``RESOURCE_EXHAUSTED``) says so."""
    from rhythmic_jax.app import signals

    stdout_open = signals.standard_streams()
    try:
        args = _parser().parse_args(argv)
    except SystemExit as done:  # --help, or a usage error already printed
        return int(done.code or 0)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    prog = f"rhythmic-jax {args.command}"
    signals.library_folders()
    limit = signals.memory_limit()
    if limit is not None and limit < signals.MIN_ADDRESS_SPACE:
        least = _gib(signals.MIN_ADDRESS_SPACE)
        _say(f"{prog}: error: memory ran out: the address-space limit (ulimit -v) "
             f"is {_gib(limit)}; the command needs at least {least}")  # fmt: skip
        return 2
    try:
        return _main(args, prog, stdout_open)
    except Exception as err:  # noqa: BLE001 - only memory's failures are said here
        if not signals.out_of_memory(err):
            raise
        where = "" if limit is None else f" (ulimit -v: {_gib(limit)})"
        _say(f"{prog}: error: memory ran out{where}; free some or give the "
             "command less to hold (see --memory where it is offered)")  # fmt: skip
        return 2


@contextlib.contextmanager
def _warning_lines(prog: str):
    """The library's warnings about a result (a solve stopped at its step cap,
    an embedding worse on held-out places) as one line each on stderr, once the
    command's work is done; other warnings shown as Python shows them."""
    import warnings

    caught: list = []
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("default")
            yield
    finally:
        for w in caught:
            if hasattr(w.message, "as_flag"):
                _say(f"{prog}: warning: {w.message.as_flag()}")
            else:
                warnings.showwarning(w.message, w.category, w.filename, w.lineno)


# standard output named as a path: written there, a file is dropped too
_STDOUT_PATH = re.compile(r"^(?:/dev/stdout|/dev/fd/1|/proc/(?:self|\d+)/fd/1)$")


def _main(args, prog: str, stdout_open: bool = True) -> int:
    """The command of the parsed ``args``: its job made, run and printed. With
    standard output closed, a job that writes a file (``--out``, ``--csv``)
    runs and only what it prints is dropped (said in a note); one that writes
    nothing is refused before any work, its results having nowhere to go."""
    try:
        job = _checked_job(args, prog)
    except OptionRefused as err:
        _say(f"{prog}: error: {err.as_flag()} (see {prog} --help)")
        return 2
    except InputError as err:
        _say(f"{prog}: error: {err.as_flag()}")
        return 2
    if not stdout_open:
        kept = [p for _, p in written(job) if not _STDOUT_PATH.match(str(p))]
        if not kept:
            _say(f"{prog}: error: standard output is closed; give it a place "
                 "(> FILE, or > /dev/null to drop what is printed)")  # fmt: skip
            return 2
        _say(f"{prog}: note: standard output is closed: what the command prints "
             f"is dropped; its files are written ({', '.join(kept)})")  # fmt: skip
    _quiet_logs(args.verbose)
    if args.command != "info":
        from rhythmic_jax.jit_cache import enable_compile_cache

        enable_compile_cache()  # programs kept between runs; see the epilog
    try:
        with _warning_lines(prog):
            text = COMMANDS[args.command](args, job, not getattr(job, "no_progress", 0))
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
