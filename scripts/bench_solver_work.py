"""Where the 0.1 % gap solve's work could be cut: losing candidates, idle frames.

python scripts/bench_solver_work.py [--slack 0.005] [--after 4]
"""

from pathlib import Path

import numpy as np
from _harness import header, log, main, nordland_features, table, timed

from rhythmic_jax.map.periods import candidate_periods, choose_periods, period_offsets
from rhythmic_jax.solvers.candidates import DropLosers
from rhythmic_jax.solvers.newton import FAST, newton_fit
from rhythmic_jax.solvers.objective import default_c, period_errors, scores, targets


class Record:
    """A ``stop`` hook that stops nothing and keeps every step's errors."""

    def __init__(self, labels, cands):
        self.labels, self.cands, self.errors = labels, cands, []

    def __call__(self, step, margins):
        errs = np.asarray(period_errors(margins, self.labels, self.cands))
        self.errors.append(errs.tolist())
        return np.zeros(sum(self.cands), bool)


def options(ap) -> None:
    ap.add_argument("--frames", type=Path, default=None, help="(n, d) .npy")
    ap.add_argument("--slack", type=float, default=0.005)
    ap.add_argument("--after", type=int, default=4)


def run(args) -> dict:
    if args.frames:
        x = np.load(args.frames).astype(np.float32)
    else:
        (x,) = nordland_features(args.root, seasons=("summer",), progress=args.progress)
    if args.quick:
        x = x[:600]
    n, labels = len(x), np.arange(len(x))
    cands = candidate_periods(n, 2, 1, 7)
    y, c = np.asarray(targets(labels, cands)), default_c(n)
    runs = {}
    for name, make in (
        ("full", lambda: Record(labels, cands)),
        ("drop", lambda: DropLosers(labels, cands, n, 2, args.slack, args.after)),
    ):
        newton_fit(x, y, c, FAST, stop=make())  # compiles
        stop = make()
        (params, info), seconds, _ = timed(newton_fit, x, y, c, FAST, stop=stop)
        s = scores(params, x)
        errors = np.asarray(period_errors(s, labels, cands))
        chosen = choose_periods(cands, errors, n, 2)
        runs[name] = dict(
            seconds=seconds, steps=info.steps, cg_iterations=list(info.cg_iterations),
            columns=list(info.columns),
            work=int(np.dot(info.cg_iterations, info.columns)), errors=errors.tolist(),
            chosen=list(chosen), objective=info.objective.tolist(),
            step_errors=stop.errors if isinstance(stop, Record) else None,
            dropped=[[k, list(t)] for k, t in getattr(stop, "dropped", [])],
        )  # fmt: skip
        if name == "full":
            active = (y * np.asarray(s, np.float64) < 1).sum(axis=1)
            runs[name]["active_per_frame"] = dict(
                min=int(active.min()), mean=float(active.mean()),
                idle_frames=int((active == 0).sum()),
            )  # fmt: skip
        log.info("%s: %.1f s, work %d, chosen %s", name, seconds,
                 runs[name]["work"], chosen)  # fmt: skip
    full, drop = runs["full"], runs["drop"]
    offs = dict(zip(cands, period_offsets(cands), strict=True))
    cols = np.concatenate([np.arange(offs[t], offs[t] + t) for t in full["chosen"]])
    f0, f1 = np.asarray(full["objective"])[cols], np.asarray(drop["objective"])[cols]
    return dict(n=n, d=int(x.shape[1]), candidates=list(cands), c=c, slack=args.slack,
                after=args.after, runs=runs,
                chosen_gap=float(np.max(np.abs(f1 - f0) / f0)))  # fmt: skip


def markdown(r: dict) -> str:
    full, drop = r["runs"]["full"], r["runs"]["drop"]
    n, cands = r["n"], r["candidates"]
    steps = np.rint(np.asarray(full["step_errors"]) * n).astype(int)
    final = np.rint(np.asarray(full["errors"]) * n).astype(int)
    move = np.abs(steps - final).max(axis=1)
    rows = [
        [k, *(int(v) for v in e), int(mv)]
        for k, (e, mv) in enumerate(zip(steps, move, strict=True))
    ] + [["end", *(int(v) for v in final), 0]]
    act, same = full["active_per_frame"], full["chosen"] == drop["chosen"]
    head = header("The 0.1 % solve's work: losing candidates and idle frames", r)
    return "\n".join([*head, "\n\n".join([
        f"Nordland summer, patchnorm: n = {n}, d = {r['d']}, candidates {cands}"
        f" ({sum(cands)} templates), C = {r['c']:.4f}, Newton ``FAST`` (0.1 % gap).",
        table(
            ["solve", "wall s", "steps", "CG iterations", "columns",
             "work (columns x CG)", "periods chosen"],
            [
                ["all candidates to the end", full["seconds"], full["steps"],
                 str(full["cg_iterations"]), str(full["columns"]), full["work"],
                 str(full["chosen"])],
                [f"losers stopped (slack {r['slack']}, from step {r['after']})",
                 drop["seconds"], drop["steps"], str(drop["cg_iterations"]),
                 str(drop["columns"]), drop["work"], str(drop["chosen"])],
            ],
        ),  # fmt: skip
        "The wall times differ by the machine's load only where the work is the same.",
        f"Candidates stopped (step, periods): {drop['dropped'] or 'none'}. Same"
        f" periods chosen: {same}; largest relative objective difference of the"
        f" chosen periods' templates between the two solves: {r['chosen_gap']:.1e}.",
        "Training errors (frames) of every candidate after every Newton step of the"
        " full solve, and the most any candidate still moves from there to the end"
        " (what a safe slack must cover, for each of the 2r errors compared):",
        table(["step", *(str(t) for t in cands), "largest move to the end"], rows),
        f"Frames beyond the margin for every one of the {sum(cands)} templates at the"
        " end (which liblinear-style shrinking could drop from the dense products):"
        f" {act['idle_frames']} of {n}; every frame is active (margin < 1) for"
        f" {act['min']} templates at least, {act['mean']:.0f} on average.",
    ])])  # fmt: skip


if __name__ == "__main__":
    main(__doc__, run, markdown, options, stem="solver_work")
