"""Compiling and starting, by part: XLA programs, compile seconds and wall per job,
cold and warm compile cache, this checkout against a baseline one; start-up time of
``import rhythmic_jax``, ``rhythmic-jax --help`` and ``info``.

    python scripts/bench_compile.py jobs --base DIR [--jobs fit,nordland,demo,jpeg]
    python scripts/bench_compile.py jobs --base DIR --small   (a quick check)
    python scripts/_harness.py bench_compile count_fit '[1000, 256]'   (one fit)
    python scripts/bench_compile.py startup --before /tmp/before --repeats 7

The package is imported inside the functions: a job's process imports this module,
and its imports count in its wall time.
"""

import json
import runpy
import shutil
import sys
import tempfile
import time
from pathlib import Path

import _harness as h
import numpy as np


def route(n: int, d: int, seed: int = 0) -> np.ndarray:
    """(n, d) unit rows drifting along a route: a smoothed random walk."""
    rng = np.random.default_rng(seed)
    x = np.cumsum(rng.standard_normal((n, d)), axis=0)
    x += 3.0 * rng.standard_normal((n, d))
    x -= x.mean(axis=0)
    return (x / np.linalg.norm(x, axis=1, keepdims=True)).astype(np.float32)


def job(out: str, *argv: str) -> dict | None:
    """A job's process, its programs counted into ``out``: ``imports`` (the floor
    under any fit), ``library FEATURES PREDICTIONS`` or a command line."""
    h.compile_counter(out)
    if argv[0] == "imports":
        import jax.numpy  # noqa: F401

        import rhythmic_jax.rhythmic_map  # noqa: F401  (in every layout)
    elif argv[0] == "library":
        import rhythmic_jax as rj

        if hasattr(rj, "enable_compile_cache"):
            rj.enable_compile_cache()
        x = np.load(argv[1])
        model = rj.RhythmicMap().fit(x, progress=False)
        np.save(argv[2], np.asarray(model.predict(x)))
        return dict(periods=list(model.periods))
    else:
        sys.argv = ["rhythmic-jax", *argv, "--no-progress"]
        runpy.run_module(eval(h.CLI_MODULE), run_name="__main__", alter_sys=True)
    return None


def run_job(argv: list[str], env: dict, tmp: Path) -> dict:
    """(wall seconds and compile counts, stdout) of one job in a fresh process."""
    out = tmp / f"count-{time.monotonic_ns()}.json"
    r = h.child(h.command(job, str(out), *argv), None, h.weights_folder(), env=env)
    c = json.loads(out.read_text())
    count = dict(programs=c["programs"], compiled=c["programs"] - c["hits"],
                 hits=c["hits"], compile_s=c["compile_s"])  # fmt: skip
    return dict(count, wall=r["wall"], load=r["load"]), r["stdout"]


def count_fit(n: int = 1000, d: int = 256) -> dict:
    """The library job alone, afresh, no compile cache: its compile counts."""
    with tempfile.TemporaryDirectory() as tmp:
        x, out = Path(tmp) / "x.npy", Path(tmp) / "count.json"
        np.save(x, route(n, d))
        argv = ["library", str(x), str(Path(tmp) / "pred.npy")]
        r = h.call(job, str(out), *argv, checkout=h.REPO, env=h.job_env("0"))
        return json.loads(out.read_text()) | r["result"]


def wait_for_build(cache: Path, timeout: float = 1800.0) -> float:
    """Seconds until no builder lock is left under ``cache/compiled``."""
    t, folder = time.perf_counter(), cache / "compiled"
    while list(folder.glob("*.lock")) and time.perf_counter() - t < timeout:
        time.sleep(1.0)
    return time.perf_counter() - t


OPTIONS_JOBS = dict(base=(Path, "baseline checkout (to measure)"),
                    jobs="imports,fit,nordland,demo,jpeg",
                    small=(False, "tiny sizes: a check"),
                    rounds=(1, "base, cold, warm, repeated: each target then takes the"
                            " median of the rounds"))  # fmt: skip


def steps(job: str, tmp: Path, tag: str, inputs: dict, folders: dict) -> list:
    """(label, argv) of each process of ``job``; a library job's argv[2]: its
    predictions."""
    jpeg_map, library = str(tmp / f"jpeg-{tag}.map"), str(tmp / f"{job}-{tag}.npy")
    return {
        "imports": [("imports", ["imports"])],
        "demo": [("demo", ["demo", "--out", str(tmp / f"demo-{tag}")])],
        "jpeg": [("jpeg fit", ["fit", str(folders.get("ref")), "--out", jpeg_map,
                               "--descriptor", "efficientnet_lite0"]),
                 ("jpeg query", ["query", jpeg_map, str(folders.get("q")), "--out",
                                 str(tmp / f"q-{tag}.npy")])],
    }.get(job, [(job, ["library", str(inputs.get(job)), library])])  # fmt: skip


def agreement(maps: dict) -> dict:
    """Per job and new variant, against the baseline over every round: periods
    equal in all, the lowest share of equal predictions."""
    same = {}
    for (job, _), runs in maps.items():
        base_pred, base_periods = runs["base"]
        for name in ("new cold", "new warm"):
            pred, periods = runs[name]
            equal = float((np.load(pred) == np.load(base_pred)).mean())
            was = same.setdefault(f"{job}, {name}", {"periods_equal": True})
            was["periods_equal"] &= periods == base_periods
            was["predictions_equal"] = min(was.get("predictions_equal", 1.0), equal)
    return same


def run_jobs(args) -> dict:
    """XLA programs, compile and wall seconds per job (compile)."""
    if args.base is None:
        raise SystemExit("--base (a baseline checkout) is needed to measure")
    from bench_frames import make_folders

    args.small = args.small or args.quick
    args.stem = "compile" + ("_small" if args.small else "")
    jobs = args.jobs.split(",")
    small = ((200, 64), 300, 100) if args.small else ((1000, 256), None, 1000)
    (n_fit, d_fit), n_nord, n_jpeg = small
    rows, agree = [], {}
    with tempfile.TemporaryDirectory(prefix="bench_compile") as tmpdir:
        tmp, inputs = Path(tmpdir), {}
        if "fit" in jobs:
            inputs["fit"] = tmp / "route.npy"
            np.save(inputs["fit"], route(n_fit, d_fit))
        if "nordland" in jobs:
            inputs["nordland"] = tmp / "nordland.npy"
            np.save(inputs["nordland"], h.summer(args)[:n_nord])
        folders = make_folders(args.root, tmp, n_jpeg, 0) if "jpeg" in jobs else {}
        network = tmp / "network"  # the new checkout's cache folder: network
        h.checkouts(args.base)
        # base, new cold, new warm (the warm run reuses the cold run's compile cache)
        common = h.job_env() | dict(JAX_PLATFORMS="cpu", RHYTHMIC_JAX_NETWORK_BUILD="1")
        old = {**common, "PYTHONPATH": str(args.base.resolve())}
        new = {**common, "PYTHONPATH": str(h.REPO)}
        variants = (("base", old), ("new cold", new), ("new warm", new))
        rounds = [(k, *v) for k in range(args.rounds) for v in variants]
        for k, name, env in rounds:
            new["RHYTHMIC_JAX_COMPILE_CACHE"] = str(tmp / f"jit{k}")  # cold: empty
            side = name.split()[0]
            if name == "new cold":
                shutil.rmtree(network, ignore_errors=True)
            for job in jobs:
                cache = h.fresh_cache(tmp, network if side == "new" else None)
                env_job = {**env, "RHYTHMIC_JAX_CACHE": str(cache)}
                tag = f"{name.replace(' ', '_')}-{k}"
                for label, argv in steps(job, tmp, tag, inputs, folders):
                    r, out = run_job(argv, env_job, tmp)
                    if argv[0] == "library":  # fit, nordland: the maps compared
                        r["periods"] = found = json.loads(out.splitlines()[-1])
                        agree.setdefault((job, k), {})[name] = argv[2], found["periods"]
                    more = dict(round=k) if args.rounds > 1 else {}
                    rows.append(dict(job=label, variant=name, **more, **r))
                    if label == "jpeg fit" and side == "new":
                        wait_for_build(cache)
                        if (cache / "compiled").is_dir():
                            shutil.rmtree(network, ignore_errors=True)
                            shutil.copytree(cache / "compiled", network / "compiled")
                print(json.dumps(rows[-1]), flush=True)
        same = agreement(agree)
    sizes = dict(fit=[n_fit, d_fit], nordland=n_nord or 3576, jpegs=n_jpeg)
    return dict(base=str(args.base), sizes=sizes, rows=rows, agreement=same)


# (target, job, variant, measure(row, the job's baseline row), limit, format):
# met when the measure is at most the limit
TARGETS = [
    ("fit: programs, cold", "fit", "new cold",
     lambda r, b: r["programs"], 20, "{:.0f}"),
    ("fit: wall / baseline's, cold", "fit", "new cold",
     lambda r, b: r["wall"] / b["wall"], 0.4, "{:.2f}x"),
    ("fit: wall, warm, imports included", "fit", "new warm",
     lambda r, b: r["wall"], 2.0, "{:.2f} s"),
    ("Nordland: compiling / cold fit's wall", "nordland", "new cold",
     lambda r, b: r["compile_s"] / r["wall"], 0.15, "{:.1%}"),
    ("demo: wall, cold", "demo", "new cold", lambda r, b: r["wall"], 15.0, "{:.1f} s"),
    ("demo: wall, warm", "demo", "new warm", lambda r, b: r["wall"], 8.0, "{:.1f} s"),
]  # fmt: skip


def targets(report: dict) -> list:
    """The targets this run's jobs answer (the median over rounds)."""
    rows, out = {}, []
    for r in report["rows"]:
        rows.setdefault((r["job"], r["variant"]), []).append(r)
    for what, job, variant, measure, limit, fmt in TARGETS:
        if (job, variant) in rows and (job, "base") in rows:
            pairs = zip(rows[job, variant], rows[job, "base"], strict=True)
            value = float(np.median([measure(*p) for p in pairs]))
            out.append(h.target(what, value, limit, False, fmt))
    return h.targets(out)


markdown_jobs = h.markdown(
    "Compiling: XLA programs, compile seconds and wall per job",
    "The baseline checkout against this one, cold (an empty compile cache) and warm;"
    " each job a fresh process. hits: programs loaded from the cache; agreement: the"
    " maps against the baseline's; imports: the floor under any fit.",
    targets,
)


HEAVY = ("numpy", "jax", "faiss", "sklearn", "torch", "optax", "orbax")
QUICK_STARTUP = dict(repeats=1)  # --quick
SCRIPT = shutil.which("rhythmic-jax") or "rhythmic-jax"


# Run in a bare interpreter (no harness, so no numpy of its own): the heavy
# packages that ``import rhythmic_jax`` or the command line with argv loads.
PROBE = """import contextlib, runpy, sys
argv = {argv!r}
if argv == ["import"]:
    import rhythmic_jax
else:
    sys.argv = ["rhythmic-jax", *argv]
    with contextlib.suppress(SystemExit):
        runpy.run_module({cli}, run_name="__main__")
print("LOADED", *(m for m in {heavy!r} if m in sys.modules))"""


def loaded(checkout: Path, cmd: list[str]) -> list[str]:
    """The heavy packages a command loads (run once with the probe)."""
    argv = ["import"] if cmd[0] == sys.executable else cmd[1:]
    code = PROBE.format(argv=argv, heavy=HEAVY, cli=h.CLI_MODULE)
    out = h.child([sys.executable, "-c", code], checkout, check=False)["stdout"]
    last = [line for line in out.splitlines() if line.startswith("LOADED")]
    return last[-1].split()[1:] if last else ["(probe failed)"]


def fit_map(folder: Path) -> Path:
    """A 600-frame, 64-d map fitted with this checkout's command line."""
    x = np.random.default_rng(0).standard_normal((600, 64)).astype(np.float32)
    np.save(folder / "ref.npy", x / np.linalg.norm(x, axis=1, keepdims=True))
    cmd = [SCRIPT, "fit", str(folder / "ref.npy"), "--out", str(folder / "route.map")]
    h.child([*cmd, "--no-progress"], h.REPO)
    return folder / "route.map"


markdown_startup = h.markdown(
    "Start-up time: import, --help, info",
    "Each command in a fresh process, in turns; loaded: the heavy packages it loads."
    " Targets on an idle machine: `--help` under 1 s, `info` under 2 s.",
    lambda r: ["Medians (s):", (["command", *r["versions"]], [
        [name, *(float(np.median(by[v])) for v in r["versions"])]
        for name, by in r["seconds"].items()])],
)  # fmt: skip


OPTIONS_STARTUP = dict(before=(Path, "checkout to compare"), repeats=5)


def run_startup(args) -> dict:
    """Start-up time: import, --help, info (startup)."""
    checkouts = h.checkouts(args.before, ("before", "after"))
    with tempfile.TemporaryDirectory() as tmp:
        route = fit_map(Path(tmp))
        cmds = {
            "import rhythmic_jax": [sys.executable, "-c", "import rhythmic_jax"],
            "rhythmic-jax --help": [SCRIPT, "--help"],
            "rhythmic-jax info MAP": [SCRIPT, "info", str(route)],
        }
        seconds = {name: {v: [] for v in checkouts} for name in cmds}
        loads = {name: {v: loaded(path, cmd) for v, path in checkouts.items()}
                 for name, cmd in cmds.items()}  # fmt: skip
        for i in range(args.repeats):
            for name, cmd in cmds.items():
                for v, path in checkouts.items():
                    seconds[name][v].append(h.child(cmd, path)["wall"])
            h.log.info("turn %d of %d done", i + 1, args.repeats)
    return dict(versions=list(checkouts), repeats=args.repeats, seconds=seconds,
                checkouts={v: str(p) for v, p in checkouts.items()},
                loaded=loads)  # fmt: skip


PARTS = {
    "jobs": h.Part(run_jobs, markdown_jobs, OPTIONS_JOBS, "compile"),
    "startup": h.Part(run_startup, markdown_startup, OPTIONS_STARTUP, "startup",
                      QUICK_STARTUP),  # fmt: skip
}

if __name__ == "__main__":
    h.main(__doc__, PARTS)
