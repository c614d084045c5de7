"""XLA programs and optax calls of a default ``RhythmicMap.fit`` in a fresh process.

python scripts/count_compiles.py                      # this checkout
python scripts/count_compiles.py --checkout /work/main --names
python scripts/count_compiles.py --n 600 --d 64 --optax
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

from _harness import REPO, child, main

# One fit (and a second, warm) in a fresh process, its XLA programs counted by the
# harness's compile counter; prints "RESULT {json}".
CHILD = r"""
import collections, functools, json, os, sys, time
args = json.loads(sys.argv[1])
t0 = time.perf_counter()
sys.path.insert(0, args["scripts"])
import jax
import numpy as np
count = __import__("_harness").compile_counter()
if args["cache"]:
    jax.config.update("jax_compilation_cache_dir", args["cache"])
else:  # cold: whatever the environment says
    jax.config.update("jax_enable_compilation_cache", False)
calls = collections.Counter()
if args["optax"]:
    import optax
    def wrap(module, prefix):
        for name in dir(module):
            f = getattr(module, name)
            if name.startswith("_") or not callable(f) or isinstance(f, type):
                continue
            def counted(*a, _f=f, _n=f"{prefix}.{name}", **kw):
                calls[_n] += 1
                return _f(*a, **kw)
            setattr(module, name, functools.wraps(f)(counted))
    wrap(optax, "optax")
    wrap(optax.tree_utils, "optax.tree_utils")
import rhythmic_jax as rj
import_s = time.perf_counter() - t0
if args["npy"]:
    x = np.load(args["npy"]).astype(np.float32)
else:
    rng = np.random.default_rng(args["seed"])
    walk = rng.standard_normal((args["n"], args["d"])).astype(np.float32)
    for i in range(1, len(walk)):
        walk[i] += 0.9 * walk[i - 1]
    x = walk / np.linalg.norm(walk, axis=1, keepdims=True)
seconds = lambda: count["compile_s"] + count["trace_s"]
base = count["programs"], seconds()
t, cpu = time.perf_counter(), time.process_time()
m = rj.RhythmicMap().fit(x)
wall, cpu = time.perf_counter() - t, time.process_time() - cpu
out = dict(programs=count["programs"] - base[0],
           compile_s=round(seconds() - base[1], 3), wall_s=round(wall, 3),
           cpu_s=round(cpu, 3), import_s=round(import_s, 3))
if args["optax"]:
    out["optax_calls"] = sum(calls.values())
    out["optax_by_name"] = dict(calls.most_common())
    out["solver"] = m.config.solver
t, cpu = time.perf_counter(), time.process_time()
rj.RhythmicMap().fit(x)
out["again_s"] = round(time.perf_counter() - t, 3)
out["again_cpu_s"] = round(time.process_time() - cpu, 3)
out["load"] = round(os.getloadavg()[0], 2)
out["periods"] = list(m.periods)
out["n"], out["d"] = [int(v) for v in x.shape]
out["package"] = rj.__file__
if args["names"]:
    out["names"] = dict(count["names"].most_common())
print("RESULT " + json.dumps(out))
"""


def measure(checkout: Path = REPO, n=1000, d=256, seed=0, npy=None, names=False,
            cache=None, optax=False) -> dict:  # fmt: skip
    """Run one fit in a fresh process against ``checkout``; its JSON record."""
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    args = dict(n=n, d=d, seed=seed, npy=npy, names=names, cache=cache, optax=optax)
    args["scripts"] = str(Path(__file__).parent)
    cmd = [sys.executable, "-c", CHILD, json.dumps(args)]
    proc = child(cmd, checkout, "/", check=False, env=env)
    lines = [ln for ln in proc["stdout"].splitlines() if ln.startswith("RESULT ")]
    if proc["rc"] or not lines:
        raise RuntimeError(f"the fit failed ({proc['rc']}):\n{proc['stderr'][-3000:]}")
    return json.loads(lines[-1][len("RESULT ") :]) | dict(checkout=str(checkout))


def options(ap) -> None:
    ap.set_defaults(out=None)  # printed only, unless --out is given
    ap.add_argument("--checkout", type=Path, default=REPO)
    ap.add_argument("--n", type=int, default=1000)
    ap.add_argument("--d", type=int, default=256)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--npy", help="frames (n, d) to fit instead of a random walk")
    ap.add_argument("--names", action="store_true", help="programs by name")
    ap.add_argument("--optax", action="store_true", help="count optax calls too")
    ap.add_argument("--cache", help="JAX's persistent compilation cache folder")


def run(args) -> dict:
    return dict(record=measure(args.checkout, args.n, args.d, args.seed, args.npy,
                               args.names, args.cache, args.optax))  # fmt: skip


def markdown(report: dict) -> str:
    """The record as one JSON line (what callers parse), after the command."""
    return f"# {report['command']}\n{json.dumps(report['record'])}"


if __name__ == "__main__":
    main(__doc__, run, markdown, options, stem="compiles")
