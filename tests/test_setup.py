"""The set-up is the same everywhere: CI runs the README's test command line as it
stands, and constraints.txt pins every package the ``[test]`` extra installs, each
pin inside the ranges that pyproject.toml and the packages themselves ask for."""

from __future__ import annotations

import re
import subprocess
from importlib import metadata
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

tomllib = pytest.importorskip("tomllib")  # Python 3.11+

REPO = Path(__file__).resolve().parents[1]
PIN = re.compile(r"^([A-Za-z0-9][A-Za-z0-9._-]*)==([0-9][A-Za-z0-9.!+_-]*)$")


def _setup_lines() -> list[str]:
    """The command lines of the README's set-up section's ``bash`` blocks."""
    text = (REPO / "README.md").read_text()
    section = text.split("## Set-up", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```bash\n(.*?)```", section, flags=re.S)
    return [line for b in blocks for line in b.splitlines() if line.strip()]


def _pins() -> dict[str, str]:
    """constraints.txt as {canonical name: version}; every other line a comment."""
    pins: dict[str, str] = {}
    for line in (REPO / "constraints.txt").read_text().splitlines():
        if not line.strip() or line.startswith("#"):
            continue
        m = PIN.match(line.strip())
        assert m, f"not name==version: {line!r}"
        name = canonicalize_name(m.group(1))
        assert name not in pins, f"pinned twice: {name}"
        pins[name] = m.group(2)
    return pins


def _project_requirements() -> list[Requirement]:
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    specs = project["dependencies"] + project["optional-dependencies"]["test"]
    return [Requirement(s) for s in specs]


def test_ci_runs_the_readme_test_command_line_in_a_new_environment():
    lines = _setup_lines()
    tests = [line for line in lines if "scripts/test.sh" in line]
    assert tests == [
        'pip install -c constraints.txt -e ".[test]" && bash scripts/test.sh'
    ]
    ci = (REPO / ".ci" / "run").read_text()
    assert tests[0] in ci.splitlines()
    # the environment is made in the run itself, before the install
    assert ci.index("-m venv") < ci.index("bin/activate") < ci.index(tests[0])
    installs = [line for line in lines if "pip install" in line]
    # the two set-up commands: install, then the main job or the suite
    assert [line for line in installs if "&&" in line] == [
        "pip install -c constraints.txt -e . && rhythmic-jax demo",
        tests[0],
    ]
    # every other install line (the CPU wheel of torch, the GPU extra) pins too
    for line in installs:
        assert "-c constraints.txt" in line or "torch==2.13.0" in line, line
    assert any(line.startswith("python -m venv .venv") for line in lines)


def test_constraints_pin_the_package_and_test_requirements_within_range():
    pins = _pins()
    assert "rhythmic-jax" not in pins
    for req in _project_requirements():
        name = canonicalize_name(req.name)
        assert name in pins, f"{name} not pinned"
        assert req.specifier.contains(pins[name], prereleases=True), (
            name,
            str(req.specifier),
            pins[name],
        )


def test_constraints_pin_every_package_the_test_extra_installs():
    """Walks the requirements of the installed packages from pyproject.toml's list
    down (markers evaluated here, extras followed): each one reached is pinned, at a
    version its dependants accept."""
    pins = _pins()
    todo = [(req, "rhythmic_jax") for req in _project_requirements()]
    seen: set[str] = set()
    while todo:
        req, by = todo.pop()
        name = canonicalize_name(req.name)
        assert name in pins, f"{name} (required by {by}) not pinned"
        assert req.specifier.contains(pins[name], prereleases=True), (
            by,
            str(req),
            pins[name],
        )
        if name in seen:
            continue
        seen.add(name)
        try:
            dist = metadata.distribution(name)
        except metadata.PackageNotFoundError:
            pytest.skip(f"{name} is not installed here: the walk needs the test set-up")
        for spec in dist.requires or []:
            sub = Requirement(spec)
            extras = {""} | set(req.extras)
            if sub.marker and not any(
                sub.marker.evaluate({"extra": e}) for e in extras
            ):
                continue
            todo.append((sub, name))
    assert {"jax", "torch", "pytest", "numpy"} <= seen


@pytest.mark.parametrize("argv", [["--bogus"], ["--out"]])
def test_refresh_script_refuses_bad_arguments_in_one_line(argv):
    proc = subprocess.run(
        ["bash", str(REPO / "scripts" / "refresh_constraints.sh"), *argv],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2
    assert proc.stderr.startswith("error: ") and proc.stderr.count("\n") == 1
