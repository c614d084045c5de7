"""The memory estimate of a full-batch fit against its measured peak, by shape.

python scripts/bench_memory.py [--shapes 1000x64 3000x128 ...] [--repeats 2]
"""

import time

import numpy as np
from _harness import call, header, main, table

from rhythmic_jax.map.periods import candidate_periods
from rhythmic_jax.solvers.memory import check_memory, fit_bytes, peak_growth

SHAPES = ["1000x64", "3000x128", "2000x256", "800x800", "400x1024", "250x4096"]
QUICK = dict(shapes=["600x32"], repeats=1)  # --quick
MB = 1e6

HEAD = ["n x d", "shape", "p", "estimate MB", "cold MB", "est / cold", "arrays MB",
        "warm MB", "arrays / warm", "limit kept"]  # fmt: skip


def fit_peak(x: np.ndarray) -> int:
    """Bytes a fit of x (n, d) adds to this process at its peak (x included)."""
    from rhythmic_jax import RhythmicMap

    return peak_growth(lambda: RhythmicMap().fit(x, progress=False)) + x.nbytes


def measure(repeats: int, shapes: list[str]) -> list[dict]:
    """The fresh process: a record per shape."""
    from rhythmic_jax import RhythmicMap

    rng, rows = np.random.default_rng(0), []
    RhythmicMap().fit(rng.normal(size=(48, 8)).astype(np.float32), progress=False)
    for shape in shapes:
        n, d = map(int, shape.split("x"))
        p, x = sum(candidate_periods(n)), rng.normal(size=(n, d)).astype(np.float32)
        estimate = sum(fit_bytes(n, d, p).values())
        admitted = check_memory(n, d, p, limit_bytes=estimate) == estimate
        t0 = time.perf_counter()
        cold = fit_peak(x)
        t1 = time.perf_counter()
        RhythmicMap().fit(x, progress=False)  # the first run of compiled code
        warm = [fit_peak(x) for _ in range(repeats)]
        warm_s = (time.perf_counter() - t1) / max(repeats, 1)
        rows.append(dict(n=n, d=d, p=p, admitted=admitted, cold=cold, warm=warm,
                         cold_s=t1 - t0, warm_s=warm_s))  # fmt: skip
    return rows


def markdown(report: dict) -> str:
    rows = [[f"{r['n']} x {r['d']}", r["kind"], r["p"], r["estimate"] / MB,
             r["cold"] / MB, r["estimate"] / r["cold"],
             r["arrays"] / MB, max(r["warm"]) / MB, r["arrays"] / max(r["warm"]),
             "yes" if r["admitted"] and r["cold"] <= r["estimate"] else "NO"]
            for r in report["rows"]]  # fmt: skip
    kept = all(r["cold"] <= r["estimate"] for r in report["rows"])
    return "\n".join(
        header("Memory of a full-batch fit: estimate against measured peak", report)
        + [
            "Random float32 frames, the default map (r = 2, 7 candidate periods: p"
            " templates). Peaks are the growth of the process's resident memory during"
            " the fit, sampled every ms, over a baseline taken after `malloc_trim(0)`"
            " (glibc otherwise serves the fit from memory an earlier one freed, and the"
            " growth undercounts). *Cold*: the shape's first fit in a process whose"
            " runtime is loaded (its functions compile); *warm*: the largest of"
            f" {report['repeats']} refits of the same frames after one unmeasured"
            " (nothing compiles). *Estimate*: the sum of `fit_bytes`; *arrays*: the"
            f" same without its `compile` part ({report['compile_bytes'] / MB:.0f} MB)."
            " *Limit kept*: the guard with its limit set to the estimate (`--memory X`,"
            " X = the estimate) admits the fit and the cold peak stays under X.",
            "",
            table(HEAD, rows),
            "",
            f"The limit held on every shape: {'yes' if kept else 'NO'}.",
        ]
    )


def options(ap) -> None:
    ap.add_argument("--shapes", nargs="+", default=SHAPES, help="NxD ...")
    ap.add_argument("--repeats", type=int, default=2, help="warm refits a shape")


def run(args) -> dict:
    rows = call(measure, args.repeats, args.shapes)["result"]
    for r in rows:
        n, d = r["n"], r["d"]
        parts = fit_bytes(n, d, r["p"])
        kind = "wide (span)" if d > 2 * n else ("tall" if n > 2 * d else "square")
        est = sum(parts.values())
        r.update(kind=kind, parts=parts, estimate=est, arrays=est - parts["compile"])
    compile_bytes = rows[0]["parts"]["compile"] if rows else 0
    return dict(repeats=args.repeats, compile_bytes=compile_bytes, rows=rows)


if __name__ == "__main__":
    main(__doc__, run, markdown, options, stem="memory", quick=QUICK)
