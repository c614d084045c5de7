"""Frames per second of each augmentation alone and of all seven in sequence.

python scripts/bench_augment.py
"""

import statistics
import time

import torch
from _harness import header, main, table

from rhythmic_jax.augment.kornia_ops import NAMES, AugmentConfig, augment

SIZES = ((32, 64), (112, 224), (224, 224))  # (H, W)
QUICK = dict(batch=8, repeats=1)  # --quick


def cases() -> list[tuple[str, AugmentConfig]]:
    """(label, config) of every timed pipeline."""
    coarse = dict(elastic_impl="coarse")
    return [(name, AugmentConfig((name,), p=1.0)) for name in NAMES] + [
        ("elastic (coarse)", AugmentConfig(("elastic",), 1.0, **coarse)),
        ("all seven (kornia elastic)", AugmentConfig(("all",), p=1.0)),
        ("all seven (coarse elastic)", AugmentConfig(("all",), 1.0, **coarse)),
    ]


def time_case(batch, config: AugmentConfig, repeats: int, min_s=0.2) -> list[float]:
    """Seconds per call of ``augment`` on ``batch``, one per repeat."""
    start = time.perf_counter()
    augment(batch, config, seed=0)  # warm-up, also sizes the inner loop
    calls = max(1, round(min_s / (time.perf_counter() - start)))
    times = []
    for r in range(repeats):
        start = time.perf_counter()
        for i in range(calls):
            augment(batch, config, seed=1 + r * calls + i)
        times.append((time.perf_counter() - start) / calls)
    return times


def options(ap) -> None:
    ap.add_argument("--batch", type=int, default=64)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--threads", type=int, nargs="+", default=[2])


def run(args) -> dict:
    generator, rows = torch.Generator().manual_seed(0), []
    for threads in args.threads:
        torch.set_num_threads(threads)
        for h, w in SIZES[:1] if args.quick else SIZES:
            batch = torch.rand(args.batch, 3, h, w, generator=generator)
            for label, config in cases():
                times = time_case(batch, config, args.repeats)
                fps, median = args.batch / min(times), statistics.median(times)
                row = dict(op=label, size=f"{w}x{h}", threads=threads, fps_best=fps)
                rows.append(row | dict(fps_median=args.batch / median))
                print(f"{threads}t {w}x{h:<4} {label:<28} {fps:9.0f} frames/s")
    return dict(batch=args.batch, repeats=args.repeats, torch_threads=args.threads,
                rows=rows)  # fmt: skip


def markdown(report: dict) -> str:
    """One table per thread count: a row per operation, a column per size."""
    sizes = list(dict.fromkeys(r["size"] for r in report["rows"]))
    ops = list(dict.fromkeys(r["op"] for r in report["rows"]))
    cell = "{fps_best:.0f} ({fps_median:.0f})"
    fps = {(r["threads"], r["op"], r["size"]): cell.format(**r) for r in report["rows"]}
    lines = header("Augmentation throughput (frames/s, CPU)", report) + [
        f"Batch {report['batch']}, p = 1, best (median) of {report['repeats']} runs "
        f"of >= 0.2 s."
    ]
    for threads in report["torch_threads"]:
        rows = [[op, *(fps[threads, op, s] for s in sizes)] for op in ops]
        title = f"## {threads} torch thread{'s' if threads > 1 else ''}"
        lines += ["", title, "", table(["operation", *sizes], rows, "")]
    return "\n".join(lines)


if __name__ == "__main__":
    main(__doc__, run, markdown, options, stem="augment", quick=QUICK)
