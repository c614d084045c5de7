"""One fit across processes: rows, reductions, and two real local processes."""

import json
import re
import subprocess

import numpy as np
import pytest

from rhythmic_jax import RhythmicMap
from rhythmic_jax.errors import InputError
from rhythmic_jax.solvers.distributed import Cluster, allreduce, row_block


def test_row_blocks_cover_every_frame_once():
    for n, k in ((10, 3), (7, 2), (2, 4), (3576, 5)):
        blocks = [row_block(n, k, i) for i in range(k)]
        rows = np.concatenate([np.arange(*b) for b in blocks])
        np.testing.assert_array_equal(rows, np.arange(n))


def test_cluster_settings_are_checked():
    with pytest.raises(InputError, match="HOST:PORT"):
        Cluster("localhost", 2, 0)
    with pytest.raises(InputError) as err:
        Cluster("localhost:1234", 2, 2)
    assert re.search("--process-id", err.value.as_flag())
    assert allreduce({"a": np.ones(3)})["a"].tolist() == [1, 1, 1]  # one process


def _fit(tmp_path, name, *extra):
    out = tmp_path / name
    cmd = ["rhythmic-jax", "fit", "ref.npy", "--out", str(out), "--no-progress",
           "--json", *extra]  # fmt: skip
    done = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-3000:]
    return RhythmicMap.load(out), json.loads(done.stdout)  # the JSON alone


@pytest.mark.slow
def test_two_local_processes_reach_the_one_process_map(tmp_path):
    """Two processes of the installed command (gloo collectives, one CPU device
    each) against one: same periods and training errors, templates to 1e-6.

    Both solve to a 1e-10 gap, so what is left is arithmetic: the gradient's
    sums over frames are float64 (in float32 their order, which the split into
    processes changes, moved the optimum by 1.3e-6)."""
    rng = np.random.default_rng(0)
    x = np.cumsum(rng.normal(size=(301, 24)), axis=0).astype(np.float32)
    np.save(tmp_path / "ref.npy", x / np.linalg.norm(x, axis=1, keepdims=True))
    one, _ = _fit(tmp_path, "one.map", "--gap", "1e-10")
    two, info = _fit(tmp_path, "two.map", "--gap", "1e-10", "--processes", "2")
    print("relative template difference",
          np.linalg.norm(np.asarray(two.params.w) - np.asarray(one.params.w))
          / np.linalg.norm(np.asarray(one.params.w)))  # fmt: skip
    assert info["fit"]["mode"] == "memory" and info["fit"]["rows"] == 151
    assert two.periods == one.periods and two.candidates == one.candidates
    np.testing.assert_allclose(two.candidate_errors, one.candidate_errors, atol=1e-6)
    w1, w2 = np.asarray(one.params.w), np.asarray(two.params.w)
    assert np.linalg.norm(w2 - w1) / np.linalg.norm(w1) < 1e-6
    b1, b2 = np.asarray(one.params.b), np.asarray(two.params.b)
    assert np.linalg.norm(b2 - b1) / np.linalg.norm(b1) < 1e-6
    # streamed over two processes (blocks of other rows, so float32 sums in
    # another order): the one-process stream's map, to the solver's accuracy
    s1, _ = _fit(tmp_path, "s1.map", "--stream")
    s2, info = _fit(tmp_path, "s2.map", "--stream", "--processes", "2")
    assert info["fit"]["mode"] == "stream" and s2.periods == s1.periods
    np.testing.assert_allclose(s2.candidate_errors, s1.candidate_errors, atol=1e-6)
    w1, w2 = np.asarray(s1.params.w), np.asarray(s2.params.w)
    assert np.linalg.norm(w2 - w1) / np.linalg.norm(w1) < 1e-3


@pytest.mark.parametrize(
    "bad, said",
    [
        ("second", r"^rhythmic-jax fit: error: x\.npy rows 30\.\.60 row 0 holds NaN"),
        ("both", r"^rhythmic-jax fit: error: reference features: values up to 253"),
    ],
)
def test_a_refusal_of_two_processes_is_one_line(tmp_path, bad, said):
    """A refusal made by one process (NaN in the second's rows; its partner
    then loses the collective it waits in) or by both (unscaled 8-bit
    features): the launcher says it once, exit status 2, no traceback, no map."""
    rng = np.random.default_rng(0)
    if bad == "second":
        x = rng.normal(size=(60, 16)).astype(np.float32)
        x[30:] = np.nan
    else:
        x = rng.integers(0, 254, (60, 16)).astype(np.float32)
    np.save(tmp_path / "x.npy", x)
    cmd = ["rhythmic-jax", "fit", "x.npy", "--out", "m.map", "--processes", "2"]
    done = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True)
    lines = done.stderr.splitlines()
    assert done.returncode == 2 and len(lines) == 1, done.stderr[-3000:]
    assert re.match(said, lines[0]) and done.stdout == ""
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.npy"]
