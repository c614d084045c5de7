"""The module graph points down: no module imports from a module above it.

Every ``rhythmic_jax`` import in the package, including those inside functions,
is read from the source. Modules sit in layers, lowest first; a module may import
only from lower layers. The command line imports only the jobs and the public
face, and nothing imports the public face.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "rhythmic_jax"

LAYERS = [
    ["errors", "version", "io.atomic", "solvers.precondition", "solvers.span",
     "progress", "decoding.buckets"],
    ["validate", "solvers.precision", "quantize", "cache_files"],
    ["scalar_codes", "jit_cache"],
    [
        "periods", "projection", "split", "nets", "io.checkpoint", "io.images", "codes",
        "io.descriptor_files", "solvers.memory", "augment.kornia_ops",
        "eval.baselines", "eval.metrics", "eval.figures", "compiled",
    ],
    ["groups"],
    ["objective", "io.tiles", "io.weights", "io.frame_files", "pipeline",
     "eval.ground_truth", "embedding"],
    ["io.ground_truth_files", "closed_form", "solvers.newton_cg", "solvers.candidates"],
    [
        "solvers.newton", "solvers.optax_loops", "solvers.sharding", "decoding.hard",
        "features", "solvers.streamed", "learn",
    ],
    ["network_build"],
    [
        "solvers.resumable", "decoding.soft", "solvers.distributed",
        "io.describe_shards", "decoding.small",
    ],
    ["decoding.group_decode", "solvers.protocol"],
    ["decoding.dispatch", "decoding.sequence", "io.sources", "scale_fit"],
    ["decoding.fusion", "decoding.batch"],
    [
        "rhythmic_map", "eval.seqslam", "eval.outliers", "eval.report",
        "augment.stream",
    ],
    ["demo", "scale_jobs", "eval.frontier"],
    ["jobs"],
    [""],  # the public face, rhythmic_jax/__init__.py
    ["cli"],
]  # fmt: skip
RANK = {name: i for i, layer in enumerate(LAYERS) for name in layer}
FOLDERS = ("solvers", "decoding", "augment", "io", "eval")


def _name(path: Path) -> str:
    parts = path.relative_to(PACKAGE).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path) -> set[str]:
    """The package modules ``path`` imports (a name imported from a package is its
    submodule when there is one)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.level:
            raise AssertionError(f"{path}: relative import")
        if isinstance(node, ast.ImportFrom) and node.module:
            modules = [node.module]
            if node.module == "rhythmic_jax" or node.module.rsplit(".", 1)[-1] in (
                FOLDERS
            ):
                modules = [f"{node.module}.{a.name}" for a in node.names]
        elif isinstance(node, ast.Import):
            modules = [a.name for a in node.names]
        else:
            continue
        for module in modules:
            if module == "rhythmic_jax" or module.startswith("rhythmic_jax."):
                inner = module.removeprefix("rhythmic_jax").removeprefix(".")
                found.add(inner if inner in RANK or inner in FOLDERS else "")
    return found


MODULES = sorted(
    p for p in PACKAGE.rglob("*.py") if _name(p) not in FOLDERS
)  # the folders' __init__ files hold only a docstring (checked below)


def test_every_module_has_a_layer():
    assert sorted(_name(p) for p in MODULES) == sorted(RANK)


@pytest.mark.parametrize("path", MODULES, ids=_name)
def test_imports_point_down(path):
    name = _name(path)
    if name == "":
        return  # the public face re-exports from everywhere
    up = sorted(m for m in _imports(path) if RANK.get(m, -1) >= RANK[name])
    assert not up, f"{name} imports from {up}, not below it"


def test_the_command_line_imports_only_jobs_and_the_public_face():
    assert _imports(PACKAGE / "cli.py") <= {"jobs", ""}


def test_folders_say_what_they_hold_and_import_nothing():
    for folder in FOLDERS:
        tree = ast.parse((PACKAGE / folder / "__init__.py").read_text())
        assert ast.get_docstring(tree), folder
        assert not [n for n in tree.body if not isinstance(n, ast.Expr)], folder


def test_the_check_catches_an_upward_import(tmp_path):
    fake = tmp_path / "x.py"
    fake.write_text("def f():\n    from rhythmic_jax.jobs import fit\n")
    assert _imports(fake) == {"jobs"}
    fake.write_text("from rhythmic_jax import RhythmicMap\n")
    assert _imports(fake) == {""}
