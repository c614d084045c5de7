"""Newton against an earlier commit's Newton, on the same problem, in one run.

``bench_solver.py --compare-ref REV`` checks REV out into a temporary
``git worktree`` (removed afterwards) and times the 0.1 % gap solve
(``FAST``) of this checkout and of REV alternately, each in its own process with
``PYTHONPATH`` set to its tree, so both import their own ``rhythmic_jax``. Every
process solves once to compile every shape, then once timed; the medians, their
ratio, the Newton steps and the objective gap between the two solutions are
reported.

The child (``python scripts/_newton_ref.py PROBLEM.npz OUT.npz``) imports
nothing of the package but its Newton solver, under either layout
(``rhythmic_jax.solvers.newton``, or ``rhythmic_jax.newton`` before the solvers
had their folder).
"""

from __future__ import annotations

import importlib
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]  # no harness: the child imports nothing


# ---------------------------------------------------------------------- child


def _newton_module():
    for name in ("rhythmic_jax.solvers.newton", "rhythmic_jax.newton"):
        try:
            return importlib.import_module(name)
        except ModuleNotFoundError:
            continue
    raise SystemExit("no Newton solver on PYTHONPATH")


def child(problem: str, out: str) -> None:
    """Solve PROBLEM.npz (``x`` (n, d), ``y`` (n, p), ``c``) with ``FAST`` twice,
    the second time timed; write the templates and the record to OUT.npz."""
    import jax
    from threadpoolctl import threadpool_limits

    newton = _newton_module()
    data = np.load(problem)
    x, y, c = data["x"], data["y"], float(data["c"])
    with threadpool_limits(limits=len(os.sched_getaffinity(0))):
        t0 = time.perf_counter()
        jax.block_until_ready(newton.newton_fit(x, y, c, newton.FAST))
        warmup = time.perf_counter() - t0
        load = os.getloadavg()
        wall, cpu = time.perf_counter(), time.process_time()
        params, info = jax.block_until_ready(newton.newton_fit(x, y, c, newton.FAST))
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    np.savez(
        out,
        w=np.asarray(params.w),
        b=np.asarray(params.b),
        seconds=wall,
        cpu_s=cpu,
        warmup_s=warmup,
        load=np.asarray(load),
        steps=info.steps,
        cg_iterations=np.asarray(info.cg_iterations),
        columns=np.asarray(info.columns),
        module=os.path.relpath(newton.__file__, Path(newton.__file__).parents[2]),
    )


# --------------------------------------------------------------------- parent


def _git(*args: str) -> str:
    return subprocess.run(
        ["git", "-C", str(REPO), *args], check=True, capture_output=True, text=True
    ).stdout.strip()


def _solve(tree: Path, problem: Path, out: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree))
    subprocess.run(
        [sys.executable, str(Path(__file__).resolve()), str(problem), str(out)],
        env=env,
        check=True,
        cwd=tree,
    )
    r = np.load(out)
    return dict(
        seconds=float(r["seconds"]),
        cpu_s=float(r["cpu_s"]),
        warmup_s=float(r["warmup_s"]),
        load_average_start=[round(float(v), 2) for v in r["load"]],
        steps=int(r["steps"]),
        cg_iterations=r["cg_iterations"].tolist(),
        columns=r["columns"].tolist(),
        module=str(r["module"]),
        w=r["w"],
        b=r["b"],
    )


def _objectives(w, b, x64, y64, c) -> np.ndarray:
    """(p,) primal objective of every template in float64."""
    w, b = np.asarray(w, np.float64), np.asarray(b, np.float64)
    h = np.maximum(0.0, 1.0 - y64 * (x64 @ w + b[None, :]))
    return 0.5 * (np.sum(w * w, axis=0) + b * b) + c * np.sum(h * h, axis=0)


def compare(rev: str, x: np.ndarray, y: np.ndarray, c: float, runs: int) -> dict:
    """Time ``FAST`` Newton of REV ("old") and of this checkout ("new"), ``runs``
    processes each, alternating (the order flips every round)."""
    commit = _git("rev-parse", "--short", rev)
    head = _git("rev-parse", "--short", "HEAD")
    dirty = bool(_git("status", "--porcelain", "--untracked-files=no", "rhythmic_jax"))
    x64, y64 = x.astype(np.float64), y.astype(np.float64)
    with tempfile.TemporaryDirectory(prefix="newton-ref-") as tmp:
        tmp = Path(tmp)
        problem = tmp / "problem.npz"
        np.savez(problem, x=x, y=y, c=c)
        tree = tmp / "ref"
        _git("worktree", "add", "--detach", str(tree), commit)
        records: dict[str, list[dict]] = {"old": [], "new": []}
        try:
            for i in range(runs):
                order = ("old", "new") if i % 2 == 0 else ("new", "old")
                for which in order:
                    src = tree if which == "old" else REPO
                    rec = _solve(src, problem, tmp / f"{which}{i}.npz")
                    records[which].append(rec)
                    print(
                        f"[compare-ref] {which} run {i + 1}/{runs}:"
                        f" {rec['seconds']:.2f} s, {rec['steps']} steps",
                        file=sys.stderr,
                    )
        finally:
            _git("worktree", "remove", "--force", str(tree))
    sides = {}
    for which, recs in records.items():
        last = recs[-1]
        f = _objectives(last.pop("w"), last.pop("b"), x64, y64, c)
        for r in recs[:-1]:
            r.pop("w"), r.pop("b")
        wall = np.array([r["seconds"] for r in recs])
        cpu = np.array([r["cpu_s"] for r in recs])
        sides[which] = dict(
            median_s=float(np.median(wall)),
            median_cpu_s=float(np.median(cpu)),
            min_s=float(wall.min()),
            max_s=float(wall.max()),
            steps=sorted({r["steps"] for r in recs}),
            objective=f,
            runs=recs,
        )
    f_old, f_new = sides["old"].pop("objective"), sides["new"].pop("objective")
    gap = (f_new - f_old) / np.abs(f_old)
    return dict(
        ref=commit,
        ref_subject=_git("log", "-1", "--format=%s", commit),
        head=head,
        head_dirty=dirty,
        runs=runs,
        n=int(x.shape[0]),
        d=int(x.shape[1]),
        p=int(y.shape[1]),
        old=sides["old"],
        new=sides["new"],
        ratio=sides["new"]["median_s"] / sides["old"]["median_s"],
        cpu_ratio=sides["new"]["median_cpu_s"] / sides["old"]["median_cpu_s"],
        objective_gap=dict(
            total=float((f_new.sum() - f_old.sum()) / f_old.sum()),
            max=float(gap.max()),
            min=float(gap.min()),
        ),
    )


def markdown(r: dict, aim: float) -> str:
    """The comparison's section of the report."""
    from _harness import table

    rows = []
    for which, label in (("old", f"{r['ref']} (before)"), ("new", "this checkout")):
        s = r[which]
        first = s["runs"][0]
        rows.append(
            [label, s["median_s"], s["min_s"], s["max_s"], s["median_cpu_s"]]
            + [", ".join(map(str, s["steps"])), str(first["cg_iterations"])]
            + [str(first["columns"]), first["module"]]
        )
    heads = ["Newton 0.1 % gap", "median wall s", "min s", "max s", "median CPU s"]
    heads += ["steps", "CG iterations", "columns", "solver module"]
    loads = [
        f"{run['load_average_start'][0]:.1f}"
        for i in range(r["runs"])
        for run in (r["old"]["runs"][i], r["new"]["runs"][i])
    ]
    met = "met" if r["ratio"] <= aim else "NOT met"
    gap = r["objective_gap"]
    return "\n".join(
        [
            "## Newton before and after: the same solve at an earlier commit",
            "",
            f"Nordland summer patchnorm (n = {r['n']}, d = {r['d']}, p = {r['p']}),"
            f' `FAST` (0.1 % gap), solved by commit {r["ref"]} ("{r["ref_subject"]}")'
            f" and by this checkout ({r['head']}"
            f"{', with uncommitted changes' if r['head_dirty'] else ''}),"
            f" {r['runs']} processes each, alternating; each process compiles with"
            " a first solve, then times the second.",
            "",
            table(heads, rows),
            "",
            f"New / old: {r['ratio']:.3f} of the median wall time"
            f" ({r['cpu_ratio']:.3f} of the median CPU time); aim <= {aim:.2f}:"
            f" {met}. Objective of the new solution against the old (relative,"
            f" float64): total {gap['total']:+.2e}, per template"
            f" {gap['min']:+.2e} to {gap['max']:+.2e}. Load average (1 min) at the"
            f" start of each timed solve (old, new of each round): {', '.join(loads)}.",
            "",
        ]
    )


if __name__ == "__main__":
    if len(sys.argv) != 3 or sys.argv[1].startswith("-"):
        print(__doc__)  # --help: what the child does, and who runs it
        sys.exit(len(sys.argv) != 2 or sys.argv[1] not in ("-h", "--help"))
    child(*sys.argv[1:3])
