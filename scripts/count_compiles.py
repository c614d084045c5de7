"""XLA programs and optax calls of a default ``RhythmicMap.fit`` in a fresh process.

python scripts/count_compiles.py                      # this checkout
python scripts/count_compiles.py --checkout /work/main --names
python scripts/count_compiles.py --n 600 --d 64 --optax
"""

from __future__ import annotations

import collections
import functools
import json
import os
import time
from pathlib import Path

from _harness import REPO, call, compile_counter, main


def counted_calls(module, prefix: str, calls: collections.Counter) -> None:
    """Count every call of ``module``'s public functions in ``calls``."""
    for name in dir(module):
        f = getattr(module, name)
        if name.startswith("_") or not callable(f) or isinstance(f, type):
            continue

        def counted(*a, _f=f, _n=f"{prefix}.{name}", **kw):
            calls[_n] += 1
            return _f(*a, **kw)

        setattr(module, name, functools.wraps(f)(counted))


def fit(args: dict) -> dict:
    """The fresh process: one fit (and a second, warm) with its XLA programs counted
    by the harness's counter; optax's calls counted when asked."""
    t0 = time.perf_counter()
    import jax
    import numpy as np

    count = compile_counter()
    if args["cache"]:
        jax.config.update("jax_compilation_cache_dir", args["cache"])
    else:  # cold: whatever the environment says
        jax.config.update("jax_enable_compilation_cache", False)
    calls = collections.Counter()
    if args["optax"]:  # before the library imports optax's functions
        import optax

        counted_calls(optax, "optax", calls)
        counted_calls(optax.tree_utils, "optax.tree_utils", calls)
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
    base = count["programs"], count["compile_s"] + count["trace_s"]
    t, cpu = time.perf_counter(), time.process_time()
    m = rj.RhythmicMap().fit(x)
    wall, cpu = time.perf_counter() - t, time.process_time() - cpu
    seconds = count["compile_s"] + count["trace_s"] - base[1]
    out = dict(programs=count["programs"] - base[0], compile_s=round(seconds, 3),
               wall_s=round(wall, 3), cpu_s=round(cpu, 3),
               import_s=round(import_s, 3))  # fmt: skip
    if args["optax"]:
        out.update(optax_calls=sum(calls.values()), solver=m.config.solver,
                   optax_by_name=dict(calls.most_common()))  # fmt: skip
    t, cpu = time.perf_counter(), time.process_time()
    rj.RhythmicMap().fit(x)
    out["again_s"] = round(time.perf_counter() - t, 3)
    out["again_cpu_s"] = round(time.process_time() - cpu, 3)
    out.update(load=round(os.getloadavg()[0], 2), periods=list(m.periods),
               n=int(x.shape[0]), d=int(x.shape[1]), package=rj.__file__)  # fmt: skip
    if args["names"]:
        out["names"] = dict(count["names"].most_common())
    return out


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
    """One fit in a fresh process against ``--checkout``: its JSON record."""
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    keys = ("n", "d", "seed", "npy", "names", "cache", "optax")
    proc = call(fit, {k: getattr(args, k) for k in keys}, checkout=args.checkout,
                cwd="/", check=False, env=env)  # fmt: skip
    if proc["result"] is None:
        raise RuntimeError(f"the fit failed ({proc['rc']}):\n{proc['stderr'][-3000:]}")
    return dict(record=proc["result"] | dict(checkout=str(args.checkout)))


def markdown(report: dict) -> str:
    """The record as one JSON line (what callers parse), after the command."""
    return f"# {report['command']}\n{json.dumps(report['record'])}"


if __name__ == "__main__":
    main(__doc__, run, markdown, options, stem="compiles")
