"""The memory estimate of a full-batch fit against measured peaks, and its guard."""

from __future__ import annotations

import os

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
    # it, most on small problems (400 x 1024: 9.6 MB measured, 27.7 MB estimated)
    assert 0.9 * measured <= estimate <= 4 * measured, (measured, estimate)
