"""XLA programs of a default ``RhythmicMap.fit`` and its predictions, in a fresh
process (``bench_compile.py``'s library job).

python scripts/count_compiles.py                      # this checkout, cold
python scripts/count_compiles.py --checkout /work/main --names
python scripts/count_compiles.py --n 600 --d 64 --cache /tmp/jax
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np
from _harness import REPO, child, command, job_env, main
from bench_compile import job


def walk(n: int, d: int, seed: int) -> np.ndarray:
    """(n, d) float32 unit rows of an AR(1) walk (coefficient 0.9)."""
    rng = np.random.default_rng(seed)
    walk = rng.standard_normal((n, d)).astype(np.float32)
    for i in range(1, len(walk)):
        walk[i] += 0.9 * walk[i - 1]
    return walk / np.linalg.norm(walk, axis=1, keepdims=True)


def options(ap) -> None:
    ap.set_defaults(out=None)  # printed only, unless --out is given
    ap.add_argument("--checkout", type=Path, default=REPO)
    ap.add_argument("--n", type=int, default=1000)
    ap.add_argument("--d", type=int, default=256)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--npy", help="frames (n, d) to fit instead of a random walk")
    ap.add_argument("--names", action="store_true", help="programs by name")
    ap.add_argument("--cache", help="persistent compile cache folder (default: none)")


def run(args) -> dict:
    """One fit in a fresh process against ``--checkout``: its JSON record."""
    env = job_env(args.cache or "0")
    with tempfile.TemporaryDirectory() as tmp:
        x, out = args.npy or Path(tmp) / "x.npy", Path(tmp) / "count.json"
        if not args.npy:
            np.save(x, walk(args.n, args.d, args.seed))
        cmd = command(job, str(out), "library", str(x), str(Path(tmp) / "pred.npy"))
        r = child(cmd, args.checkout, "/", env=env)
        count = json.loads(out.read_text())
    record = dict(
        programs=count["programs"], hits=count["hits"], wall_s=round(r["wall"], 3),
        compile_s=round(count["compile_s"] + count["trace_s"], 3),
        cpu_s=round(r["cpu"], 3), load=r["load"], checkout=str(args.checkout),
    )  # fmt: skip
    record |= json.loads(r["stdout"].splitlines()[-1])  # the periods
    if args.names:
        record["names"] = count["names"]
    return dict(record=record)


def markdown(report: dict) -> str:
    """The record as one JSON line (what callers parse), after the command."""
    return f"# {report['command']}\n{json.dumps(report['record'])}"


if __name__ == "__main__":
    main(__doc__, run, markdown, options, stem="compiles")
