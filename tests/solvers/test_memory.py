"""The memory estimate of a full-batch fit against measured peaks, and its guard."""

from __future__ import annotations

import os

import numpy as np
import pytest

from rhythmic_jax.errors import InputError
from rhythmic_jax.map.periods import candidate_periods
from rhythmic_jax.solvers.memory import (
    COMPILE_BYTES,
    SCRATCH_BYTES,
    available_memory,
    check_memory,
    fit_bytes,
)


def test_memory_guard_refuses_with_the_bytes_needed():
    n, d, p = 7403, 4096, 7 * 90
    need = sum(fit_bytes(n, d, p).values())
    assert fit_bytes(n, d, p)["features"] == n * d * 4
    assert check_memory(n, d, p, limit_bytes=need) == need
    with pytest.raises(InputError) as err:
        check_memory(n, d, p, limit_bytes=need - 1)
    message = str(err.value)
    assert f"needs about {need:,} bytes" in message
    assert f"but {need - 1:,} bytes" in message
    assert "memmap_batches(" in message and "train_run" in message
    assert "\n" not in message


def test_memory_guard_uses_the_machine_by_default():
    avail = available_memory()
    total = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    assert 0 < avail <= total
    assert check_memory(100, 64, 70) < avail  # a small fit passes
    with pytest.raises(InputError, match="stream the frames instead"):
        check_memory(10**7, 4096, 700)  # 160 GB of features alone


def test_memory_estimate_grows_with_every_size():
    base = sum(fit_bytes(1000, 100, 70).values())
    for n, d, p in [(2000, 100, 70), (1000, 200, 70), (1000, 100, 140)]:
        assert sum(fit_bytes(n, d, p).values()) > base
    assert fit_bytes(1000, 100, 70, itemsize=8)["features"] == 8 * 10**5


# Peak growth of a process's resident memory during fits, with glibc's freed
# memory handed back (malloc_trim) before each baseline: without it the allocator
# serves a fit from what the previous one freed and the growth undercounts. A fit
# of another shape first loads the runtime; then each (n, d) is fitted once
# "cold" (compiling its functions; with "warm" instead of "cold", unmeasured,
# without the other shape's fit, and loaded from the suite's compile cache when
# it is on), then once more unmeasured and `repeats` times
# "warm" on the same frames (the same column counts: nothing compiles). Prints
# one JSON line per shape.
MEASURE = """
import json, sys
import numpy as np
from rhythmic_jax import RhythmicMap
from rhythmic_jax.solvers.memory import peak_growth as grows

def peak_growth(x):
    return grows(lambda: RhythmicMap().fit(x, progress=False)) + x.nbytes

rng = np.random.default_rng(0)
repeats, cold_too = int(sys.argv[1]), sys.argv[2] == "cold"
if cold_too:
    RhythmicMap().fit(rng.normal(size=(48, 8)).astype(np.float32), progress=False)
else:  # no fit compiles while measured: the suite's cache serves them
    from rhythmic_jax.jit_cache import enable_compile_cache

    enable_compile_cache()
for shape in sys.argv[3:]:
    n, d = map(int, shape.split("x"))
    x = rng.normal(size=(n, d)).astype(np.float32)
    cold = None
    if cold_too:
        cold = peak_growth(x)
    else:
        RhythmicMap().fit(x, progress=False)  # compiles
    RhythmicMap().fit(x, progress=False)  # the first run of compiled code
    warm = [peak_growth(x) for _ in range(repeats)]
    print(json.dumps(dict(n=n, d=d, cold=cold, warm=warm)), flush=True)
"""


def _measure(shapes, repeats, cold=True):
    import json
    import subprocess
    import sys

    out = subprocess.run(
        [sys.executable, "-c", MEASURE, str(repeats), "cold" if cold else "warm"]
        + [f"{n}x{d}" for n, d in shapes],
        capture_output=True,
        text=True,
        check=True,
    )
    return [json.loads(line) for line in out.stdout.splitlines() if line[:1] == "{"]


def _check_bounds(run, warm_ratio=5.0):
    """A first fit of a shape (when measured) within [0.9, 2] x the whole
    estimate, every fit of a compiled shape within [0.9, ``warm_ratio``] x the
    estimate without ``compile`` (0.9: the sampling's noise)."""
    n, d = run["n"], run["d"]
    parts = fit_bytes(n, d, sum(candidate_periods(n)))
    whole = sum(parts.values())
    arrays = whole - parts["compile"]
    if run["cold"] is not None:
        assert 0.9 * run["cold"] <= whole <= 2 * run["cold"], (n, d, run, whole)
    for warm in run["warm"]:
        assert 0.9 * warm <= arrays <= warm_ratio * warm, (n, d, run, arrays)


@pytest.mark.slow
def test_memory_estimate_bounds_a_measured_fit():
    """Tall (3000 x 128) and wide (400 x 1024: solved in the span) fits."""
    runs = _measure([(3000, 128), (400, 1024)], repeats=2)
    assert [(r["n"], r["d"]) for r in runs] == [(3000, 128), (400, 1024)]
    for run in runs:
        _check_bounds(run)


@pytest.mark.slow
def test_memory_estimate_holds_twenty_fits_in_a_row():
    """The estimate holds every one of 20 fits of two small compiled shapes,
    tall and wide, in one process (the allocator trimmed before each). Their
    steps last about a millisecond, so the sampled peaks run from 3 to 15 MB
    (800 x 48, 28.8 MB estimated): no ratio is asserted for them."""
    runs = _measure([(800, 48), (120, 512)], repeats=20, cold=False)
    assert [len(r["warm"]) for r in runs] == [20, 20]
    for run in runs:
        _check_bounds(run, warm_ratio=float("inf"))


@pytest.fixture
def on_the_cpu():
    """The estimate is of a CPU fit's host memory: the step compiles for the CPU,
    on a GPU machine too."""
    import jax

    try:
        cpu = jax.devices("cpu")[0]
    except RuntimeError:
        pytest.skip("no CPU backend: the estimate is of a CPU fit's host memory")
    with jax.default_device(cpu):
        yield cpu


@pytest.mark.parametrize("n, d", [(1000, 64), (400, 1024)])  # tall; wide: span
def test_memory_estimate_bounds_the_compiled_newton_step(n, d, on_the_cpu):
    """The step's arrays (design, system, templates) hold XLA's own count of a
    Newton step's arguments, results and temporaries, whole or compacted."""
    import jax
    import jax.numpy as jnp

    from rhythmic_jax.solvers import newton
    from rhythmic_jax.solvers.newton_cg import Iterate, newton_solver
    from rhythmic_jax.solvers.precondition import spectral_setup

    config = newton.NewtonConfig()
    p = sum(candidate_periods(n))
    parts = fit_bytes(n, d, p)
    arrays = parts["design"] + parts["system"] + parts["templates"]
    assert parts["compile"] == COMPILE_BYTES
    rest = sum(parts.values()) - parts["allocator"] - COMPILE_BYTES
    assert 4 * (parts["allocator"] - SCRATCH_BYTES) <= rest
    q = min(n, d) + 1  # wide frames are solved in their (n, n) span
    rng = np.random.default_rng(0)
    xa = newton._design(
        jnp.asarray(rng.normal(size=(n, q - 1)), jnp.float32), jnp.ones(n, jnp.float32)
    )
    spectral = spectral_setup(
        xa, min(config.rank, q), config.power_iters, jax.random.PRNGKey(0)
    )
    with jax.enable_x64(True):
        params = Iterate(jnp.zeros((q, p)), jnp.zeros((n, p)))
        state = newton_solver(config.eta, config.max_cg, config.block).init(params)
        for cols in (None, jnp.arange(p // 2)):
            stats = newton._newton_step.lower(
                xa, spectral, cols, params, state, jnp.ones((n, p)),
                jnp.float64(1.0), config.eta, config.block, jnp.int32(10),
                config.exact_gradient,
            ).compile().memory_analysis()  # fmt: skip
            held = (
                stats.argument_size_in_bytes
                + stats.output_size_in_bytes
                + stats.temp_size_in_bytes
            )
            assert held <= arrays <= 2 * held, (cols is None, held, arrays)
