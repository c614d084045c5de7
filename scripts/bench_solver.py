"""Time the joint solve of every candidate's templates against liblinear.

The map's period search trains every template of 7 candidate periods
(``candidate_periods(n, 2, level=1, count=7)``, p templates in all) jointly. This
script times that solve three ways on the same features, in the same run:

- Newton-CG (:func:`rhythmic_jax.newton.newton_fit`, default config), all p
  templates at once;
- optax L-BFGS (:func:`rhythmic_jax.train.fit_full_batch`, default settings)
  from the ridge start, all p templates at once;
- scikit-learn ``LinearSVC(loss="squared_hinge", dual=True, C=log N)`` (liblinear,
  default ``tol=1e-4``, ``max_iter=1000``), one template after another as the
  paper did. A liblinear fit takes seconds, so it runs on a fixed sample of
  templates spread evenly over all candidates (columns
  ``linspace(0, p - 1, samples)``) and its time is extrapolated linearly to all p
  templates: ``mean seconds per sampled template * p``.

Objective gaps are relative, ``(f_solver - f_ref) / f_ref`` of liblinear's primal
``0.5 (||w||^2 + b^2) + C sum_i max(0, 1 - y_i (w.x_i + b))^2`` in float64 numpy
(negative: the solver went lower than the reference). Each JAX solver is first
called once on the same shapes (Newton: one step of one CG iteration; L-BFGS: two
steps, same optimiser object) so that the timed call does not compile; the
warm-up's time is reported too.

Features: (a) Nordland summer, patch-normalised 64x32 (2048-d), all 3576 frames;
(b) "video-like" 3705 x 4096 rows: a stationary Gaussian random walk
``z_t = rho z_(t-1) + sqrt(1 - rho^2) e_t`` (rho = 0.99, so neighbours are similar
and frames a few hundred apart are not) plus per-frame noise of standard
deviation 0.3, rows L2-normalised, seeded.

    python scripts/bench_solver.py           # writes reports/solver.{json,md}
    python scripts/bench_solver.py --quick   # 800 frames, 4 sampled templates
    python scripts/bench_solver.py --render reports/solver.json  # Markdown again
"""

from __future__ import annotations

import argparse
import logging
import warnings
from pathlib import Path

import numpy as np
import optax
from _bench_common import (
    DEFAULT_DATA,
    RENDER_HELP,
    REPO,
    command_line,
    cores,
    environment,
    header,
    load_average,
    plain,
    rerender,
    set_threads,
    stats,
    table,
    timed,
    write_report,
)
from sklearn.exceptions import ConvergenceWarning
from sklearn.svm import LinearSVC

from rhythmic_jax.data import nordland
from rhythmic_jax.features import cached_describe, get_descriptor
from rhythmic_jax.newton import NewtonConfig, newton_fit
from rhythmic_jax.objective import (
    default_c,
    period_errors,
    period_offsets,
    scores,
    targets,
)
from rhythmic_jax.periods import candidate_periods, choose_periods
from rhythmic_jax.train import fit_full_batch

log = logging.getLogger("bench_solver")

AIM_SPEEDUP = 100.0
AIM_GAP = 1e-3
VIDEO = dict(rho=0.99, noise=0.3, seed=0)


# ------------------------------------------------------------------- features


def nordland_summer(root: Path, frames: int, progress: bool) -> np.ndarray:
    """(frames, 2048) patch-normalised Nordland summer descriptors, cached."""
    (summer,) = nordland(root / "nordland_64x32", ("summer",), progress=progress)
    x = cached_describe(
        summer.images,
        get_descriptor("patchnorm"),
        "nordland64x32-summer",
        progress=progress,
    )
    return x[:frames]


def video_like(n: int, d: int, rho: float, noise: float, seed: int) -> np.ndarray:
    """(n, d) float32 unit rows: AR(1) Gaussian walk plus per-frame noise."""
    rng = np.random.default_rng(seed)
    steps = rng.standard_normal((n, d), dtype=np.float32)
    walk = np.empty_like(steps)
    walk[0] = steps[0]
    scale = np.float32(np.sqrt(1.0 - rho * rho))
    for t in range(1, n):
        walk[t] = np.float32(rho) * walk[t - 1] + scale * steps[t]
    x = walk + np.float32(noise) * rng.standard_normal((n, d), dtype=np.float32)
    return x / np.linalg.norm(x, axis=1, keepdims=True)


def neighbour_cosines(x: np.ndarray, lags=(1, 10, 100, 1000)) -> dict[str, float]:
    """Mean cosine of frames ``lag`` apart (rows are unit vectors)."""
    return {
        str(lag): float(np.mean(np.sum(x[lag:] * x[:-lag], axis=1)))
        for lag in lags
        if lag < len(x)
    }


# ------------------------------------------------------------------- solvers


def liblinear_objectives(w, b, x64: np.ndarray, y: np.ndarray, c: float):
    """(p,) liblinear primal of every template, float64: w (d, p), b (p,)."""
    w = np.asarray(w, np.float64).reshape(x64.shape[1], -1)
    b = np.asarray(b, np.float64).reshape(-1)
    hinge = np.maximum(0.0, 1.0 - y * (x64 @ w + b[None, :]))
    return 0.5 * (np.sum(w * w, axis=0) + b * b) + c * np.sum(hinge * hinge, axis=0)


def sampled_columns(periods: tuple[int, ...], samples: int) -> list[dict]:
    """``samples`` template columns spread evenly over all p, with their
    (period, phase)."""
    p = sum(periods)
    cols = np.unique(np.linspace(0, p - 1, samples).round().astype(int))
    offs = period_offsets(periods)
    out = []
    for col in cols:
        k = int(np.searchsorted(offs, col, side="right") - 1)
        out.append(dict(column=int(col), period=periods[k], phase=int(col - offs[k])))
    return out


def run_linearsvc(x64: np.ndarray, y: np.ndarray, c: float, picks: list[dict]):
    """Fit LinearSVC on each sampled column; times, iterations and parameters."""
    rows = []
    for pick in picks:
        svc = LinearSVC(C=c, loss="squared_hinge", dual=True, random_state=0)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", ConvergenceWarning)
            _, seconds, cpu = timed(svc.fit, x64, y[:, pick["column"]])
        converged = not any(issubclass(w.category, ConvergenceWarning) for w in caught)
        rows.append(
            dict(**pick, seconds=seconds, cpu_s=cpu, n_iter=int(svc.n_iter_))
            | dict(converged=converged, w=svc.coef_[0], b=svc.intercept_[0])
        )
        log.info("LinearSVC %s: %.2f s, %d iterations", pick, seconds, svc.n_iter_)
    return rows


def run_newton(x: np.ndarray, y: np.ndarray, c: float, progress: bool):
    """Warm-up (setup + one CG iteration, compiles), then the timed full solve."""
    warm = NewtonConfig(max_iter=1, max_cg=1)
    _, warmup, _ = timed(newton_fit, x, y, c, warm, progress=False)
    load = load_average()
    (params, info), seconds, cpu = timed(newton_fit, x, y, c, progress=progress)
    log.info(
        "Newton: %.1f s (%d steps, CG %s)", seconds, info.steps, info.cg_iterations
    )
    return (
        params,
        info,
        dict(seconds=seconds, cpu_s=cpu, warmup_s=warmup, load_average_start=load),
    )


def run_lbfgs(x: np.ndarray, y: np.ndarray, c: float, progress: bool):
    """Warm-up (two steps, compiles), then the timed full solve (default
    settings; the same ``optax.lbfgs()`` object so the jitted step is reused)."""
    opt = optax.lbfgs()
    _, warmup, _ = timed(fit_full_batch, x, y, c, steps=2, optimizer=opt, progress=0)
    load = load_average()
    (params, history), seconds, cpu = timed(
        fit_full_batch, x, y, c, optimizer=opt, progress=progress
    )
    log.info("L-BFGS: %.1f s (%d steps)", seconds, len(history))
    return (
        params,
        history,
        dict(seconds=seconds, cpu_s=cpu, warmup_s=warmup, load_average_start=load),
    )


# ---------------------------------------------------------------------- cases


def _gap(ours, ref):
    return (ours - ref) / np.abs(ref)


def bench_case(name: str, x: np.ndarray, samples: int, progress: bool) -> dict:
    """All three solvers on features ``x`` (n, d); returns the case's record."""
    n, d = x.shape
    cands = candidate_periods(n, 2, 1, 7)
    p, c, labels = sum(cands), default_c(n), np.arange(n)
    y = np.asarray(targets(labels, cands))
    x64, y64 = x.astype(np.float64), y.astype(np.float64)
    log.info("%s: n=%d d=%d candidates %s (p=%d), C=%.4f", name, n, d, cands, p, c)

    load_svc = load_average()
    svc = run_linearsvc(x64, y64, c, sampled_columns(cands, samples))
    w_n, info, newton = run_newton(x, y, c, progress)
    w_l, hist, lbfgs = run_lbfgs(x, y, c, progress)

    f_n = liblinear_objectives(w_n.w, w_n.b, x64, y64, c)
    f_l = liblinear_objectives(w_l.w, w_l.b, x64, y64, c)
    cols = [t["column"] for t in svc]
    f_svc = np.array(
        [
            liblinear_objectives(t.pop("w"), t.pop("b"), x64, y64[:, [j]], c)[0]
            for t, j in zip(svc, cols, strict=True)
        ]
    )
    for t, f, j in zip(svc, f_svc, cols, strict=True):
        t.update(objective=f, newton_gap=_gap(f_n[j], f), lbfgs_gap=_gap(f_l[j], f))
    wall = np.array([t["seconds"] for t in svc])
    cpu = np.array([t["cpu_s"] for t in svc])
    linearsvc = dict(
        settings=dict(loss="squared_hinge", dual=True, tol=1e-4, max_iter=1000, C=c),
        sampled=len(svc),
        per_template_s=dict(**stats(wall), std=float(wall.std())),
        per_template_cpu_s=dict(**stats(cpu), std=float(cpu.std())),
        extrapolated_s=float(wall.mean() * p),
        extrapolated_cpu_s=float(cpu.mean() * p),
        extrapolated_range_s=[float(wall.min() * p), float(wall.max() * p)],
        load_average_start=load_svc,
        templates=svc,
    )
    margins = y64 * (x64 @ np.asarray(w_n.w, np.float64) + np.asarray(w_n.b))
    newton.update(
        form=info.form,
        steps=info.steps,
        cg_iterations=list(info.cg_iterations),
        active_fraction=float(np.mean(margins < 1.0)),
        gap_vs_linearsvc=stats(_gap(f_n[cols], f_svc)),
        training_error=np.asarray(period_errors(scores(w_n, x), labels, cands)),
    )
    newton["chosen_periods"] = choose_periods(cands, newton["training_error"], n, 2)
    lbfgs.update(
        steps=len(hist),
        gap_vs_linearsvc=stats(_gap(f_l[cols], f_svc)),
        gap_vs_newton=stats(_gap(f_l, f_n)),
        total_gap_vs_newton=_gap(f_l.sum(), f_n.sum()),
        training_error=np.asarray(period_errors(scores(w_l, x), labels, cands)),
    )
    for t in (newton, lbfgs):
        t["speedup_vs_linearsvc"] = linearsvc["extrapolated_s"] / t["seconds"]
        t["cpu_speedup_vs_linearsvc"] = linearsvc["extrapolated_cpu_s"] / t["cpu_s"]
    return plain(
        dict(
            name=name,
            n=n,
            d=d,
            xla_threads=cores(),
            candidates=cands,
            p=p,
            c=c,
            linearsvc=linearsvc,
            newton=newton,
            lbfgs=lbfgs,
            newton_vs_lbfgs_speedup=lbfgs["seconds"] / newton["seconds"],
        )
    )


# -------------------------------------------------------------------- report


def cg_flops(r: dict) -> float:
    """Floating-point operations of Newton's CG products: per iteration one
    (n, n) x (n, p) product in the Gram form, two (n, d+1) ones in the primal."""
    n, d, p = r["n"], r["d"], r["p"]
    per = 2 * n * n * p if r["newton"]["form"] == "gram" else 4 * n * (d + 1) * p
    return float(per * sum(r["newton"]["cg_iterations"]))


def _rel(v: float) -> str:
    return f"{v:+.2e}"


TIMING = ["solver", "wall s", "LinearSVC / this", "CPU s", "LinearSVC / this (CPU)"]
GAPS = ["comparison", "templates", "max gap", "median gap", "min gap"]
SAMPLED = ["period", "phase", "LinearSVC s", "iterations", "converged", "objective"]


def case_markdown(r: dict) -> str:
    s, nw, lb = r["linearsvc"], r["newton"], r["lbfgs"]
    per = s["per_template_s"]
    aim = (
        nw["speedup_vs_linearsvc"] >= AIM_SPEEDUP
        and nw["gap_vs_linearsvc"]["max"] <= AIM_GAP
    )
    solvers = [
        (f"LinearSVC, {r['p']} templates (extrapolated from {s['sampled']})", s),
        (f"Newton-CG, joint ({nw['form']} form)", nw),
        ("optax L-BFGS, joint (ridge start)", lb),
    ]
    wall0, cpu0 = s["extrapolated_s"], s["extrapolated_cpu_s"]
    rows = []
    for label, t in solvers:
        wall, cpu = t.get("seconds", wall0), t.get("cpu_s", cpu0)
        load = f"{t['load_average_start'][0]:.1f}"
        rows.append([label, wall, wall0 / wall, cpu, cpu0 / cpu, load])
    timing = table([*TIMING, "load avg at start"], rows)
    sampled_label, stats = f"{s['sampled']} sampled", ("max", "median", "min")
    gaps = table(
        GAPS,
        [
            [label, which, *(_rel(g[k]) for k in stats)]
            for label, which, g in (
                ("Newton vs LinearSVC", sampled_label, nw["gap_vs_linearsvc"]),
                ("L-BFGS vs LinearSVC", sampled_label, lb["gap_vs_linearsvc"]),
                ("L-BFGS vs Newton", f"all {r['p']}", lb["gap_vs_newton"]),
            )
        ],
    )
    errors = table(
        ["candidate period", "Newton training error", "L-BFGS training error"],
        [
            list(row)
            for row in zip(
                r["candidates"], nw["training_error"], lb["training_error"], strict=True
            )
        ],
    )
    sampled = table(
        [*SAMPLED, "Newton gap", "L-BFGS gap"],
        [
            [t["period"], t["phase"], t["seconds"], t["n_iter"]]
            + ["yes" if t["converged"] else "no", t["objective"]]
            + [_rel(t["newton_gap"]), _rel(t["lbfgs_gap"])]
            for t in s["templates"]
        ],
    )
    lo, hi = s["extrapolated_range_s"]
    return "\n".join(
        [
            f"## {r['name']}: n = {r['n']}, d = {r['d']}",
            "",
            f"Candidates {r['candidates']} (p = {r['p']} templates), C = log N ="
            f" {r['c']:.4f}. The load changed between solvers: see each row.",
            "",
            timing,
            "",
            "LinearSVC(loss='squared_hinge', dual=True, C=log N, tol=1e-4,"
            " max_iter=1000; intercept_scaling=1 makes the bias a regularised"
            " constant-1 feature, the same objective) was run on"
            f" {s['sampled']} of the {r['p']} templates only;"
            f" its time is EXTRAPOLATED: per template {per['mean']:.2f} s mean"
            f" (std {per['std']:.2f}, min {per['min']:.2f}, max {per['max']:.2f}),"
            f" times p = {r['p']}: {s['extrapolated_s']:.0f} s (range"
            f" {lo:.0f}-{hi:.0f} s from the fastest and slowest sampled template)."
            f" liblinear runs on one thread, the JAX solvers on {r['xla_threads']}"
            " (XLA's pool): CPU seconds (all threads of the process) count the"
            " work, wall seconds what a user waits.",
            "",
            f"Newton: {nw['steps']} steps, CG iterations {nw['cg_iterations']}"
            f" ({sum(nw['cg_iterations'])} in all, their products"
            f" {cg_flops(r) / 1e9:,.4g} GFLOP in float32, i.e."
            f" {cg_flops(r) / 1e9 / nw['seconds']:.3g} GFLOP/s over the solve's"
            f" wall time); at the optimum"
            f" {100 * nw['active_fraction']:.1f} % of (frame, template) margins are"
            f" active (< 1). Warm-up call (setup, one CG iteration, compilation):"
            f" {nw['warmup_s']:.1f} s. L-BFGS: {lb['steps']} steps (warm-up of two"
            f" steps {lb['warmup_s']:.1f} s). Wall time L-BFGS / Newton:"
            f" {r['newton_vs_lbfgs_speedup']:.2f}. Periods"
            f" chosen from Newton's training errors: {nw['chosen_periods']}.",
            "",
            f"Aim (>= {AIM_SPEEDUP:.0f}x over LinearSVC at <= {100 * AIM_GAP:.1f} %"
            f" objective gap): {'met' if aim else 'NOT met'}"
            f" ({nw['speedup_vs_linearsvc']:.1f}x, max gap"
            f" {_rel(nw['gap_vs_linearsvc']['max'])}).",
            "",
            "Relative objective gaps (f_solver - f_ref) / f_ref, liblinear's primal"
            " in float64 (negative: lower than the reference):",
            "",
            gaps,
            "",
            "Training error of every candidate (fraction of frames whose argmax"
            " phase is wrong):",
            "",
            errors,
            "",
            "Sampled templates:",
            "",
            sampled,
            "",
        ]
    )


def markdown(report: dict) -> str:
    title = "Joint solve of all candidate templates: Newton-CG, L-BFGS, liblinear"
    parts = header(title, report)
    for r in report["cases"]:
        parts.append(case_markdown(r))
    if report.get("video_like"):
        v = report["video_like"]
        cos = ", ".join(f"{lag}: {c:.3f}" for lag, c in v["cosines"].items())
        parts += [
            f"Video-like features: AR(1) walk rho = {v['rho']}, noise {v['noise']},"
            f" seed {v['seed']}; mean cosine of frames lag apart: {cos}.",
            "",
        ]
    return "\n".join(parts)


# ---------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", type=Path, default=DEFAULT_DATA, help="shared data")
    ap.add_argument("--out", type=Path, default=REPO / "reports")
    ap.add_argument("--frames", type=int, default=None, help="Nordland frames")
    ap.add_argument("--video-frames", type=int, default=None)
    ap.add_argument("--video-dim", type=int, default=4096)
    ap.add_argument("--samples", type=int, default=None, help="LinearSVC templates")
    ap.add_argument("--quick", action="store_true", help="800 frames, 4 templates")
    ap.add_argument("--no-progress", dest="progress", action="store_false")
    ap.add_argument("--render", type=Path, default=None, help=RENDER_HELP)
    args = ap.parse_args(argv)
    if args.render:
        return rerender(args.render, markdown)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    frames = args.frames or (800 if args.quick else 3576)
    video_frames = args.video_frames or (800 if args.quick else 3705)
    samples = args.samples or (4 if args.quick else 12)

    threads = set_threads(cores())
    env = environment(threads)
    log.info("environment %s", env)
    load_start = load_average()
    cases = []
    nordland_dir = args.root / "nordland_64x32"
    if nordland_dir.is_dir():
        x = nordland_summer(args.root, frames, args.progress)
        cases.append(
            bench_case("Nordland summer, patchnorm 64x32", x, samples, args.progress)
        )
    else:
        log.warning(
            "no Nordland data at %s: skipping the real-frame case", nordland_dir
        )
    xv = video_like(video_frames, args.video_dim, **VIDEO)
    cases.append(bench_case("Video-like random walk", xv, samples, args.progress))
    report = dict(
        command=command_line("bench_solver.py", argv),
        environment=env,
        load_average=dict(start=load_start, end=load_average()),
        aim=dict(speedup=AIM_SPEEDUP, gap=AIM_GAP),
        video_like=dict(**VIDEO, cosines=neighbour_cosines(xv)),
        cases=cases,
    )
    stem = "solver_quick" if args.quick else "solver"
    write_report(args.out, stem, report, markdown(report))
    return report


if __name__ == "__main__":
    main()
