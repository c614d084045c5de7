"""Each meaning of the command line stated once: defaults in the declarations,
rendered into ``--help``; outputs checked by the runner alone; frontier made
from its job like every other command; warnings said only on success."""

from __future__ import annotations

import ast
import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from rhythmic_jax.app.cli import JOBS, main
from rhythmic_jax.app.options import default_phrase, option, options, outputs
from rhythmic_jax.app.specs import FitJob, FrontierJob
from rhythmic_jax.errors import InputError

APP = Path(__file__).resolve().parents[2] / "rhythmic_jax" / "app"
OUTPUT_CALLS = ("check_place", "check_target", "write_errors", "check_file_place")


def test_no_option_words_its_own_default():
    """Every option's help leaves its default to the declaration: no help text
    of any command says "default" itself."""
    for name, (job, _) in JOBS.items():
        for dest, _, help_, _ in options(job):
            assert "default" not in help_.lower(), (name, dest, help_)


def _field(**declared):
    @dataclasses.dataclass(frozen=True)
    class Job:
        x: object = option("x", **declared)

    return dataclasses.fields(Job)[0]


@pytest.mark.parametrize(
    ("declared", "phrase"),
    [
        ({"default": 5}, "(default 5)"),
        ({"default": 25.0}, "(default 25)"),
        (
            {"default": 1e-7, "show_default": "the optimum"},
            "(default 1e-07: the optimum)",
        ),
        ({"show_default": "size/2"}, "(default: size/2)"),
        ({"default": "", "show_default": "none"}, "(default: none)"),
        ({}, None),
        ({"default": False}, None),
        ({"default": ""}, None),
        ({"default": 0}, "(default 0)"),
    ],
)
def test_a_default_is_rendered_from_its_declaration(declared, phrase):
    assert default_phrase(_field(**declared)) == phrase


def test_the_augmented_fits_defaults_are_its_configs():
    """fit --epochs, --batch-size and --checkpoint-every state the defaults of
    AugmentedFit, read from its source (the parser imports no JAX), and the
    job leaves them to it."""
    from rhythmic_jax.augment.stream import AugmentedFit

    fields = {f.name: f for f in dataclasses.fields(FitJob)}
    for name in ("epochs", "batch_size", "checkpoint_every"):
        want = next(f.default for f in dataclasses.fields(AugmentedFit)
                    if f.name == name)  # fmt: skip
        assert fields[name].default is None
        assert default_phrase(fields[name]) == f"(default {want})"


def test_output_checks_are_the_runners_alone():
    """No module of app/ but the runner calls the output checks, and the runner
    calls each at most once."""
    calls: dict[str, list[str]] = {}
    for path in sorted(APP.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call):
                name = getattr(node.func, "id", getattr(node.func, "attr", ""))
                if name in OUTPUT_CALLS:
                    calls.setdefault(path.name, []).append(name)
    assert set(calls) <= {"cli.py", "demo.py"}, calls
    assert sorted(calls["cli.py"]) == sorted(OUTPUT_CALLS)


def test_frontier_refuses_by_its_rules_when_made(tmp_path):
    """frontier's job checks itself as every job does: a ground-truth format
    without a ground truth, a grid it has not; its outputs' names and places
    are the runner's, before any work."""
    ref = str(tmp_path / "r.npy")
    with pytest.raises(InputError, match="^ground_truth_format needs ground_truth"):
        FrontierJob(ref, ref, ground_truth_format="positions")
    with pytest.raises(InputError, match="^grid 'huge': one of small, full$"):
        FrontierJob(ref, ref, grid="huge")
    assert outputs(FrontierJob(ref, ref, csv="f.csv")) == [("csv", "f.csv", "file")]
    with pytest.raises(InputError, match=r"^plot f\.pdf: give a \.png file name$"):
        outputs(FrontierJob(ref, ref, plot="f.pdf"))


@pytest.fixture(scope="module")
def route(tmp_path_factory):
    folder = tmp_path_factory.mktemp("route")
    rng = np.random.default_rng(1)
    walk = np.cumsum(rng.standard_normal((60, 8)), axis=0).astype(np.float32)
    walk -= walk.mean(axis=0)
    np.save(folder / "ref.npy", walk + 0.2 * rng.standard_normal(walk.shape))
    np.save(folder / "qry.npy", walk + 0.5 * rng.standard_normal(walk.shape))
    return folder


def test_frontier_from_its_job_is_the_commands(route, capsys):
    """The library's frontier on a job and the command's JSON name the same
    rows with the same recall."""
    from rhythmic_jax.app.frontier import frontier

    ref, qry = str(route / "ref.npy"), str(route / "qry.npy")
    grid = {"maps": "2:1", "bits": "8", "pq": "", "lengths": "1"}
    result = frontier(FrontierJob(ref, qry, **grid), progress=False)
    flags = [f"--{k}={v}" for k, v in grid.items()]
    assert main(["frontier", ref, qry, *flags, "--json", "--no-progress"]) == 0
    said = json.loads(capsys.readouterr().out)
    got = {r["name"]: r["recall@1 L=1"] for r in said["rows"]}
    assert got == {r["name"]: r["recall@1 L=1"] for r in result["rows"]}
    assert tuple(result["config"]["dtypes"]) == ("float32", "float16", "int8")


def test_a_warning_is_said_on_success_and_dropped_on_refusal(route, tmp_path, capsys):
    """--compile on descriptor files is ignored with a warning: said after a
    run that succeeds, not before the one error line of a refused one."""
    fit = ["fit", str(route / "ref.npy"), "--compile", "never", "--no-progress"]
    assert main([*fit, "--out", str(tmp_path / "absent" / "sub" / "m.map")]) == 0
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith("rhythmic-jax fit: warning: --compile applies to images")
    assert all(": warning: " in line or ": note: " in line for line in err), err
    (tmp_path / "file").write_text("")
    assert main([*fit, "--out", str(tmp_path / "file" / "m.map")]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("rhythmic-jax fit: error: "), err
