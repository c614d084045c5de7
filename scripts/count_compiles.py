"""XLA programs a default ``RhythmicMap.fit`` compiles, in a fresh process.

A child process (``PYTHONPATH`` = the checkout measured, JAX on the CPU, no
persistent compilation cache unless ``--cache DIR``) imports the package, builds
route-like frames (a random walk of unit descriptors: neighbours alike, as
frames along a route are), fits ``RhythmicMap()`` on them and prints one JSON
line:

- ``programs``: XLA programs compiled during the fit (JAX's
  ``/jax/core/compile/backend_compile_duration`` events, one per program, the
  same count as ``jax_log_compiles``' "Finished XLA compilation" lines);
- ``compile_s``: seconds of those compilations, tracing and lowering included;
- ``wall_s``: seconds of the fit call (``cpu_s``: the process's CPU seconds,
  every thread, less sensitive to other processes' load); ``import_s``: of
  ``import rhythmic_jax``;
- ``again_s``, ``again_cpu_s``: a second fit of the same frames in the same
  process; ``load``: the 1-minute load average at the end;
- ``periods``, ``objective`` (the chosen templates' objective sum), ``names``
  (``--names``: programs compiled, by name, most first).

With ``--npy FILE`` the frames are read from a .npy file instead.

    python scripts/count_compiles.py                      # this checkout
    python scripts/count_compiles.py --checkout /work/main --names
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

CHILD = r"""
import collections, json, logging, sys, time
args = json.loads(sys.argv[1])
t0 = time.perf_counter()
import jax
import numpy as np
if args["cache"]:
    jax.config.update("jax_compilation_cache_dir", args["cache"])
else:  # cold: whatever the environment says
    jax.config.update("jax_enable_compilation_cache", False)
programs, seconds, names = [0], [0.0], collections.Counter()
EVENTS = ("/jax/core/compile/jaxpr_trace_duration",
          "/jax/core/compile/jaxpr_to_mlir_module_duration",
          "/jax/core/compile/backend_compile_duration")
def listen(event, duration, **kw):
    if event in EVENTS:
        seconds[0] += duration
    if event == EVENTS[2]:
        programs[0] += 1
jax.monitoring.register_event_duration_secs_listener(listen)
class Names(logging.Handler):
    def emit(self, record):
        msg = record.getMessage()
        if msg.startswith("Finished XLA compilation of "):
            names[msg.split(" ")[4]] += 1
if args["names"]:
    jax.config.update("jax_log_compiles", True)
    handler = Names()
    for name in ("jax._src.dispatch", "jax._src.interpreters.pxla"):
        logging.getLogger(name).addHandler(handler)
        logging.getLogger(name).propagate = False
import rhythmic_jax as rj
import_s = time.perf_counter() - t0
if args["npy"]:
    x = np.load(args["npy"]).astype(np.float32)
else:
    rng = np.random.default_rng(args["seed"])
    step = rng.standard_normal((args["n"], args["d"])).astype(np.float32)
    walk = np.empty_like(step)
    walk[0] = step[0]
    for i in range(1, len(step)):
        walk[i] = 0.9 * walk[i - 1] + step[i]
    x = walk / np.linalg.norm(walk, axis=1, keepdims=True)
base = programs[0], seconds[0]
t, cpu = time.perf_counter(), time.process_time()
m = rj.RhythmicMap().fit(x)
wall, cpu = time.perf_counter() - t, time.process_time() - cpu
out = dict(programs=programs[0] - base[0], compile_s=round(seconds[0] - base[1], 3),
           wall_s=round(wall, 3), cpu_s=round(cpu, 3), import_s=round(import_s, 3))
t, cpu = time.perf_counter(), time.process_time()
rj.RhythmicMap().fit(x)
out["again_s"] = round(time.perf_counter() - t, 3)
out["again_cpu_s"] = round(time.process_time() - cpu, 3)
import os
out["load"] = round(os.getloadavg()[0], 2)
out["periods"] = list(m.periods)
out["n"], out["d"] = [int(v) for v in x.shape]
if args["names"]:
    out["names"] = dict(names.most_common())
print("RESULT " + json.dumps(out))
"""


def measure(
    checkout: Path = REPO,
    n: int = 1000,
    d: int = 256,
    seed: int = 0,
    npy: str | None = None,
    names: bool = False,
    cache: str | None = None,
) -> dict:
    """Run one fit in a fresh process against ``checkout``; its JSON record."""
    env = dict(os.environ, PYTHONPATH=str(checkout), TF_CPP_MIN_LOG_LEVEL="3")
    env.setdefault("JAX_PLATFORMS", "cpu")
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    args = dict(n=n, d=d, seed=seed, npy=npy, names=names, cache=cache)
    proc = subprocess.run(
        [sys.executable, "-c", CHILD, json.dumps(args)],
        env=env,
        capture_output=True,
        text=True,
        check=False,
        cwd="/",
    )
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    if proc.returncode or not lines:
        tail = proc.stderr[-3000:]
        raise RuntimeError(f"the fit failed ({proc.returncode}):\n{tail}")
    out = json.loads(lines[-1][len("RESULT ") :])
    out["checkout"] = str(checkout)
    return out


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--checkout", type=Path, default=REPO)
    ap.add_argument("--n", type=int, default=1000)
    ap.add_argument("--d", type=int, default=256)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--npy", help="frames (n, d) to fit instead of a random walk")
    ap.add_argument("--names", action="store_true", help="programs by name")
    ap.add_argument("--cache", help="JAX's persistent compilation cache folder")
    args = ap.parse_args(argv)
    out = measure(
        args.checkout, args.n, args.d, args.seed, args.npy, args.names, args.cache
    )
    print(json.dumps(out))
    return out


if __name__ == "__main__":
    main()
