"""Start-up time: ``import rhythmic_jax``, ``rhythmic-jax --help`` and ``info``.

python scripts/bench_startup.py --before /tmp/before --repeats 7
"""

import shutil
import statistics
import sys
import tempfile
from pathlib import Path

import numpy as np
from _harness import CLI_MODULE, REPO, bytecode, child, header, log, main, table

HEAVY = ("numpy", "jax", "faiss", "sklearn", "torch", "optax", "orbax")
QUICK = dict(repeats=1)  # --quick
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
    code = PROBE.format(argv=argv, heavy=HEAVY, cli=CLI_MODULE)
    out = child([sys.executable, "-c", code], checkout, check=False)["stdout"]
    last = [line for line in out.splitlines() if line.startswith("LOADED")]
    return last[-1].split()[1:] if last else ["(probe failed)"]


def fit_map(folder: Path) -> Path:
    """A 600-frame, 64-d map fitted with this checkout's command line."""
    x = np.random.default_rng(0).standard_normal((600, 64)).astype(np.float32)
    np.save(folder / "ref.npy", x / np.linalg.norm(x, axis=1, keepdims=True))
    cmd = [SCRIPT, "fit", str(folder / "ref.npy"), "--out", str(folder / "route.map")]
    child([*cmd, "--no-progress"], REPO)
    return folder / "route.map"


def markdown(report: dict) -> str:
    lines = header("Start-up time: import, --help, info", report)
    versions = report["versions"]
    lines += [
        f"Each command in a fresh process (each checkout compiled to bytecode first),"
        f" wall seconds, median of "
        f"{report['repeats']} runs taken in turns ({', '.join(versions)}). Targets "
        "on an idle machine: `--help` under 1 s, `info` under 2 s.",
        "",
    ]
    rows = []
    for name, by_version in report["seconds"].items():
        med = [statistics.median(by_version[v]) for v in versions]
        ratio = [f"{med[0] / med[1]:.2f}x"] if len(versions) == 2 else []
        heavy = [", ".join(report["loaded"][name][v]) or "-" for v in versions]
        rows.append([name, *med, *ratio, *heavy])
    heads = ["command", *(f"{v} (s)" for v in versions)]
    if len(versions) == 2:
        heads.append(f"{versions[0]} / {versions[1]}")
    heads += [f"heavy packages loaded, {v}" for v in versions]
    lines.append(table(heads, rows))
    return "\n".join(lines)


def options(ap) -> None:
    ap.add_argument("--before", type=Path, default=None, help="checkout to compare")
    ap.add_argument("--repeats", type=int, default=5)


def run(args) -> dict:
    checkouts = {"this": REPO}
    if args.before is not None:
        checkouts = {"before": args.before.resolve(), "after": REPO}
    bytecode(*checkouts.values())
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
                    seconds[name][v].append(child(cmd, path)["wall"])
            log.info("turn %d of %d done", i + 1, args.repeats)
    return dict(versions=list(checkouts), repeats=args.repeats, seconds=seconds,
                checkouts={v: str(p) for v, p in checkouts.items()},
                loaded=loads)  # fmt: skip


if __name__ == "__main__":
    main(__doc__, run, markdown, options, stem="startup", quick=QUICK)
