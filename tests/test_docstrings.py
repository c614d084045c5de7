"""Docstrings point at things that exist and quote no timings.

Every dotted ``rhythmic_jax....`` name in a docstring of the package resolves to a
module or an attribute of one, and every repository path it names (``tests/…``,
``scripts/…``, ``docs/…``, ``reports/…``) is a file, so a renamed or removed
piece cannot leave a stale pointer behind. No docstring quotes a timing
(seconds, milliseconds, "3x faster"): timings live in ``reports/``, with the
command and the machine that measured them, and a docstring points there.
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


# Timings live in reports/ (measured, dated, with the command that made them); a
# docstring says what a piece does and why, and points there.
TIMING = re.compile(
    r"(?<![\w.])\d+(?:\.\d+)?\s*(?:s|ms|µs|us|sec|secs|seconds?|minutes?)\b"
    r"|\d+(?:\.\d+)?\s*x\s+(?:faster|slower|sooner|quicker)",
    re.IGNORECASE,
)
# Matches that are not timings, with why: (file, the matched text).
NOT_TIMINGS: tuple[tuple[str, str], ...] = ()


def _timings(doc: str) -> list[str]:
    return [m.group(0) for m in TIMING.finditer(doc)]


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: str(p.relative_to(REPO)))
def test_docstrings_quote_no_timings(path):
    name = str(path.relative_to(REPO))
    quoted = [
        f"{where}: {hit!r}"
        for where, doc in _docstrings(path)
        for hit in _timings(doc)
        if (name, hit) not in NOT_TIMINGS
    ]
    assert not quoted, quoted


def test_the_timing_check_catches_timings():
    caught = ["9.4 s against 7.8 s", "12 ms", "2.6 µs", "3 seconds", "~3x faster"]
    assert all(_timings(text) for text in caught)
    clean = ["(n, d) x (d, n)", "1e-6 relative", "3576 x 2048", "2 sums", "3 sets"]
    assert not any(_timings(text) for text in clean)
