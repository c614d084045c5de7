"""Compile options by backend: the GPU set on a GPU, nothing on the CPU, every
jitted program of the package made through the one wrapper."""

from __future__ import annotations

import ast
import functools
import logging
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from rhythmic_jax import jit_options
from rhythmic_jax.errors import InputError
from rhythmic_jax.jit_options import GPU_OPTIONS, compiler_options, describe, jit

PACKAGE = Path(__file__).resolve().parents[1] / "rhythmic_jax"


@pytest.fixture(autouse=True)
def _clean(monkeypatch):
    """Each test starts with no override, no XLA_FLAGS and nothing refused."""
    monkeypatch.delenv(jit_options.ENV, raising=False)
    monkeypatch.delenv("XLA_FLAGS", raising=False)
    monkeypatch.setattr(jit_options, "_override", None)
    monkeypatch.setattr(jit_options, "_rejected", set())


@pytest.mark.parametrize("platform", ["gpu", "cuda", "rocm", "GPU"])
def test_a_gpu_gets_the_triton_gemm_and_fusion_autotuner_off(platform):
    assert compiler_options(platform) == {
        "xla_gpu_enable_triton_gemm": False,
        "xla_gpu_experimental_enable_fusion_autotuner": False,
    }


@pytest.mark.parametrize("platform", ["cpu", "tpu"])
def test_other_backends_get_no_option(platform):
    assert compiler_options(platform) == {}


def test_this_machine_s_backend_decides():
    expected = GPU_OPTIONS if jax.default_backend() == "gpu" else {}
    assert compiler_options() == expected
    try:
        cpu = jax.devices("cpu")[0]
    except RuntimeError:
        return  # JAX_PLATFORMS=cuda: no CPU backend to ask about
    with jax.default_device(cpu):
        assert compiler_options() == {}


@pytest.mark.parametrize("value", ["1", "on", "TRUE", " yes "])
def test_the_environment_keeps_xla_s_autotuner(monkeypatch, value):
    monkeypatch.setenv(jit_options.ENV, value)
    assert compiler_options("gpu") == {}
    assert "autotuner kept" in describe()


@pytest.mark.parametrize("value", ["0", "off", "", "no"])
def test_the_environment_can_say_skip_it(monkeypatch, value):
    monkeypatch.setenv(jit_options.ENV, value)
    assert compiler_options("gpu") == GPU_OPTIONS


def test_a_bad_environment_value_is_one_line(monkeypatch):
    monkeypatch.setenv(jit_options.ENV, "maybe")
    with pytest.raises(InputError, match="RHYTHMIC_JAX_GPU_AUTOTUNE='maybe'"):
        compiler_options("gpu")


def test_the_function_overrides_the_environment(monkeypatch):
    monkeypatch.setenv(jit_options.ENV, "1")
    jit_options.set_gpu_autotune(False)
    assert compiler_options("gpu") == GPU_OPTIONS
    jit_options.set_gpu_autotune(True)
    monkeypatch.setenv(jit_options.ENV, "0")
    assert compiler_options("gpu") == {}
    jit_options.set_gpu_autotune(None)
    assert compiler_options("gpu") == GPU_OPTIONS
    with pytest.raises(InputError, match="gpu_autotune"):
        jit_options.set_gpu_autotune("yes")


def test_the_user_s_xla_flags_win(monkeypatch):
    monkeypatch.setenv("XLA_FLAGS", "--xla_gpu_enable_triton_gemm=true --xla_dump_hlo")
    assert compiler_options("gpu") == {
        "xla_gpu_experimental_enable_fusion_autotuner": False
    }


def test_describe_states_the_setting_without_a_backend():
    line = describe()
    assert "xla_gpu_enable_triton_gemm=false" in line
    assert "other backends: XLA defaults" in line
    assert describe("cpu") == "cpu: XLA defaults"


def _jit_sites(path: Path) -> list[str]:
    """Every use of ``jax.jit`` (an attribute ``jit`` of the name ``jax``) or a
    ``jit`` imported from jax in ``path``."""
    tree = ast.parse(path.read_text())
    found = []
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Attribute)
            and node.attr in ("jit", "pjit", "pmap")
            and isinstance(node.value, ast.Name)
            and node.value.id == "jax"
        ):
            found.append(f"{path.name}:{node.lineno} jax.{node.attr}")
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("jax"):
            names = [a.name for a in node.names if a.name in ("jit", "pjit", "pmap")]
            found += [f"{path.name}:{node.lineno} from jax import {n}" for n in names]
    return found


def test_every_jitted_program_of_the_package_goes_through_the_wrapper():
    files = [p for p in PACKAGE.rglob("*.py") if p.name != "jit_options.py"]
    bare = [site for p in files for site in _jit_sites(p)]
    assert bare == []
    users = [p for p in files if "from rhythmic_jax.jit_options import jit" in (
        p.read_text())]  # fmt: skip
    assert len(users) >= 20  # the solvers, decoders, codes, projections, SeqSLAM


def test_the_scan_finds_a_bare_jit(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text("import jax\nf = jax.jit(abs)\nfrom jax import jit\n")
    found = sorted(_jit_sites(bad))
    assert found == ["bad.py:2 jax.jit", "bad.py:3 from jax import jit"]


def _product(a, b):
    return jnp.matmul(a, b, precision=jax.lax.Precision.HIGHEST).sum(axis=0)


def test_the_wrapper_compiles_and_equals_jax_jit_on_this_machine():
    a = np.random.default_rng(0).normal(size=(64, 32)).astype(np.float32)
    mine = jit(_product)(a, a.T)
    np.testing.assert_array_equal(mine, jax.jit(_product)(a, a.T))
    reference = (a.astype(np.float64) @ a.T.astype(np.float64)).sum(axis=0)
    np.testing.assert_allclose(mine, reference, rtol=1e-5, atol=1e-4)


def test_gpu_options_reach_xla_when_the_backend_is_a_gpu(monkeypatch, tmp_path):
    """With the platform reported as a GPU, a library program compiles with the GPU
    set plus one option whose effect shows on the CPU (a dump of the program), and
    its result is the CPU's without options."""
    from rhythmic_jax.decoding.hard import hard_decode

    monkeypatch.setattr(jit_options, "_platform", lambda: "gpu")
    monkeypatch.setattr(
        jit_options, "GPU_OPTIONS", GPU_OPTIONS | {"xla_dump_to": str(tmp_path)}
    )
    scores = np.random.default_rng(1).normal(size=(5, 7 + 9)).astype(np.float32)
    got = hard_decode(jnp.asarray(scores), (7, 9), 60)
    monkeypatch.undo()
    want = hard_decode(jnp.asarray(scores), (7, 9), 60)
    for mine, theirs in zip(got, want, strict=True):
        np.testing.assert_array_equal(mine, theirs)
    dumped = [p.name for p in tmp_path.iterdir()]
    assert any("_hard" in name for name in dumped), dumped[:5]
    options = [p for p in tmp_path.iterdir() if p.name.endswith("debug_options")]
    text = "".join(p.read_text() for p in options)
    assert "xla_gpu_enable_triton_gemm: false" in text


def test_an_option_xla_refuses_warns_once_and_compiles_without(monkeypatch, caplog):
    monkeypatch.setattr(jit_options, "_platform", lambda: "gpu")
    monkeypatch.setattr(jit_options, "GPU_OPTIONS", {"xla_no_such_flag": 1})
    f = jit(lambda x: x * 2)
    with caplog.at_level(logging.WARNING, logger="rhythmic_jax.jit_options"):
        np.testing.assert_array_equal(f(jnp.arange(3)), [0, 2, 4])
        np.testing.assert_array_equal(jit(lambda x: x + 1)(jnp.arange(2)), [1, 2])
    assert [r.getMessage() for r in caplog.records if "refused" in r.getMessage()]
    assert len(caplog.records) == 1
    assert compiler_options("gpu") == {}


def test_inside_another_trace_the_program_runs_without_options(monkeypatch):
    """JAX takes compiler options only on the outermost program: a wrapped program
    called under jax.jit or jax.grad is inlined without them."""
    monkeypatch.setattr(jit_options, "_platform", lambda: "gpu")
    inner = jit(lambda x: jnp.sum(x**2))
    x = jnp.arange(4.0)
    assert float(jax.jit(lambda y: inner(y) + 1)(x)) == 15.0
    np.testing.assert_array_equal(jax.grad(inner)(x), 2 * np.arange(4.0))
    assert float(inner(x)) == 14.0


def test_static_arguments_methods_and_attributes_pass_through():
    @functools.partial(jit, static_argnames=("k",))
    def power(x, k):
        return x**k

    assert power.__name__ == "power"
    power.clear_cache()
    np.testing.assert_array_equal(power(jnp.arange(3), k=2), [0, 1, 4])
    power(jnp.arange(3), k=2)
    assert power._cache_size() == 1
    power(jnp.arange(3), k=3)
    assert power._cache_size() == 2
    lowered = power.lower(jnp.arange(3), k=2)
    assert "power" in lowered.as_text()


def test_explicit_options_are_added_to_the_backend_s(monkeypatch, tmp_path):
    f = jit(lambda x: x - 1, compiler_options={"xla_dump_to": str(tmp_path)})
    np.testing.assert_array_equal(f(jnp.arange(2)), [-1, 0])
    assert any(tmp_path.iterdir())


def test_a_fit_logs_its_compile_options(caplog):
    from rhythmic_jax.rhythmic_map import RhythmicMap

    x = np.random.default_rng(2).normal(size=(40, 16)).astype(np.float32)
    with caplog.at_level(logging.INFO, logger="rhythmic_jax.fitting.fit_map"):
        RhythmicMap(r=2, level=1).fit(x)
    lines = [r.getMessage() for r in caplog.records if "compile options" in (
        r.getMessage())]  # fmt: skip
    assert lines == [f"compile options {describe(jax.default_backend())}"]


def test_info_states_the_compile_options(tmp_path, capsys):
    from rhythmic_jax.app.cli import main
    from rhythmic_jax.rhythmic_map import RhythmicMap

    x = np.random.default_rng(3).normal(size=(40, 16)).astype(np.float32)
    RhythmicMap(r=2, level=1).fit(x).save(str(tmp_path / "m.map"))
    assert main(["info", str(tmp_path / "m.map")]) == 0
    out = capsys.readouterr().out.splitlines()
    import jax

    # the backend in use, not every backend's
    assert out[-1].split(": ", 1) == ["   compile options",
                                      describe(jax.default_backend())]


def test_the_command_line_states_it_without_starting_jax():
    import subprocess
    import sys

    code = (
        "import sys; from rhythmic_jax.jit_options import describe; "
        "print(describe()); print('jax' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True,
                         text=True, check=True).stdout.split("\n")  # fmt: skip
    assert out[0] == describe() and out[1] == "False"
