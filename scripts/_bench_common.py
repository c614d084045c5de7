"""Shared by the benchmark scripts: thread settings, the machine's record, reports.

Every benchmark pins torch, BLAS and faiss to the same thread count as XLA (whose
CPU client runs one intra-op thread per schedulable core), records the devices,
the versions and the load average (the machine is shared: timings taken under
load are pessimistic), and writes its report as JSON and Markdown atomically.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import platform
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import faiss
import jax
import numpy as np
import torch
from threadpoolctl import threadpool_info, threadpool_limits

from rhythmic_jax.io.atomic import write_file

REPO = Path(__file__).resolve().parents[1]
DEFAULT_DATA = Path(os.environ.get("RHYTHMIC_DATA", REPO.parent / "shared" / "data"))

RENDER_HELP = "re-render the Markdown of this JSON report (no timing)"

_LIMITS: list[threadpool_limits] = []  # keep the global BLAS limit referenced


def cores() -> int:
    """Cores this process may run on (XLA sizes its CPU thread pool by this)."""
    return len(os.sched_getaffinity(0))


def set_threads(n: int) -> dict[str, int]:
    """Pin torch intra-op, BLAS (threadpoolctl) and faiss OpenMP to ``n`` threads.

    Returns the counts in force afterwards, XLA's included.
    """
    torch.set_num_threads(n)
    _LIMITS.append(threadpool_limits(limits=n))
    faiss.omp_set_num_threads(n)
    blas = sorted({int(p["num_threads"]) for p in threadpool_info()})
    return dict(
        xla=cores(),
        torch=torch.get_num_threads(),
        blas=blas[0] if len(blas) == 1 else -1,
        faiss=n,
    )


def timed(fn, *args, **kwargs):
    """``(fn(*args, **kwargs), wall seconds, process CPU seconds)``.

    JAX results are waited for. The CPU time sums every thread of this process:
    it counts the work done and is less sensitive than the wall clock to other
    processes' load.
    """
    wall, cpu = time.perf_counter(), time.process_time()
    out = jax.block_until_ready(fn(*args, **kwargs))
    return out, time.perf_counter() - wall, time.process_time() - cpu


def stats(v) -> dict[str, float]:
    """max, median, min and mean of an array."""
    v = np.asarray(v, np.float64)
    return dict(
        max=float(v.max()),
        median=float(np.median(v)),
        min=float(v.min()),
        mean=float(v.mean()),
    )


def plain(obj):
    """``obj`` with numpy scalars and arrays and tuples turned into JSON types."""
    if isinstance(obj, dict):
        return {str(k): plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple | np.ndarray):
        return [plain(v) for v in obj]
    if isinstance(obj, np.integer | np.bool_):
        return obj.item()
    if isinstance(obj, np.floating):
        return float(obj)
    return obj


def load_average() -> list[float]:
    """1, 5 and 15 minute load averages (``os.getloadavg``), rounded."""
    return [round(v, 2) for v in os.getloadavg()]


def environment(threads: dict[str, int]) -> dict:
    """Devices, versions, core count, thread counts and XLA flags of this run."""
    import optax
    import sklearn

    return dict(
        devices=[str(d) for d in jax.devices()],
        jax=jax.__version__,
        optax=optax.__version__,
        numpy=np.__version__,
        sklearn=sklearn.__version__,
        faiss=faiss.__version__,
        torch=torch.__version__,
        python=platform.python_version(),
        cpu=platform.processor() or platform.machine(),
        cores=cores(),
        threads=threads,
        xla_flags=os.environ.get("XLA_FLAGS", ""),
    )


def command_line(script: str, argv: list[str] | None) -> str:
    """The command that ran ``script`` with ``argv`` (default: this process's)."""
    args = sys.argv[1:] if argv is None else argv
    return " ".join(["python", f"scripts/{script}", *args])


def header(title: str, report: dict) -> list[str]:
    """A report's title and its paragraph on the command, machine and load."""
    env, load = report["environment"], report["load_average"]
    return [
        f"# {title}",
        "",
        f"Command: `{report['command']}`. Devices {env['devices']}, {env['cores']}"
        f" cores; threads {env['threads']} (XLA: one per core). Load average"
        f" (1, 5, 15 min) at start {load['start']}, at end {load['end']}: the"
        " machine is shared, so the times are pessimistic.",
        "",
    ]


def table(headers: Sequence[str], rows: Sequence[Sequence[object]]) -> str:
    """A Markdown table; numbers right-aligned, text left-aligned."""
    numeric = [
        all(isinstance(r[i], int | float | np.number) for r in rows)
        for i in range(len(headers))
    ]
    lines = [
        "| " + " | ".join(headers) + " |",
        "|" + "|".join("---:" if num else "---" for num in numeric) + "|",
    ]
    for r in rows:
        lines.append("| " + " | ".join(_cell(v) for v in r) + " |")
    return "\n".join(lines)


def _cell(v: object) -> str:
    if isinstance(v, float | np.floating):
        return f"{v:,.0f}" if abs(v) >= 100 else f"{v:.4g}"
    return str(v)


def write_report(out_dir: Path, stem: str, report: dict, markdown: str) -> None:
    """Write ``<stem>.json`` and ``<stem>.md`` under ``out_dir`` and print the
    Markdown."""
    write_file(Path(out_dir) / f"{stem}.json", json.dumps(report, indent=2) + "\n")
    write_file(Path(out_dir) / f"{stem}.md", markdown + "\n")
    print(markdown)


def rerender(json_path: Path, markdown) -> dict:
    """Rewrite and print the Markdown beside a JSON report, from its numbers."""
    json_path = Path(json_path)
    report = json.loads(json_path.read_text())
    write_report(json_path.parent, json_path.stem, report, markdown(report))
    return report


def parser(doc: str) -> argparse.ArgumentParser:
    """The options every benchmark takes: --root, --out, --no-progress, --render."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--root", type=Path, default=DEFAULT_DATA, help="shared data")
    ap.add_argument("--out", type=Path, default=REPO / "reports")
    ap.add_argument("--no-progress", dest="progress", action="store_false")
    ap.add_argument("--render", type=Path, default=None, help=RENDER_HELP)
    return ap


def begin(log: logging.Logger) -> tuple[dict, list[float]]:
    """Start a timed run: log to stderr, pin every pool to one thread per core,
    log the environment. Returns it and the load average at the start."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    env = environment(set_threads(cores()))
    log.info("environment %s", env)
    return env, load_average()


def run_record(script: str, argv: list[str] | None, env: dict, load_start) -> dict:
    """The fields every report opens with: command, environment, load average
    at the start (from :func:`begin`) and now."""
    return dict(
        command=command_line(script, argv),
        environment=env,
        load_average=dict(start=load_start, end=load_average()),
    )
