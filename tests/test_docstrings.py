"""Docstrings point at things that exist.

Every dotted ``rhythmic_jax....`` name in a docstring of the package resolves to a
module or an attribute of one, and every repository path it names (``tests/…``,
``scripts/…``, ``docs/…``, ``reports/…``) is a file, so a renamed or removed
piece cannot leave a stale pointer behind.
"""

from __future__ import annotations

import ast
import importlib
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGE = REPO / "rhythmic_jax"
DOTTED = re.compile(r"rhythmic_jax(?:\.[A-Za-z_][A-Za-z0-9_]*)+")
PATH = re.compile(
    r"(?<![\w/.])((?:tests|scripts|docs|reports)/[\w/.-]+\.(?:py|md|json))"
)


def _docstrings(path: Path):
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(
            node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)
        ):
            doc = ast.get_docstring(node, clean=False)
            if doc:
                yield getattr(node, "name", "<module>"), doc


def _resolves(dotted: str) -> bool:
    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        for name in parts[cut:]:
            if not hasattr(obj, name):
                return False
            obj = getattr(obj, name)
        return True
    return False


SOURCES = sorted(PACKAGE.rglob("*.py"))


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: str(p.relative_to(REPO)))
def test_docstring_references_exist(path):
    stale = []
    for where, doc in _docstrings(path):
        for dotted in set(DOTTED.findall(doc)):
            if not _resolves(dotted.rstrip(".")):
                stale.append(f"{where}: {dotted}")
        for named in set(PATH.findall(doc)):
            if not (REPO / named).exists():
                stale.append(f"{where}: {named}")
    assert not stale, stale


def test_the_check_catches_a_stale_name(tmp_path):
    assert _resolves("rhythmic_jax.errors.InputError")
    assert not _resolves("rhythmic_jax.errors.NoSuchThing")
    assert not _resolves("rhythmic_jax.no_such_module")
