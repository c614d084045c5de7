"""The one harness of the benchmark scripts.

A script groups the reports of one theme as :class:`Part` s (``run(args) -> dict``,
the measurements; ``markdown(report) -> str``, mostly :func:`markdown`: every figure
of the JSON through the one renderer, :func:`render`; ``options``), and ends with
``main(__doc__, PARTS)``: a subcommand a part, common options, threads pinned to one
per core, the machine and load recorded, then ``<stem>.json`` and ``<stem>.md``
written (``--render [JSON]``: the Markdown again from a report, the JSON as it is).
Also: the timer, a command in a fresh process, the Nordland and aerial features and
the cache of fitted maps.
"""

import argparse
import dataclasses
import hashlib
import json
import logging
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("RHYTHMIC_DATA", REPO.parent / "shared" / "data"))
NORDLAND = "nordland_64x32"
MAP_CACHE = Path(tempfile.gettempdir()) / "rhythmic_jax_maps"  # cached_fit's folder
log = logging.getLogger("harness")
_LIMITS: list = []  # keeps the global BLAS limit referenced


def cores() -> int:
    """Cores this process may run on (XLA sizes its CPU thread pool by this)."""
    return len(os.sched_getaffinity(0))


def set_threads(n: int) -> dict[str, int]:
    """Pin torch, BLAS and faiss to ``n`` threads; the counts in force, XLA's too."""
    import faiss
    import torch
    from threadpoolctl import threadpool_info, threadpool_limits

    torch.set_num_threads(n)
    _LIMITS.append(threadpool_limits(limits=n))
    faiss.omp_set_num_threads(n)
    blas = sorted({int(p["num_threads"]) for p in threadpool_info()})
    one = blas[0] if len(blas) == 1 else -1
    return dict(xla=cores(), torch=torch.get_num_threads(), blas=one, faiss=n)


def load_average() -> list[float]:
    """1, 5 and 15 minute load averages, rounded."""
    return [round(v, 2) for v in os.getloadavg()]


def git_commit(repo: Path = REPO) -> str:
    """The checkout's short commit, ``+`` when its package has changes."""

    def git(*a):
        cmd = ["git", "-C", str(repo), *a]
        return subprocess.run(cmd, capture_output=True, text=True).stdout.strip()

    dirty = git("status", "--porcelain", "--untracked-files=no", "rhythmic_jax")
    return git("rev-parse", "--short", "HEAD") + ("+" if dirty else "")


def machine(threads: dict[str, int] | None = None) -> dict:
    """Devices, versions, cpu, cores, threads, XLA flags and commit of this run."""
    import faiss
    import jax
    import optax
    import sklearn
    import torch

    return dict(devices=[str(d) for d in jax.devices()], jax=jax.__version__,
                optax=optax.__version__, numpy=np.__version__,
                sklearn=sklearn.__version__, faiss=faiss.__version__,
                torch=torch.__version__, python=platform.python_version(),
                cpu=platform.processor() or platform.machine(), cores=cores(),
                threads=threads or {}, xla_flags=os.environ.get("XLA_FLAGS", ""),
                commit=git_commit())  # fmt: skip


def timed(fn, *args, **kwargs):
    """(``fn(*args, **kwargs)``, wall s, this process's CPU s), JAX results ready."""
    import jax

    wall, cpu = time.perf_counter(), time.process_time()
    out = jax.block_until_ready(fn(*args, **kwargs))
    return out, time.perf_counter() - wall, time.process_time() - cpu


def fastest(fn: Callable[[], object], repeats: int):
    """(first output, fastest wall s of ``repeats`` calls after a compiling one)."""
    import jax

    return jax.block_until_ready(fn()), min(timed(fn)[1] for _ in range(repeats))


def walls(fn: Callable[[], object], repeats: int, calls: int = 1) -> dict:
    """Best and median wall s per call of ``fn()`` over ``repeats`` runs of ``calls``
    calls, and the best run's CPU s over its wall."""

    def run():
        for _ in range(calls):
            fn()

    wall, cpu = np.array([timed(run)[1:] for _ in range(repeats)]).T / calls
    best = int(np.argmin(wall))
    return dict(best=float(wall[best]), median=float(np.median(wall)),
                cpu_per_wall=float(cpu[best] / wall[best]))  # fmt: skip


def child(cmd, checkout=None, cwd=None, check=True, env=None, **extra) -> dict:
    """``cmd`` in a fresh process (``checkout`` on the path, JAX on the CPU unless
    said): rc, wall and CPU s, peak resident bytes, stdout, stderr, load after."""
    env = dict(os.environ if env is None else env, TF_CPP_MIN_LOG_LEVEL="3", **extra)
    env.setdefault("JAX_PLATFORMS", "cpu")
    if checkout is not None:
        env["PYTHONPATH"] = str(checkout)
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        t = time.perf_counter()
        proc = subprocess.Popen(cmd, env=env, stdout=out, stderr=err, text=True,
                                cwd=cwd or tempfile.gettempdir())  # fmt: skip
        _, status, use = os.wait4(proc.pid, 0)  # the child's usage and its own's
        wall, rc = time.perf_counter() - t, os.waitstatus_to_exitcode(status)
        proc.returncode = rc
        out.seek(0), err.seek(0)
        stdout, stderr = out.read(), err.read()
    if check and rc != 0:
        raise RuntimeError(f"{cmd} failed:\n{stderr[-3000:]}")
    cpu, peak = use.ru_utime + use.ru_stime, use.ru_maxrss * 1024
    return dict(rc=rc, wall=wall, cpu=cpu, peak=peak, stdout=stdout, stderr=stderr,
                load=load_average()[0])  # fmt: skip


# The command line's module in whichever layout the checkout on sys.path has (a
# baseline checkout may predate ``rhythmic_jax/app/``).
CLI_MODULE = (
    "__import__('importlib.util').util.find_spec('rhythmic_jax.app') "
    "and 'rhythmic_jax.app.cli' or 'rhythmic_jax.cli'"
)
CLI = [sys.executable, "-c", f"import runpy; runpy.run_module({CLI_MODULE}, "
       "run_name='__main__', alter_sys=True)"]  # fmt: skip


def checkouts(base: Path | None, names=("base", "new")) -> dict[str, Path]:
    """``base`` and this checkout by ``names`` (no ``base``: "this"), compiled to
    bytecode first (else every timed job would compile Python)."""
    import compileall

    pair = {names[0]: Path(base).resolve(), names[1]: REPO} if base else {"this": REPO}
    for tree in pair.values():
        compileall.compile_dir(tree / "rhythmic_jax", quiet=1)
    return pair


def fresh_cache(tmp: Path, warm: Path | None = None, kept=("compiled",)) -> Path:
    """A new cache folder under ``tmp``, holding the ``kept`` folders of ``warm``."""
    cache = Path(tempfile.mkdtemp(dir=tmp, prefix="cache"))
    for name in kept if warm else ():
        if (warm / name).is_dir():
            shutil.copytree(warm / name, cache / name)
    return cache


def job_env(compile_cache: str | None = None) -> dict[str, str]:
    """This environment, its programs compiled to ``compile_cache`` ("0": none;
    default: under the job's ``RHYTHMIC_JAX_CACHE``)."""
    own = ("JAX_COMPIL", "RHYTHMIC_JAX_COMPILE_CACHE")
    env = {k: v for k, v in os.environ.items() if not k.startswith(own)}
    if compile_cache is not None:
        env["RHYTHMIC_JAX_COMPILE_CACHE"] = compile_cache
    return env


def command(fn, *args) -> list[str]:
    """The command that runs ``fn(*args)`` of a script afresh, printing its JSON."""
    script = Path(sys.modules[fn.__module__].__file__).stem
    return [sys.executable, str(Path(__file__).resolve()), script, fn.__name__,
            json.dumps(args)]  # fmt: skip


def call(fn, *args, checkout=None, **kw) -> dict:
    """:func:`child`'s record of :func:`command` (``kw``), ``result`` the answer."""
    r = child(command(fn, *args), checkout, **kw)
    r["result"] = json.loads(r["stdout"].splitlines()[-1]) if r["rc"] == 0 else None
    return r


def compile_counter(out=None) -> dict:
    """This process's XLA ``programs`` from now (JAX's compile log), cache ``hits``,
    ``compile_s``, ``trace_s`` and ``names``; written as JSON to ``out`` at exit."""
    import atexit
    import collections
    import re

    import jax

    count = dict(programs=0, hits=0, compile_s=0.0, trace_s=0.0,
                 names=collections.Counter())  # fmt: skip
    done = re.compile(r"Finished XLA compilation of (\S+) in ([0-9.eE+-]+) sec")

    class Count(logging.Handler):
        def emit(self, record):
            text = record.getMessage()
            if m := done.search(text):
                count["programs"] += 1
                count["compile_s"] += float(m.group(2))
                count["names"][m.group(1)] += 1
            elif "compilation cache hit" in text:
                count["hits"] += 1

    def listen(event, duration, **_):
        if event.endswith(("/jaxpr_trace_duration", "/jaxpr_to_mlir_module_duration")):
            count["trace_s"] += duration

    jax.monitoring.register_event_duration_secs_listener(listen)
    logger = logging.getLogger("jax._src")
    logger.setLevel(logging.WARNING)  # the CLI quiets "jax"; this stays
    logger.addHandler(Count())
    logger.propagate = False
    jax.config.update("jax_log_compiles", True)
    if out:
        atexit.register(lambda: Path(out).write_text(json.dumps(count)))
    return count


def weights_folder() -> Path:
    """The Lite0 weights' folder (a baseline checkout's map records a bare name)."""
    from rhythmic_jax.frames.nets import lite0_weights_path

    return lite0_weights_path().parent


def stats(v) -> dict[str, float]:
    """max, median, min and mean of an array."""
    v = np.asarray(v, np.float64)
    return dict(max=float(v.max()), median=float(np.median(v)), min=float(v.min()),
                mean=float(v.mean()))  # fmt: skip


def nordland_images(root: Path, seasons=("summer", "winter"), progress=False):
    """The Nordland 64x32 traversals of ``seasons`` under ``root``."""
    from rhythmic_jax.io.images import nordland

    return nordland(Path(root) / NORDLAND, tuple(seasons), progress=progress)


def nordland_features(root: Path, descriptor="patchnorm", seasons=("summer", "winter"),
                      key="nordland64x32-", progress=False, **kw):  # fmt: skip
    """Each season's descriptors (n, d), cached as ``key + season``."""
    from rhythmic_jax.frames.features import cached_describe, get_descriptor

    desc = get_descriptor(descriptor) if isinstance(descriptor, str) else descriptor
    trav = nordland_images(root, seasons, progress)
    return tuple(
        cached_describe(t.images, desc, key + s, progress=progress, **kw)
        for t, s in zip(trav, seasons, strict=True)
    )


def summer(args, descriptor="patchnorm") -> np.ndarray:
    """The Nordland summer traversal's descriptors (n, d) under ``args.root``."""
    kw = dict(progress=getattr(args, "progress", False))
    return nordland_features(args.root, descriptor, ("summer",), **kw)[0]


def aerial_features(root: Path, descriptor="patchnorm", folder="samples_LEVIR",
                    key="levir-64-32-", progress=False, **kw):  # fmt: skip
    """(A tiles (n, d), B tiles (n, d), the route) of an aerial pairs folder."""
    from rhythmic_jax.frames.features import cached_describe, get_descriptor
    from rhythmic_jax.io.tiles import load_aerial_route

    desc = get_descriptor(descriptor) if isinstance(descriptor, str) else descriptor
    route = load_aerial_route(Path(root) / "aerial_pairs" / folder, progress=progress)
    a, b = (
        cached_describe(t, desc, key + side, progress=progress, **kw)
        for t, side in ((route.map_tiles, "a"), (route.query_tiles, "b"))
    )
    return a, b, route


def unit_rows(a) -> np.ndarray:
    """Rows scaled to unit L2 norm, float32."""
    a = np.asarray(a, np.float32)
    return a / np.linalg.norm(a, axis=1, keepdims=True)


def digest(ident, *arrays) -> str:
    """A cached fit's key: 16 hex digits of sha256 over ``ident`` and ``arrays``."""
    text = ident if isinstance(ident, str) else json.dumps(ident, sort_keys=True,
                                                           default=str)  # fmt: skip
    h = hashlib.sha256(text.encode())
    for a in arrays:
        h.update(np.ascontiguousarray(a).data)
    return h.hexdigest()[:16]


def cached_fit(model, x, folder: Path = MAP_CACHE, fit=None, extra=None, arrays=(),
               tag="", progress=False):  # fmt: skip
    """(map, record): ``model`` fitted on ``x`` (by ``fit(model)``), or loaded from
    ``folder`` if fitted with the same settings, ``extra`` and arrays before."""
    from rhythmic_jax.rhythmic_map import RhythmicMap

    x = np.ascontiguousarray(x, np.float32)
    ident = dict(config=dataclasses.asdict(model.config), shape=list(x.shape))
    h, cfg = digest(ident | (extra or {}), x, *arrays), model.config
    path = Path(folder) / f"{tag}{cfg.descriptor}-L{cfg.level}-n{len(x)}-{h}.map"
    side = path.with_name(path.name + ".fit.json")
    if (path / "map.json").is_file():
        timing = json.loads(side.read_text()) if side.is_file() else {}
        return RhythmicMap.load(path), dict(map_path=str(path), cached=True, **timing)
    _, wall, cpu = timed(fit or (lambda m: m.fit(x, progress=progress)), model)
    log.info("fitted %s in %.0f s: periods %s", path.name, wall, model.periods)
    model.save(path)
    timing = dict(fit_wall_s=wall, fit_cpu_s=cpu)
    _write(side, json.dumps(timing))
    return model, dict(map_path=str(path), cached=False, **timing)


def kept(path: Path, make: Callable[[], dict]) -> dict:
    """``make()``'s record saved as JSON at ``path`` (atomically: a killed run
    leaves none) and read back; read alone when saved before."""
    from rhythmic_jax.io.reader import read_json

    if not path.exists():
        _write(path, json.dumps(plain(make())))
    return read_json(path, "saved record")


def plain(obj):
    """``obj`` with numpy scalars and arrays and tuples turned into JSON types."""
    if isinstance(obj, dict):
        return {str(k): plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple | np.ndarray):
        return [plain(v) for v in obj]
    if isinstance(obj, np.integer | np.bool_):
        return obj.item()
    return float(obj) if isinstance(obj, np.floating) else obj


def table(headers: Sequence[str], rows: Sequence[Sequence[object]], align=None) -> str:
    """A Markdown table; numbers right-aligned unless ``align`` says (l, r each)."""
    if align is None:
        align = "".join("r" if all(isinstance(r[i], int | float | np.number)
                                   for r in rows) else "l"
                        for i in range(len(headers)))  # fmt: skip
    seps = ("---:" if a == "r" else "---" for a in align.ljust(len(headers), "l"))
    lines = ["| " + " | ".join(headers) + " |", "|" + "|".join(seps) + "|"]
    lines += ["| " + " | ".join(_cell(v) for v in r) + " |" for r in rows]
    return "\n".join(lines)


def _cell(v: object) -> str:
    if isinstance(v, float | np.floating):
        return f"{v:,.0f}" if abs(v) >= 100 else f"{v:.4g}"
    return str(v)


def header(title: str, report: dict) -> list[str]:
    """A report's title and its paragraph on the command, machine and load."""
    env, load = report.get("environment") or {}, report.get("load_average")
    text, lacks = [], []
    if report.get("command"):
        text.append(f"Command: `{report['command']}`.")
    else:
        lacks.append("the command")
    if "devices" in env:
        text.append(f"Devices {env['devices']}, {env.get('cores', env.get('cpus'))}"
                    f" cores; threads {env.get('threads')} (XLA: one per core).")
    else:
        lacks.append("the devices, cores and threads")
    if isinstance(load, dict):
        text.append(f"Load average (1, 5, 15 min) at start {load['start']}, at end"
                    f" {load['end']}: the machine is shared, so the times are"
                    " pessimistic.")  # fmt: skip
    else:
        lacks.append("the load average at start and end")
    if env.get("commit"):
        text.append(f"Commit {env['commit']}.")
    if lacks:
        text.append("Not recorded (the report predates the harness's record of"
                    f" them): {'; '.join(lacks)}; its JSON holds what it"
                    " kept.")  # fmt: skip
    return [f"# {title}", "", " ".join(text), ""]


def render(title: str, report: dict, *blocks) -> str:
    """The one renderer: :func:`header`, then each block, a paragraph (str), a table
    ``(headers, rows[, align])`` or nothing (None, ""), a blank line apart."""
    parts = [b if isinstance(b, str) else table(*b) for b in blocks if b]
    return "\n".join(header(title, report)) + "\n" + "\n\n".join(parts)


HEADER_KEYS = ("command", "environment", "load_average", "wall_seconds")
NAMES = ("name", "method", "job", "op", "descriptor", "solver", "layout", "label")


def figures(node: dict, level: int = 2) -> list:
    """Blocks that show every figure of ``node``: plain values in a key/value table,
    long texts as paragraphs, records as tables, anything deeper a section."""
    plain_rows, blocks = [], []
    for key, value in node.items():
        if isinstance(value, str) and len(value) > 120:  # a paragraph
            blocks += [f"{key}: {value}"]
        elif (records := _records(value)) is not None:
            blocks += ["#" * level + f" {key}", records_table(records)]
        elif (flat := _flat(value)) is not None:
            plain_rows += [[f"{key}.{k}" if k else key, _value(v)]
                           for k, v in flat.items()]  # fmt: skip
        elif isinstance(value, dict):
            blocks += ["#" * level + f" {key}", *figures(value, level + 1)]
        else:  # a list of sections
            for i, item in enumerate(value):
                title = _section(item) or str(i)
                blocks += ["#" * level + f" {key}: {title}", *figures(item, level + 1)]
    head = [(["figure", "value"], plain_rows, "ll")] if plain_rows else []
    return head + blocks


def _flat(value, prefix: str = "") -> dict | None:
    """``{dotted key: value}`` of a value without a list of records, else None."""
    if isinstance(value, dict):
        out = {}
        for k, v in value.items():
            sub = _flat(v, f"{prefix}.{k}" if prefix else str(k))
            if sub is None:
                return None
            out |= sub
        return out
    if isinstance(value, list | tuple) and any(isinstance(v, dict) for v in value):
        return None
    return {prefix: value}


def _records(value) -> list[dict] | None:
    """A list (or a dict, its key as ``""``) of flat records, else None."""
    if isinstance(value, dict) and len(value) > 1:
        if all(isinstance(v, dict) for v in value.values()):
            flat = [_flat(v) for v in value.values()]
            if all(f is not None for f in flat):
                return [{"": k} | f for k, f in zip(value, flat, strict=True)]
    if not isinstance(value, list) or not value:
        return None
    if all(isinstance(v, list | tuple) for v in value):
        return [{str(i): x for i, x in enumerate(row)} for row in value]
    if all(isinstance(v, dict) for v in value):
        flat = [_flat(v) for v in value]
        return flat if all(f is not None for f in flat) else None
    return None


def _label(item) -> str:
    """The name of a section (its first naming key's value)."""
    if not isinstance(item, dict):
        return ""
    return next((str(item[k]) for k in NAMES if isinstance(item.get(k), str)), "")


def _section(item) -> str:
    """A section's title: its first three plain values, ``key=value``."""
    if not isinstance(item, dict):
        return ""
    named = [f"{k}={v}" for k, v in item.items()
             if isinstance(v, str | int) and not isinstance(v, bool)]  # fmt: skip
    return ", ".join(named[:3])


def records_table(records: list[dict]) -> tuple:
    """A table of records: a column per key (a row, for few records of many)."""
    keys = list(dict.fromkeys(k for r in records for k in r))
    cells = [[_value(r.get(k, "-")) for k in keys] for r in records]
    if len(keys) <= 12 or len(records) > 6:
        return [k or "key" for k in keys], cells, "l" * len(keys)
    names = [str(r.get("", "") or _label(r) or i) for i, r in enumerate(records)]
    rows = [[k, *(c[i] for c in cells)] for i, k in enumerate(keys) if k]
    return ["figure", *names], rows, "l" * (len(names) + 1)


def _value(v) -> str:
    """A table cell: a number by :func:`_cell`, a list as ``[a, b]``, None ``-``."""
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    return "-" if v is None else _cell(v).replace("|", "/").replace("\n", " ")


def target(what: str, value: float, limit: float, at_least=True, fmt="{:.4g}"):
    """A row of a targets table: what, the limit, the measured value, met or not."""
    met = value >= limit if at_least else value <= limit
    limit_text = (">= " if at_least else "<= ") + fmt.format(limit)
    return [what, limit_text, fmt.format(value), "met" if met else "NOT met"]


def targets(rows: list) -> list:
    """The blocks of a targets table (none without rows)."""
    heads = ["target", "limit", "measured", ""]
    return ["Targets:", (heads, rows, "l")] if rows else []


def markdown(title: str, note: str = "", extra: Callable | None = None) -> Callable:
    """A part's ``markdown``: the title, a note, ``extra(report)``'s blocks, the
    run's wall seconds, then every figure of the report."""

    def to_markdown(report: dict) -> str:
        shown = dict(environment="devices" in report.get("environment", {}),
                     load_average=isinstance(report.get("load_average"), dict))
        body = {k: v for k, v in report.items()
                if k not in HEADER_KEYS or shown.get(k) is False}  # fmt: skip
        wall = report.get("wall_seconds")
        tail = [] if wall is None else [f"Wall seconds of the run: {_cell(wall)}."]
        blocks = extra(report) if extra else ()
        return render(title, report, note, *blocks, *tail, *figures(body))

    return to_markdown


def _write(path: Path, text: str) -> None:
    from rhythmic_jax.io.atomic import write_file

    Path(path).parent.mkdir(parents=True, exist_ok=True)
    write_file(Path(path), text)


def write_report(out: Path, stem: str, report: dict, md: str, md_stem=None) -> None:
    """Write ``<stem>.json`` and ``<md_stem or stem>.md`` under ``out``; print it."""
    _write(Path(out) / f"{stem}.json", json.dumps(report, indent=1) + "\n")
    _write(Path(out) / f"{md_stem or stem}.md", md + "\n")
    print(md)


@dataclasses.dataclass(frozen=True)
class Part:
    """One report: ``run(args) -> dict``, ``markdown(report) -> str``, ``options``
    (:func:`add_options`), ``stem``, the options ``--quick`` sets, ``refresh(report,
    args)`` (for ``--render``) and the Markdown's own stem."""

    run: Callable
    markdown: Callable
    options: Callable | dict | None = None
    stem: str = "report"
    quick: dict | None = None
    refresh: Callable | None = None
    md_stem: str | None = None


def _common(ap: argparse.ArgumentParser) -> argparse.ArgumentParser:
    ap.add_argument("--root", type=Path, default=DATA, help="shared data folder")
    ap.add_argument("--out", type=Path, default=REPO / "reports", help="reports")
    ap.add_argument("--quick", action="store_true", help="the smallest settings")
    ap.add_argument("--no-progress", dest="progress", action="store_false")
    ap.add_argument("--render", type=Path, nargs="?", const=Path(), default=None,
                    help="write the Markdown again from this JSON report (default:"
                    " the one in --out), measuring nothing")  # fmt: skip
    return ap


def add_options(ap: argparse.ArgumentParser, options) -> None:
    """A part's options: ``options(ap)``, or ``{name: spec}``, each ``--name`` (``_``
    as ``-``) declared once; spec: a default, a type (default None), ``(either,
    help)`` or add_argument's keywords. False: a flag; a list: ``nargs="+"``."""
    if callable(options):
        return options(ap)
    for name, spec in (options or {}).items():
        if not isinstance(spec, dict):
            value, *text = spec if isinstance(spec, tuple) else (spec,)
            spec = dict(type=value) if callable(value) else dict(default=value)
            spec |= dict(zip(["help"], text, strict=False))
        value = spec.get("default")
        if value is False:
            spec.setdefault("action", "store_true")
        elif isinstance(value, list):
            spec = dict(nargs="+", type=type(value[0])) | spec
        elif value is not None:
            spec.setdefault("type", type(value))
        ap.add_argument("--" + name.replace("_", "-"), **spec)


def parser(doc: str, parts: dict[str, Part] | None = None):
    """The common options; with several ``parts``, a subcommand each."""
    ap = argparse.ArgumentParser(description=doc.strip().splitlines()[0])
    if not parts or len(parts) == 1:
        for part in (parts or {}).values():
            add_options(ap, part.options)
        return _common(ap)
    sub = ap.add_subparsers(dest="part", required=True, metavar="PART")
    ap.parts = {}  # each part's parser, for its defaults
    for name, part in parts.items():
        text = (part.run.__doc__ or name).strip().splitlines()[0]
        ap.parts[name] = _common(sub.add_parser(name, help=text, description=text))
        add_options(ap.parts[name], part.options)
    return ap


def spelled_now(command: str, script: str, part: str) -> str:
    """A report's command in today's spelling, ``python scripts/SCRIPT PART ...``
    (an older report names the script it came from, and no part)."""
    runs = []
    for one in command.split(" ; "):
        _, _, *rest = one.split(" ")
        rest = rest[1:] if rest[:1] == [part] else rest
        runs.append(" ".join(["python", f"scripts/{script}", *filter(None, [part]),
                              *rest]))  # fmt: skip
    return " ; ".join(runs)


def main(doc: str, parts: dict[str, Part], argv=None):
    """Parse, record the machine, run the part, write and print its report. ``parts``:
    by subcommand ("": one part). ``--quick``: the part's ``quick`` options where
    left at their defaults, the report ``<stem>_quick``."""
    ap = parser(doc, parts)
    argv = sys.argv[1:] if argv is None else list(argv)
    args = ap.parse_args(argv)
    name = getattr(args, "part", None) or next(iter(parts))
    part, own = parts[name], getattr(ap, "parts", {}).get(name, ap)
    args.stem = f"{part.stem}_quick" if args.quick else part.stem
    md_stem = part.md_stem and part.md_stem + ("_quick" if args.quick else "")
    for key, value in (part.quick or {}).items() if args.quick else ():
        if getattr(args, key) == own.get_default(key):
            setattr(args, key, value)
    script = Path(sys.modules[part.run.__module__].__file__ or "script").name
    if args.render is not None:
        if not args.render.name:
            args.render = args.out / f"{args.stem}.json"
        report = json.loads(args.render.read_text())
        if report.get("command"):
            report["command"] = spelled_now(report["command"], script, name)
        if part.refresh:
            part.refresh(report, args)
        md = part.markdown(report)  # the JSON stays as it is
        _write(args.render.with_name(f"{md_stem or args.render.stem}.md"), md + "\n")
        return report
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    logging.getLogger("absl").setLevel(logging.WARNING)  # orbax chatter
    env, load0, t0 = machine(set_threads(cores())), load_average(), time.time()
    log.info("environment %s", env)
    out = part.run(args)
    if out is None:
        return None
    report = dict(command=" ".join(["python", f"scripts/{script}", *argv]),
                  environment=env, load_average=dict(start=load0, end=load_average()),
                  wall_seconds=time.time() - t0)  # fmt: skip
    report = plain(report | out)
    write_report(args.out, args.stem, report, part.markdown(report), md_stem)
    return report


if __name__ == "__main__":  # call(): python _harness.py SCRIPT FUNCTION JSON_ARGS
    script, name, argv = sys.argv[1:]
    fn = getattr(__import__(script), name)
    print(json.dumps(plain(fn(*json.loads(argv)))), flush=True)
