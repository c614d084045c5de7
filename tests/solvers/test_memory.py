"""The memory estimate of a full-batch fit against measured peaks, and its guard."""

from __future__ import annotations

import os

import numpy as np
import pytest

from rhythmic_jax.errors import InputError
from rhythmic_jax.periods import candidate_periods
from rhythmic_jax.solvers.memory import available_memory, check_memory, fit_bytes


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


MEASURE = """
import gc, sys, threading, time
import os

import numpy as np
from rhythmic_jax import RhythmicMap

n, d = int(sys.argv[1]), int(sys.argv[2])
rng = np.random.default_rng(0)
RhythmicMap().fit(rng.normal(size=(n, d)).astype(np.float32), progress=False)
x = rng.normal(size=(n, d)).astype(np.float32)
gc.collect()

def rss():
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * 4096

base, peak, done = rss(), [0], []

def watch():
    while not done:
        peak[0] = max(peak[0], rss())
        time.sleep(0.002)

t = threading.Thread(target=watch)
t.start()
RhythmicMap().fit(x, progress=False)  # compiled already: the solver's own memory
done.append(1)
t.join()
print(peak[0] - base + x.nbytes)
"""


@pytest.mark.slow
@pytest.mark.parametrize("n, d", [(3000, 128), (400, 1024)])  # tall; wide: span
def test_memory_estimate_bounds_a_measured_fit(n, d):
    import subprocess
    import sys

    out = subprocess.run(
        [sys.executable, "-c", MEASURE, str(n), str(d)],
        capture_output=True,
        text=True,
        check=True,
    )
    measured = int(out.stdout.split()[-1])
    estimate = sum(fit_bytes(n, d, sum(candidate_periods(n))).values())
    # an upper estimate (0.9: measurement noise), and not a wild one: the growth
    # measured after a warm-up fit undercounts buffers the allocator kept from
    # it, most on small problems (400 x 1024: 9.6 MB measured, 34.6 MB estimated)
    assert 0.9 * measured <= estimate <= 5 * measured, (measured, estimate)


@pytest.mark.parametrize("n, d", [(1000, 64), (400, 1024)])  # tall; wide: span
def test_memory_estimate_bounds_the_compiled_newton_step(n, d):
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
    assert 4 * parts["allocator"] <= sum(parts.values()) - parts["allocator"]
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
