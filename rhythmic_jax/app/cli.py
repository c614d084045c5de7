"""The ``rhythmic-jax`` command line: the runner of its jobs.

Every command parses its arguments (:mod:`rhythmic_jax.app.parser`), makes its
job (:mod:`rhythmic_jax.app.specs`: it checks itself, each option in its domain
and against the others, the job's rules), checks where it writes, runs it
(:mod:`rhythmic_jax.app.jobs`) and prints what it returns
(:mod:`rhythmic_jax.app.render`); bad input ends with one line on stderr
(settings spelled as flags) and exit status 2, and nothing half-written on disk.

Outputs are handled here in one step for every job (:func:`_outputs`): the place
of each option declared ``path="writes"`` (and of the job's implied writes) is
checked before the work, as its ``output`` says
(:data:`rhythmic_jax.app.options.OUTPUTS`), and a write of any of them that
fails during the work ends in one line naming it. What a job says beside its
result (a warning on an option the input leaves idle, the library's warnings,
notes) is held until it has succeeded: a refusal is exactly one line.

The parser is built from light modules only (the jobs' settings and domains, the
map's configuration, the compile policy): ``rhythmic-jax --help`` imports no
numpy, JAX or torch. What a job needs is imported when it runs.
"""

from __future__ import annotations

import contextlib
import gc
import json
import logging
import os
import re
import sys
from collections.abc import Callable
from pathlib import Path

from rhythmic_jax.app import specs
from rhythmic_jax.app.options import OptionRefused, check_paths, make, outputs, written
from rhythmic_jax.app.parser import JOBS, given_options
from rhythmic_jax.app.parser import parser as _parser
from rhythmic_jax.errors import InputError

__all__ = ["main"]

# what the command says beside its result, said once it has succeeded
_HELD: list[Callable[[], None]] = []


def _hold(line: str) -> None:
    """``line`` said on stderr once the job has succeeded (dropped if refused)."""
    _HELD.append(lambda: _say(line))


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
        _hold(f"rhythmic-jax fit: note: {note}")
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


def _frontier(args, job, progress: bool) -> str:
    from rhythmic_jax.app import frontier

    result = frontier.frontier(job, progress=progress)
    if job.json:
        return json.dumps(result, indent=2)
    return frontier.frontier_lines(result, recall_at="recall_values" in job.given)


# command -> what runs its job and returns the text it prints (None: nothing)
COMMANDS = {"fit": _fit, "learn": _learn, "query": _query, "info": _info,
            "evaluate": _evaluate, "demo": _demo, "frontier": _frontier,
            "describe": _describe}  # fmt: skip


def _checked_job(args):
    """The command's job, made (so checked) from the options; a refused option
    or a path written over one read ends in one usage line (InputError)."""
    given = frozenset(given_options(args.argv, args))
    job = make(JOBS[args.command][0], args, given=given)
    line = check_paths(job)
    if line is not None:
        raise OptionRefused(line)
    return job


@contextlib.contextmanager
def _outputs(job):
    """Every output of ``job`` (:func:`rhythmic_jax.app.options.outputs`) with
    its place checked before the work (:mod:`rhythmic_jax.io.outputs`: a probe
    file written and removed there; a map's folder may only replace a map,
    :func:`rhythmic_jax.io.checkpoint.check_target`); within, a write of any of
    them that fails is one line naming it, the first declared (``--out``)
    taking a failure that names no path."""
    from rhythmic_jax.io.outputs import check_file_place, check_place, write_errors

    found = outputs(job)
    for option, path, how in found:
        if how == "map":
            from rhythmic_jax.io.checkpoint import check_target

            check_target(path)
        if how == "file":
            check_file_place(option, path)
        elif how != "kept" or not Path(path).expanduser().exists():
            check_place(option, path, inside=how == "into", file=how == "made")
    with contextlib.ExitStack() as stack:
        for option, path, _ in reversed(found):
            stack.enter_context(write_errors(option, path))
        yield


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
    an embedding worse on held-out places) held as one line each, said once
    the command's work is done; other warnings as Python shows them. A job that
    fails says none."""
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("default")
        yield
    for w in caught:
        if hasattr(w.message, "as_flag"):
            _hold(f"{prog}: warning: {w.message.as_flag()}")
        else:
            _HELD.append(lambda w=w: warnings.showwarning(
                w.message, w.category, w.filename, w.lineno))  # fmt: skip


# standard output named as a path: written there, a file is dropped too
_STDOUT_PATH = re.compile(r"^(?:/dev/stdout|/dev/fd/1|/proc/(?:self|\d+)/fd/1)$")


def _main(args, prog: str, stdout_open: bool = True) -> int:
    """The command of the parsed ``args``: its job made, its outputs checked,
    run and printed. With standard output closed, a job that writes a file
    (``--out``, ``--csv``) runs and only what it prints is dropped (said in a
    note); one that writes nothing is refused before any work, its results
    having nowhere to go. Warnings and notes are said once the job has
    succeeded, before what it prints; a refusal is its one error line."""
    _HELD.clear()
    try:
        job = _checked_job(args)
    except OptionRefused as err:
        _say(f"{prog}: error: {err.as_flag()} (see {prog} --help)")
        return 2
    except InputError as err:
        _say(f"{prog}: error: {err.as_flag()}")
        return 2
    for warning in job.warnings:
        _hold(f"{prog}: warning: {InputError(warning).as_flag()}")
    if not stdout_open:
        kept = [p for _, p in written(job) if not _STDOUT_PATH.match(str(p))]
        if not kept:
            _say(f"{prog}: error: standard output is closed; give it a place "
                 "(> FILE, or > /dev/null to drop what is printed)")  # fmt: skip
            return 2
        _hold(f"{prog}: note: standard output is closed: what the command prints "
              f"is dropped; its files are written ({', '.join(kept)})")  # fmt: skip
    _quiet_logs(args.verbose)
    if args.command != "info":
        from rhythmic_jax.jit_cache import enable_compile_cache

        enable_compile_cache()  # programs kept between runs; see the epilog
    try:
        with _outputs(job), _warning_lines(prog):
            text = COMMANDS[args.command](args, job, not getattr(job, "no_progress", 0))
        for said in _HELD:
            said()
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
