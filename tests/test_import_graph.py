"""The module graph points down: no module imports from a module above it.

Every ``rhythmic_jax`` import in the package, including those inside functions,
is read from the source. Modules sit in layers, lowest first; a module may import
only from lower layers. The command line builds its parser from light modules
(the jobs' options, the map's configuration, the compile policy) and
runs the jobs only when a command runs; nothing imports the public face.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "rhythmic_jax"

LAYERS = [
    ["errors", "version"],
    ["jit_options", "progress"],
    ["validate"],
    ["io.csv_cells", "io.names", "io.reader"],
    ["io.outputs"],
    ["io.atomic", "io.checkpoint", "io.images"],
    ["io.descriptor_files", "io.tiles"],
    ["io.vpr_files"],
    ["io.frame_files"],
    ["map.periods", "map.projection", "map.quantize", "map.scalar_codes"],
    ["map.embedding", "map.groups", "map.storage"],
    ["map.config"],
    ["map.codes"],
    ["map.pytree"],
    ["map.checks"],
    ["map.map_file"],
    ["frames.cache_files", "frames.compile_policy", "frames.nets"],
    ["frames.package_builds"],
    ["frames.compiled", "frames.weights"],
    ["frames.descriptors", "frames.pipeline"],
    ["frames.features"],
    ["frames.describe_shards", "frames.network_build", "frames.sources"],
    ["frames.route_descriptors"],
    ["jit_cache"],
    ["solvers.frame_length", "solvers.newton_system", "solvers.objective",
     "solvers.precision", "solvers.precondition", "solvers.span"],
    ["solvers.exact_linesearch", "solvers.newton_config"],
    ["solvers.candidates", "solvers.memory", "solvers.newton_cg", "solvers.optax_loops",
     "solvers.passes"],
    ["solvers.newton", "solvers.resumable"],
    ["solvers.distributed", "solvers.streamed"],
    ["solvers.protocol"],
    ["estimator_inputs"],
    ["decoding.buckets"],
    ["decoding.hard"],
    ["decoding.host", "decoding.soft"],
    ["decoding.group_decode"],
    ["decoding.dispatch", "decoding.sequence"],
    ["decoding.batch", "decoding.fusion"],
    ["decoding.queries"],
    ["decoding.held"],
    ["fitting.closed_form", "fitting.fit_plan", "fitting.holdout", "fitting.places"],
    ["fitting.fit_map", "fitting.learn"],
    ["fitting.prepare", "fitting.scale_fit"],
    ["augment.kornia_ops"],
    ["augment.stream"],
    ["eval.baselines", "eval.budget_peers", "eval.figure_canvas", "eval.frontier_pca",
     "eval.seqslam", "eval.split", "eval.timing"],
    ["eval.frontier_figure", "eval.image_figures", "eval.metrics",
     "eval.paper_figures"],
    ["eval.evaluation_figure", "eval.ground_truth", "eval.ground_truth_formats",
     "eval.outliers"],
    ["eval.figures", "eval.method_scores"],
    ["eval.model_frontier", "eval.peer_rows", "eval.report_text"],
    ["eval.frontier", "eval.ground_truth_files", "eval.report"],
    ["eval.ablation"],
    ["app.native_stderr", "app.options", "app.signals"],
    ["app.parts"],
    ["app.query_specs"],
    ["app.specs"],
    ["app.demo", "app.frontier", "app.fusion", "app.matches", "app.parser",
     "app.query_results", "app.render", "app.scale_jobs"],
    ["app.per_query"],
    ["app.jobs"],
    ["app.cli"],
    ["rhythmic_map"],  # the scikit-learn face: nothing in the package imports it
    [""],  # the public face, rhythmic_jax/__init__.py: nothing imports it
]  # fmt: skip
RANK = {name: i for i, layer in enumerate(LAYERS) for name in layer}
FOLDERS = (
    "io",
    "map",
    "frames",
    "solvers",
    "decoding",
    "fitting",
    "augment",
    "eval",
    "app",
)


def _name(path: Path) -> str:
    parts = path.relative_to(PACKAGE).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path, top: bool = False) -> set[str]:
    """The package modules ``path`` imports (a name imported from a package is its
    submodule when there is one); ``top``: only those imported at module level."""
    found = set()
    tree = ast.parse(path.read_text())
    for node in tree.body if top else ast.walk(tree):
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


# no numpy, JAX, torch at load (jit_cache is imported inside a function)
PARSER = {"app.options", "app.parser", "app.specs", "errors", "map.config",
          "validate", "frames.compile_policy", "version"}  # fmt: skip


def test_the_command_line_loads_only_its_parsers_modules_and_runs_jobs():
    """At load the command line imports only what its parser is built from; the
    jobs are imported inside the commands (tests/test_cli.py runs --help)."""
    assert _imports(PACKAGE / "app" / "cli.py", top=True) <= PARSER
    inside = {
        "app.demo",
        "app.frontier",
        "app.jobs",
        "app.render",
        "app.scale_jobs",
        "app.signals",
        "io.checkpoint",
        "io.outputs",
        "jit_cache",
    }  # in commands, and the check of their outputs
    assert _imports(PACKAGE / "app" / "cli.py") <= PARSER | inside


def test_folders_say_what_they_hold_and_import_nothing():
    for folder in FOLDERS:
        tree = ast.parse((PACKAGE / folder / "__init__.py").read_text())
        assert ast.get_docstring(tree), folder
        assert not [n for n in tree.body if not isinstance(n, ast.Expr)], folder


def test_the_check_catches_an_upward_import(tmp_path):
    fake = tmp_path / "x.py"
    fake.write_text("def f():\n    from rhythmic_jax.app.jobs import fit\n")
    assert _imports(fake) == {"app.jobs"}
    assert _imports(fake, top=True) == set()
    fake.write_text("from rhythmic_jax import RhythmicMap\n")
    assert _imports(fake) == {""}


def test_the_estimator_is_imported_by_no_module_and_alone_imports_sklearn():
    """``RhythmicMap`` is a face for scikit-learn's users: the command line and
    the evaluations work on ``Map`` values, and only the estimator's module
    imports scikit-learn at load (others import it inside what uses it)."""
    users = [_name(p) for p in MODULES if "rhythmic_map" in _imports(p)]
    assert users == []
    at_load = []
    for path in MODULES:
        for node in ast.parse(path.read_text()).body:
            names = [a.name for a in getattr(node, "names", [])]
            module = getattr(node, "module", None) or ""
            if module.startswith("sklearn") or any(
                n.startswith("sklearn") for n in names
            ):
                at_load.append(_name(path))
    assert sorted(set(at_load)) == ["rhythmic_map"]


def test_each_folder_sits_on_consecutive_layers():
    for folder in FOLDERS:
        ranks = {RANK[m] for m in RANK if m.startswith(f"{folder}.")}
        assert ranks == set(range(min(ranks), max(ranks) + 1)), folder
