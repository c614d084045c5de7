"""The persistent compile cache: its switch, its checked entry format, and that a
truncated, garbled or foreign entry is recompiled (same results), never run."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from rhythmic_jax import jit_cache
from rhythmic_jax.jit_cache import (
    ENV,
    compile_cache_dir,
    enable_compile_cache,
    pack_entry,
    unpack_entry,
)


def test_entry_is_whole_and_for_its_key_or_nothing():
    value = bytes(range(256)) * 8
    data = pack_entry("jit_f-abc", value)
    assert unpack_entry("jit_f-abc", data) == value
    assert unpack_entry("jit_g-abc", data) is None  # another program's entry
    assert unpack_entry("jit_f-abc", data[:-1]) is None  # cut short
    assert unpack_entry("jit_f-abc", data[: len(jit_cache.MAGIC) + 32]) is None
    assert unpack_entry("jit_f-abc", b"") is None
    flipped = bytearray(data)
    flipped[len(data) // 2] ^= 1
    assert unpack_entry("jit_f-abc", bytes(flipped)) is None  # garbled
    assert unpack_entry("jit_f-abc", value) is None  # JAX's own format


def test_switch_and_folder(monkeypatch, tmp_path):
    import jax

    monkeypatch.setenv("RHYTHMIC_JAX_CACHE", str(tmp_path / "c"))
    monkeypatch.delenv(ENV, raising=False)
    assert compile_cache_dir() == tmp_path / "c" / "jax"
    assert compile_cache_dir(tmp_path / "x") == tmp_path / "x"
    monkeypatch.setenv(ENV, "1")
    assert compile_cache_dir() == tmp_path / "c" / "jax"
    monkeypatch.setenv(ENV, str(tmp_path / "elsewhere"))
    assert compile_cache_dir() == tmp_path / "elsewhere"
    before = jax.config.jax_compilation_cache_dir
    for off in ("0", "off", "False", "no"):
        monkeypatch.setenv(ENV, off)
        assert compile_cache_dir(tmp_path / "x") is None
        assert enable_compile_cache(tmp_path / "x") is None
    assert jax.config.jax_compilation_cache_dir == before
    assert not (tmp_path / "x").exists()


def _python(code: str, env_extra: dict | None = None) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != ENV}
    env.update(JAX_PLATFORMS="cpu", **(env_extra or {}))
    env["PYTHONPATH"] = os.pathsep.join(
        [str(Path(__file__).resolve().parents[1]), env.get("PYTHONPATH", "")]
    )
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_importing_the_library_changes_no_jax_setting():
    proc = _python(
        """
        import json, jax
        names = ["jax_compilation_cache_dir",
                 "jax_persistent_cache_min_compile_time_secs",
                 "jax_persistent_cache_min_entry_size_bytes"]
        before = [getattr(jax.config, n) for n in names]
        import rhythmic_jax as rj
        rj.RhythmicMap, rj.enable_compile_cache, rj.decode
        import rhythmic_jax.app.cli
        print(json.dumps([before, [getattr(jax.config, n) for n in names]]))
        """
    )
    assert proc.returncode == 0, proc.stderr
    before, after = json.loads(proc.stdout)
    assert before == after and before[0] is None


# Four programs of different shapes: a foreign entry run in place of the right
# one would give a wrong shape or wrong numbers.
_PROGRAMS = """
    import json, logging, sys
    import jax, jax.numpy as jnp, numpy as np
    jnp.ones(3).block_until_ready()  # compiled before the cache is on
    hits = []
    class Hits(logging.Handler):
        def emit(self, record):
            if "cache hit" in record.getMessage():
                hits.append(record.getMessage())
    logging.getLogger("jax").addHandler(Hits())
    jax.config.update("jax_log_compiles", True)
    import rhythmic_jax as rj
    folder = rj.enable_compile_cache(sys.argv[1])
    x = np.arange(30, dtype=np.float32).reshape(5, 6) / 7
    hi = jax.lax.Precision.HIGHEST
    out = [
        jax.jit(lambda a: jnp.matmul(a, a.T, precision=hi))(x),
        jax.jit(lambda a: jnp.sum(a, 0))(x[:4, :2]),
        jax.jit(lambda a: jnp.sin(a) * 2 + 1)(x[0]),
        jax.jit(lambda a: jnp.cumsum(a[::-1]))(x[1]),
    ]
    print(json.dumps(dict(folder=str(folder), hits=len(hits),
                          out=[np.asarray(o).tolist() for o in out])))
"""


def _run_programs(folder: Path) -> dict:
    proc = _python(_PROGRAMS.replace("sys.argv[1]", repr(str(folder))))
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    return json.loads(proc.stdout.splitlines()[-1])


def test_damaged_and_foreign_entries_are_recompiled_with_the_same_results(tmp_path):
    folder = tmp_path / "jax"
    cold = _run_programs(folder)
    assert cold["hits"] == 0 and cold["folder"] == str(folder)
    entries = sorted(folder.glob("*-cache"))
    assert len(entries) >= 4
    assert not list(folder.glob(".*.tmp"))  # written through a temporary file
    warm = _run_programs(folder)
    assert warm["out"] == cold["out"] and warm["hits"] == len(entries)

    data = {e: e.read_bytes() for e in entries}
    a, b, c, d = entries[:4]
    a.write_bytes(data[a][: len(data[a]) // 2])  # a writer killed mid-entry
    b.write_bytes(data[c])  # another program's whole entry under b's key
    c.write_bytes(data[c][jit_cache.MAGIC.__len__() + 32 :])  # JAX's plain format
    d.write_bytes(b"")
    damaged = _run_programs(folder)
    assert damaged["out"] == cold["out"]
    assert damaged["hits"] == len(entries) - 4
    for e in (a, b, c, d):  # written anew, whole
        assert unpack_entry(e.name.removesuffix("-cache"), e.read_bytes())
    again = _run_programs(folder)
    assert again["out"] == cold["out"] and again["hits"] == len(entries)


def test_conftest_turns_the_cache_on_for_the_suite():
    import jax

    if compile_cache_dir() is None:
        pytest.skip(f"{ENV} switches the compile cache off")
    assert jax.config.jax_compilation_cache_dir == os.environ[ENV]
    assert Path(os.environ[ENV]).is_dir()
