"""The notebooks: they run in reduced size, import only public library names,
define no core logic, and are committed without outputs.

The execution test runs every notebook with nbclient in ``notebooks/`` with
``RHYTHMIC_NB_QUICK=1`` (300 places, 1 epoch, few maps), once on the shared data
and once with it absent (the demo route); it is slow (kernel start, torch and JAX
imports, compiling each fit's shapes: 1-3 minutes a notebook on two busy cores),
so CI runs it in the second step: ``pytest -m slow tests/test_notebooks.py``.
"""

from __future__ import annotations

import ast
import importlib
import os
import types
from pathlib import Path

import nbformat
import pytest

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))
PACKAGE = "rhythmic_jax"
MAX_BODY = 5  # statements a helper defined in a notebook may hold
MAX_LOOP = 4  # statements a loop in a notebook may hold (nested ones included)
SHARED_DATA = Path(
    os.environ.get(
        "RHYTHMIC_DATA", Path(__file__).resolve().parents[1].parent / "shared" / "data"
    )
)


def _code(path: Path) -> list[str]:
    """Code cells as plain Python (IPython magics turned into calls)."""
    from IPython.core.inputtransformer2 import TransformerManager

    nb = nbformat.read(path, as_version=4)
    python = TransformerManager().transform_cell
    return [python(c.source) for c in nb.cells if c.cell_type == "code"]


def _tree(path: Path) -> ast.Module:
    return ast.parse("\n\n".join(_code(path)), filename=str(path))


def check_public_names(tree: ast.Module, where: str) -> set[str]:
    """Assert every package name the code uses is public; return those names."""
    aliases = _library_names(tree, where)
    used = set(aliases)
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Load):
            chain = _attribute_chain(node)
            if chain and chain[0] in aliases:
                _resolve(aliases[chain[0]], chain[1], f"{where} line {node.lineno}")
                used.add(".".join([chain[0], *chain[1]]))
    return used


def check_no_core_logic(tree: ast.Module, where: str) -> None:
    """Assert no function or class holds more than ``MAX_BODY`` statements and no
    loop more than ``MAX_LOOP``: longer logic belongs in the library (a job)."""
    for node in ast.walk(tree):
        size = sum(1 for s in ast.walk(node) if isinstance(s, ast.stmt)) - 1
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            assert size <= MAX_BODY, (
                f"{where}: {node.name!r} holds {size} statements; "
                "move it into the library"
            )
        if isinstance(node, ast.For | ast.AsyncFor | ast.While):
            assert size <= MAX_LOOP, (
                f"{where} line {node.lineno}: a loop of {size} statements; "
                "move it into the library"
            )


def _resolve(obj: object, dotted: list[str], where: str) -> object:
    """Walk ``dotted`` attributes from ``obj``; each must be public and exist."""
    for name in dotted:
        assert not name.startswith("_"), f"{where}: private name {name!r}"
        if not hasattr(obj, name):  # a submodule not imported yet
            try:
                importlib.import_module(f"{obj.__name__}.{name}")
            except (AttributeError, ImportError):
                pass
        assert hasattr(obj, name), (
            f"{where}: {getattr(obj, '__name__', obj)} has no {name!r}"
        )
        value = getattr(obj, name)
        module = isinstance(obj, types.ModuleType)
        if module and not isinstance(value, types.ModuleType):
            assert name in getattr(obj, "__all__", [name]), (
                f"{where}: {name!r} is not in {obj.__name__}.__all__"
            )
        obj = value
    return obj


def _attribute_chain(node: ast.Attribute) -> tuple[str, list[str]] | None:
    """``a.b.c`` -> ("a", ["b", "c"]); None when the chain does not start at a name."""
    names = []
    while isinstance(node, ast.Attribute):
        names.append(node.attr)
        node = node.value
    return (node.id, names[::-1]) if isinstance(node, ast.Name) else None


def _library_names(tree: ast.Module, where: str) -> dict[str, object]:
    """Check every import from the package; map each bound alias to its object."""
    aliases: dict[str, object] = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] != PACKAGE:
                    continue
                parts = a.name.split(".")
                _resolve(importlib.import_module(PACKAGE), parts[1:], where)
                if a.asname:
                    aliases[a.asname] = importlib.import_module(a.name)
                else:
                    aliases[PACKAGE] = importlib.import_module(PACKAGE)
        elif isinstance(node, ast.ImportFrom) and node.module:
            if node.module.split(".")[0] != PACKAGE or node.level:
                continue
            parts = node.module.split(".")
            module = importlib.import_module(node.module)
            _resolve(importlib.import_module(PACKAGE), parts[1:], where)
            for a in node.names:
                assert a.name != "*", f"{where}: star import from {node.module}"
                aliases[a.asname or a.name] = _resolve(module, [a.name], where)
    return aliases


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_uses_only_public_library_names(path):
    assert len(check_public_names(_tree(path), path.name)) > 5


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_defines_no_core_logic(path):
    check_no_core_logic(_tree(path), path.name)


@pytest.mark.parametrize(
    "source",
    [
        "from rhythmic_jax.eval.report import _ranked",
        "from rhythmic_jax.map.periods import no_such_name",
        "import rhythmic_jax as rj\nrj.objective.period_offsets\nrj._version",
        "from rhythmic_jax.frames import features\nfeatures._l2",
        "from rhythmic_jax.io.images import *",
        "from rhythmic_jax.io.images import Path",  # imported there, not its own
    ],
)
def test_public_name_check_catches_private_or_missing_names(source):
    with pytest.raises(AssertionError):
        check_public_names(ast.parse(source), "example")


def test_public_name_check_follows_aliases_and_submodules():
    source = "import rhythmic_jax as rj\nfrom rhythmic_jax.io import images\n"
    source += "rj.RhythmicMap\nrj.map.periods.phases\nimages.read_rgb\n"
    assert check_public_names(ast.parse(source), "example") == {
        "rj", "images", "rj.RhythmicMap", "rj.map", "rj.map.periods",
        "rj.map.periods.phases",
        "images.read_rgb",
    }  # fmt: skip


def test_core_logic_check_allows_short_helpers_only():
    short = "def f(x):\n    return x + 1\n"
    check_no_core_logic(ast.parse(short), "example")
    long = "def g(x):\n" + "".join(f"    x = x + {i}\n" for i in range(6))
    with pytest.raises(AssertionError, match="'g' holds 6 statements"):
        check_no_core_logic(ast.parse(long), "example")


def test_core_logic_check_catches_a_long_loop():
    short = "for i in range(3):\n    x = i\n    if x:\n        print(x)\n"
    check_no_core_logic(ast.parse(short), "example")
    body = "".join(f"    x = x + {i}\n" for i in range(5))
    for head in ("for i in range(3):\n", "while x < 9:\n"):
        with pytest.raises(AssertionError, match="line 1: a loop of 5 statements"):
            check_no_core_logic(ast.parse(head + body), "example")


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_is_committed_without_outputs(path):
    nb = nbformat.read(path, as_version=4)
    nbformat.validate(nb)
    assert nb.metadata.get("kernelspec", {}).get("name") == "python3"
    for i, cell in enumerate(nb.cells):
        if cell.cell_type == "code":
            assert cell.outputs == [], f"{path.name} cell {i} has outputs"
            assert cell.execution_count is None, f"{path.name} cell {i} was run"


def test_every_notebook_is_found():
    names = {p.name for p in NOTEBOOKS}
    want = {"augmentation_ablation.ipynb", "embedding_ablation.ipynb"}
    assert want | {"periods_and_storage.ipynb"} <= names


def _figures(notebook: Path) -> list[Path]:
    return sorted(notebook.parents[1].joinpath("reports").glob("nb_*.png"))


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_writes_figures_outside_the_checkout_unless_asked(path):
    """No path into the checkout's reports/ is written in a notebook's code; a
    notebook that saves figures takes its folder from RHYTHMIC_NB_FIGURES
    (default: a temporary folder; ../reports is the opt-in)."""
    tree = _tree(path)
    texts = [n.value for n in ast.walk(tree)
             if isinstance(n, ast.Constant) and isinstance(n.value, str)]  # fmt: skip
    assert not [t for t in texts if "reports" in t], path.name
    code = "\n".join(_code(path))
    if "save_figure(" in code or "path=" in code:
        assert "RHYTHMIC_NB_FIGURES" in texts and "gettempdir" in code, path.name


@pytest.mark.slow
@pytest.mark.parametrize("data", ["shared", "absent"])
@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_runs_in_reduced_size(path, data, monkeypatch, tmp_path):
    """Reduced size, on the shared data and on the demo route that replaces it."""
    from nbclient import NotebookClient

    if data == "shared" and not SHARED_DATA.is_dir():
        pytest.skip(f"no shared data at {SHARED_DATA}: the 'absent' case covers it")
    monkeypatch.setenv("RHYTHMIC_NB_QUICK", "1")
    monkeypatch.setenv("RHYTHMIC_JAX_CACHE", str(tmp_path / "cache"))
    empty = tmp_path / "no-data"
    monkeypatch.setenv("RHYTHMIC_DATA", str(SHARED_DATA if data == "shared" else empty))
    figures = tmp_path / "figures"
    monkeypatch.setenv("RHYTHMIC_NB_FIGURES", str(figures))
    nb = nbformat.read(path, as_version=4)
    before = {p: p.stat().st_mtime_ns for p in _figures(path)}
    client = NotebookClient(
        nb,
        kernel_name="python3",
        timeout=300,
        resources={"metadata": {"path": str(path.parent)}},
    )
    client.execute()  # raises CellExecutionError on the first failing cell
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    images = sum("image/png" in o.get("data", {}) for o in outputs)
    least = {"embedding_ablation.ipynb": 1}.get(path.name, 4)  # one side-by-side plot
    assert images >= least, f"{path.name} drew {images} figures"
    text = "".join(o.get("text", "") for o in outputs)
    assert ("scikit-image's photographs" in text) == (data == "absent")
    after = {p: p.stat().st_mtime_ns for p in _figures(path)}
    assert after == before, "a run must not write reports/nb_*.png unless asked"
    if "RHYTHMIC_NB_FIGURES" in "".join(_code(path)):
        assert len(list(figures.glob("nb_*.png"))) >= least, path.name
