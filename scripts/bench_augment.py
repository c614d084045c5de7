"""Frames per second of each augmentation alone and of all seven in sequence.

Usage: ``python scripts/bench_augment.py [--batch 64] [--repeats 5] [--threads 2 1]``

Every operation runs with ``p = 1`` (each image transformed; kornia computes the
transform for the whole batch at any ``p`` and then selects, so this is also the
cost at ``p = 0.5``) on random float32 batches of 64x32, 224x112 and 224x224
(width x height), with the parameter draws included. The elastic transform is
timed with kornia's ``RandomElasticTransform`` and with the coarse-grid version
(``AugmentConfig.elastic_impl="coarse"``), alone and inside the full sequence.
Each figure is ``batch / time per call`` of the fastest and the median of
``--repeats`` runs (each long enough to last 0.2 s) after one warm-up call.
Writes ``reports/augment.json`` and ``reports/augment.md`` and prints the table.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path

import torch

from rhythmic_jax.augment.kornia_ops import NAMES, AugmentConfig, augment

SIZES = ((32, 64), (112, 224), (224, 224))  # (H, W)


def cases() -> list[tuple[str, AugmentConfig]]:
    """(label, config) of every timed pipeline."""
    out = [(name, AugmentConfig((name,), p=1.0)) for name in NAMES]
    out.append(
        ("elastic (coarse)", AugmentConfig(("elastic",), 1.0, elastic_impl="coarse"))
    )
    out.append(("all seven (kornia elastic)", AugmentConfig(("all",), p=1.0)))
    out.append(
        (
            "all seven (coarse elastic)",
            AugmentConfig(("all",), 1.0, elastic_impl="coarse"),
        )
    )
    return out


def time_case(
    batch: torch.Tensor, config: AugmentConfig, repeats: int, min_s: float = 0.2
) -> list[float]:
    """Seconds per call of ``augment`` on ``batch``, one per repeat.

    Each repeat times enough calls (new seeds) to last ``min_s`` seconds, so
    that fast operations are not measured at the scale of scheduler ticks.
    """
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


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=64)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--threads", type=int, nargs="+", default=[2])
    parser.add_argument("--out-dir", type=Path, default=Path("reports"))
    args = parser.parse_args(argv)
    generator = torch.Generator().manual_seed(0)
    rows = []
    for threads in args.threads:
        torch.set_num_threads(threads)
        for h, w in SIZES:
            batch = torch.rand(args.batch, 3, h, w, generator=generator)
            for label, config in cases():
                times = time_case(batch, config, args.repeats)
                rows.append(
                    {
                        "op": label,
                        "size": f"{w}x{h}",
                        "threads": threads,
                        "fps_best": args.batch / min(times),
                        "fps_median": args.batch / statistics.median(times),
                    }
                )
                fps = rows[-1]["fps_best"]
                print(f"{threads}t {w}x{h:<4} {label:<28} {fps:9.0f} frames/s")
    report = {
        "batch": args.batch,
        "repeats": args.repeats,
        "torch_threads": args.threads,
        "cpu_count": os.cpu_count(),
        "load_average": os.getloadavg(),
        "torch": torch.__version__,
        "python": platform.python_version(),
        "rows": rows,
    }
    args.out_dir.mkdir(parents=True, exist_ok=True)
    (args.out_dir / "augment.json").write_text(json.dumps(report, indent=2) + "\n")
    table = markdown(report)
    (args.out_dir / "augment.md").write_text(table)
    print(table)
    return report


def markdown(report: dict) -> str:
    """One table per thread count: a row per operation, a column per size."""
    sizes = [f"{w}x{h}" for h, w in SIZES]
    fps = {(r["threads"], r["op"], r["size"]): r for r in report["rows"]}
    ops = list(dict.fromkeys(r["op"] for r in report["rows"]))
    lines = [
        "# Augmentation throughput (frames/s, CPU)",
        "",
        f"Batch {report['batch']}, p = 1, best (median) of {report['repeats']} runs "
        f"of >= 0.2 s; torch {report['torch']}, {report['cpu_count']} cores, load "
        f"average at the end {report['load_average'][0]:.1f} (a shared machine). "
        "Command: `python scripts/bench_augment.py --threads "
        + " ".join(map(str, report["torch_threads"]))
        + "`.",
    ]
    for threads in report["torch_threads"]:
        lines += [
            "",
            f"## {threads} torch thread{'s' if threads > 1 else ''}",
            "",
            "| operation | " + " | ".join(sizes) + " |",
            "|---|" + "---|" * len(sizes),
        ]
        for op in ops:
            cells = [fps[threads, op, s] for s in sizes]
            text = [f"{c['fps_best']:.0f} ({c['fps_median']:.0f})" for c in cells]
            lines.append(f"| {op} | " + " | ".join(text) + " |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
