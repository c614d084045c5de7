"""learn -> fit -> query -> evaluate through the installed command, elsewhere."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
from test_embedding import two_conditions


def _cli(*argv, cwd, env):
    script = shutil.which("rhythmic-jax")
    cmd = [script] if script else [sys.executable, "-m", "rhythmic_jax.cli"]
    proc = subprocess.run(
        [*cmd, *argv], cwd=cwd, env=env, capture_output=True, text=True, timeout=600
    )
    assert proc.returncode == 0, proc.stderr
    return proc.stdout


@pytest.mark.slow
def test_learn_fit_query_evaluate_from_another_directory(tmp_path):
    data, work = tmp_path / "data", tmp_path / "elsewhere"
    data.mkdir()
    work.mkdir()
    a, b = two_conditions(n=400, strength=4.0, seed=5)
    for name, x in (("a_train", a[:180]), ("b_train", b[:180]),
                    ("a_test", a[200:]), ("b_test", b[200:])):  # fmt: skip
        np.save(data / f"{name}.npy", x)
    env = {**os.environ, "RHYTHMIC_JAX_CACHE": str(tmp_path / "cache")}
    out = _cli("learn", str(data / "a_train.npy"), str(data / "b_train.npy"),
               "--out", "route.emb", "--k", "40", "--no-progress",
               cwd=work, env=env)  # fmt: skip
    assert "linear 48 -> 40" in out
    _cli("fit", str(data / "a_test.npy"), "--embedding", "route.emb",
         "--out", "route.map", "--no-progress", cwd=work, env=env)  # fmt: skip
    _cli("fit", str(data / "a_test.npy"), "--out", "plain.map", "--no-progress",
         cwd=work, env=env)  # fmt: skip
    info = json.loads(_cli("info", "route.map", "--json", cwd=work, env=env))
    assert info["embedding"] == {"kind": "linear", "k": 40} and info["d"] == 48
    assert info["embedding_bytes"] == 4 * (48 + 48 * 40)
    text = _cli("info", "route.map", cwd=work, env=env)
    assert "embedding_bytes" in text
    _cli("query", "route.map", str(data / "b_test.npy"), "--decode", "soft",
         "--out", "pred.npy", "--no-progress", cwd=work, env=env)  # fmt: skip
    pred = np.load(work / "pred.npy")
    _cli("query", "plain.map", str(data / "b_test.npy"), "--decode", "soft",
         "--out", "plain.npy", "--no-progress", cwd=work, env=env)  # fmt: skip
    plain = np.load(work / "plain.npy")
    gt = np.arange(200)
    assert np.mean(pred == gt) > np.mean(plain == gt) + 0.1
    ev = json.loads(_cli("evaluate", "route.map", str(data / "b_test.npy"),
                         "--decode", "soft", "--json", "--no-progress",
                         cwd=work, env=env))  # fmt: skip
    assert ev["methods"]["map"]["accuracy"] == np.mean(pred == gt)
    assert ev["methods"]["map"]["embedding_bytes"] == info["embedding_bytes"]
