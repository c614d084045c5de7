"""The command line on descriptor files, an image folder, and Nordland when present."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from skimage import data as skdata
from skimage.io import imsave
from skimage.transform import resize

from rhythmic_jax import BruteForce, RhythmicMap
from rhythmic_jax.app.cli import main


def run(capsys, *argv):
    code = main([*argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture()
def npy_route(tmp_path):
    rng = np.random.default_rng(0)
    x = rng.normal(size=(120, 300)).astype(np.float32)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    q = x + 0.02 * rng.normal(size=x.shape).astype(np.float32)
    np.save(tmp_path / "ref.npy", x)
    np.save(tmp_path / "q.npy", q)
    return tmp_path


def test_fit_query_info_on_descriptor_files(npy_route, capsys):
    out_map = npy_route / "route.map"
    code, out, _ = run(capsys, "fit", str(npy_route / "ref.npy"), "--out", str(out_map),
                       "--no-progress", "--json")  # fmt: skip
    assert code == 0
    info = json.loads(out)
    model = RhythmicMap.load(out_map)
    assert info["periods"] == list(model.periods) and info["n"] == 120
    assert info["storage_bytes"] == model.storage_bytes
    pred_file = npy_route / "pred.npy"
    code, _, _ = run(capsys, "query", str(out_map), str(npy_route / "q.npy"),
                     "--out", str(pred_file), "--no-progress")  # fmt: skip
    assert code == 0
    pred = np.load(pred_file)
    np.testing.assert_array_equal(pred, model.predict(np.load(npy_route / "q.npy")))
    assert (pred == np.arange(120)).mean() > 0.95
    code, out, _ = run(capsys, "info", str(out_map), "--json")
    assert code == 0 and json.loads(out)["candidate_errors"] == list(
        model.candidate_errors
    )
    code, out, _ = run(capsys, "evaluate", str(out_map), str(npy_route / "q.npy"),
                       "--reference", str(npy_route / "ref.npy"), "--json",
                       "--tolerance", "1", "--no-progress")  # fmt: skip
    assert code == 0
    res = json.loads(out)
    assert res["tolerance"] == 1
    assert res["methods"]["map"]["accuracy"] == pytest.approx(
        float((pred == np.arange(120)).mean())
    )
    assert res["methods"]["brute force"]["storage_bytes"] == 120 * 300 * 4


def test_evaluate_finds_the_maps_reference_or_says_why_not(npy_route, capsys):
    """Without --reference, brute force reads the sources the map was fitted on."""
    ref = npy_route / "ref_copy.npy"
    shutil.copy(npy_route / "ref.npy", ref)
    out_map = npy_route / "copy.map"
    assert run(capsys, "fit", str(ref), "--out", str(out_map), "--no-progress")[0] == 0
    assert RhythmicMap.load(out_map).reference["sources"] == [str(ref.absolute())]
    query = str(npy_route / "q.npy")
    code, out, err = run(capsys, "evaluate", str(out_map), query, "--json")
    assert code == 0, err
    res = json.loads(out)
    expected = BruteForce().fit(np.load(ref)).search(np.load(query), 1)[1][:, 0]
    assert res["methods"]["brute force"]["accuracy"] == pytest.approx(
        float((expected == np.arange(120)).mean())
    )
    assert str(ref.absolute()) in res["reference_note"]
    ref.unlink()
    code, out, err = run(capsys, "evaluate", str(out_map), query)
    assert code == 0, err
    rows = out.splitlines()[5:-1]  # below the heading and header, above the note
    rows = [row for row in rows if ":" not in row]  # recall lines, the legend
    assert [row.split()[0] for row in rows] == ["map"]
    assert out.strip().endswith("is gone); give --reference SOURCE")


def make_folder(path, images):
    path.mkdir()
    for i, img in enumerate(images):
        imsave(path / f"frame{i}.png", img, check_contrast=False)


def test_fit_and_query_image_folders(tmp_path, capsys):
    photo = resize(skdata.astronaut(), (96, 640), anti_aliasing=True)
    frames = [(photo[:, 8 * i : 8 * i + 64] * 255).astype(np.uint8) for i in range(72)]
    make_folder(tmp_path / "a", frames)
    make_folder(
        tmp_path / "b", [np.clip(f * 0.9 + 10, 0, 255).astype(np.uint8) for f in frames]
    )
    out_map = tmp_path / "m"
    code, out, err = run(capsys, "fit", str(tmp_path / "a"), str(tmp_path / "b"),
                         "--out", str(out_map), "--no-progress")  # fmt: skip
    assert code == 0, err
    model = RhythmicMap.load(out_map)
    assert model.config.descriptor == "patchnorm" and model.n == 72
    code, out, err = run(capsys, "query", str(out_map), str(tmp_path / "b"), "--json",
                         "--no-progress")  # fmt: skip
    assert code == 0, err
    pred = np.asarray(json.loads(out)["predictions"])
    assert (np.abs(pred - np.arange(72)) <= 1).mean() > 0.9
    # brute force over both traversals the map was fitted on, as places
    code, out, err = run(capsys, "evaluate", str(out_map), str(tmp_path / "b"),
                         "--json", "--no-progress")  # fmt: skip
    assert code == 0, err
    res = json.loads(out)
    assert res["methods"]["brute force"]["accuracy"] == 1.0  # b is in the map
    assert res["methods"]["brute force"]["storage_bytes"] == 2 * 72 * 2048 * 4
    code, _, err = run(capsys, "query", str(out_map), str(tmp_path / "b"),
                       "--descriptor", "hog")  # fmt: skip
    assert code == 2 and "patchnorm" in err and len(err.strip().splitlines()) == 1
    # a PCA fitted on the references is saved with the map and applied to queries
    pca_map = tmp_path / "pca"
    code, _, err = run(capsys, "fit", str(tmp_path / "a"), "--out", str(pca_map),
                       "--pca", "40", "--no-progress")  # fmt: skip
    assert code == 0, err
    model = RhythmicMap.load(pca_map)
    assert model.d == 40 and model.extra["pca_components"].shape == (40, 2048)
    code, out, err = run(capsys, "query", str(pca_map), str(tmp_path / "b"), "--json",
                         "--no-progress")  # fmt: skip
    assert code == 0, err
    pred = np.asarray(json.loads(out)["predictions"])
    assert (np.abs(pred - np.arange(72)) <= 1).mean() > 0.8


def test_bad_arguments_exit_2_without_a_map(npy_route, capsys):
    bad = npy_route / "bad.npy"
    np.save(bad, np.full((4, 3), np.inf, np.float32))
    code, _, err = run(capsys, "fit", str(bad), "--out", str(npy_route / "x.map"))
    assert code == 2 and "NaN or inf" in err
    assert not (npy_route / "x.map").exists()
    assert not [p for p in npy_route.iterdir() if p.name.startswith(".x.map")]
    code, _, err = run(capsys, "info", str(npy_route / "nothing"))
    assert code == 2 and "no such map" in err
    code, _, err = run(capsys, "fit", str(npy_route / "ref.npy"), "--out",
                       str(npy_route / "g.map"), "--gap", "2")  # fmt: skip
    assert code == 2 and "argument --gap: must be in (0, 1), got 2" in err
    assert not (npy_route / "g.map").exists()
    code, _, err = run(capsys, "fit")
    assert code == 2
    assert err.splitlines() == [
        "rhythmic-jax fit: error: the following arguments are required: sources, "
        "--out (see rhythmic-jax fit --help)"
    ]


def test_installed_entry_exits_with_mains_status_and_a_frozen_collector(
    npy_route, capsys, monkeypatch
):
    """``rhythmic-jax`` is :func:`rhythmic_jax.app.cli.run`: main's status becomes the
    exit status, and the objects left are out of the collector's last walk."""
    import gc
    import sys

    from rhythmic_jax.app import cli

    monkeypatch.setattr(sys, "argv", ["rhythmic-jax", "info", str(npy_route / "no")])
    before = gc.get_freeze_count()
    try:
        with pytest.raises(SystemExit) as done:
            cli.run()
        assert done.value.code == 2 and "no such map" in capsys.readouterr().err
        assert gc.get_freeze_count() > before
    finally:
        gc.unfreeze()


def test_help_has_examples(capsys):
    for cmd in ("fit", "query", "info", "evaluate", "demo"):
        assert main([cmd, "--help"]) == 0
        assert "examples:" in capsys.readouterr().out


def test_version_is_the_packages(capsys):
    from rhythmic_jax import __version__

    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"rhythmic-jax {__version__}"


def _stated(value) -> set[str]:
    """How a help line may state a default: as written, or %g for numbers."""
    forms = {str(value)}
    if isinstance(value, int | float) and not isinstance(value, bool):
        forms.add(f"{value:g}")
    return forms


def test_every_option_has_help_and_states_its_default():
    """Each option of each command (those added later too) has help text, and
    one declared with a default (not None, False or '') states it in that text;
    choices are listed in the option's line."""
    import argparse

    from rhythmic_jax.app.cli import _parser

    for name, command in _parser().commands.items():
        formatter = command._get_formatter()
        for action in command._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            where = (name, action.dest)
            assert action.help, where
            text = " ".join(formatter._expand_help(action).split())
            default = action.default
            if action.option_strings and not (default is None or default is False
                                              or default in ("", argparse.SUPPRESS)):
                assert "default" in text, where
                assert any(form in text for form in _stated(default)), where
            if action.choices:
                line = formatter._format_action_invocation(action)
                assert all(str(c) in line for c in action.choices), where


def test_the_compile_note_is_said_once_at_the_top(capsys):
    """The long --compile paragraph is in the top-level epilog only; each
    command's --compile points there."""
    note = "a background build (a niced process, about a minute of CPU) starts"
    assert main(["--help"]) == 0
    assert note in " ".join(capsys.readouterr().out.split())
    for cmd in ("fit", "learn", "query", "evaluate"):
        assert main([cmd, "--help"]) == 0
        text = " ".join(capsys.readouterr().out.split())
        assert note not in text and "see the main --help" in text, cmd


HEAVY = ("numpy", "jax", "torch", "faiss", "sklearn", "optax", "orbax")
PARSE_ONLY = """
import contextlib, io, sys
from rhythmic_jax.app.cli import _parser, main
argvs = [[c, "--help"] for c in ("fit", "learn", "query", "info", "evaluate", "demo")]
with contextlib.redirect_stdout(io.StringIO()):
    codes = [main(argv) for argv in [["--help"], *argvs]]
_parser().parse_args(["fit", "a.npy", "--out", "m.map", "--r", "3", "--gap", "0.5"])
print(codes, [m for m in {heavy!r} if m in sys.modules])
"""


def test_help_and_the_parser_import_no_numpy_jax_or_torch():
    """``rhythmic-jax --help``, each command's ``--help`` and a parsed command line
    load none of the heavy packages (numpy included): the parser is built from
    light modules, and the jobs are imported when a command runs."""
    out = subprocess.run(
        [sys.executable, "-c", PARSE_ONLY.format(heavy=HEAVY)],
        capture_output=True, text=True, cwd=Path(__file__).resolve().parents[2],
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[0, 0, 0, 0, 0, 0, 0] []"


@pytest.mark.slow
def test_nordland_folders_end_to_end(nordland_root, tmp_path, capsys):
    out_map = tmp_path / "nordland.map"
    code, _, err = run(capsys, "fit", str(nordland_root / "summer"), "--out",
                       str(out_map), "--no-progress")  # fmt: skip
    assert code == 0, err
    summer = str(nordland_root / "summer")
    code, out, err = run(capsys, "evaluate", str(out_map), summer,
                         "--json", "--no-progress")  # fmt: skip
    assert code == 0, err
    methods = json.loads(out)["methods"]
    assert methods["map"]["accuracy"] >= 0.93
    assert methods["brute force"]["accuracy"] >= 0.99  # the map's own reference
    code, out, err = run(capsys, "query", str(out_map), summer, "--json",
                         "--no-progress")  # fmt: skip
    assert code == 0, err
    pred = np.asarray(json.loads(out)["predictions"])
    assert np.mean(pred == np.arange(len(pred))) == pytest.approx(
        methods["map"]["accuracy"]
    )


# ------------------------------------------------------------- option rules


def _commands():
    from rhythmic_jax.app.cli import _parser

    return _parser().commands


def _declared() -> dict[str, dict]:
    """command -> {dest: field} of the options its job declares."""
    from rhythmic_jax.app.cli import JOBS
    from rhythmic_jax.app.options import options

    return {
        name: {dest: f for dest, f, _, _ in options(job)}
        for name, (job, _) in JOBS.items()
    }


def test_every_option_is_declared_once():
    """Each command's parser holds exactly the options its job's fields declare,
    each once, with the field's default, choices and domain; the command line
    adds no option of its own but --verbose and --version."""
    import argparse
    import ast
    from dataclasses import MISSING

    from rhythmic_jax.app import cli, parser
    from rhythmic_jax.app.options import default_of

    for name, declared in _declared().items():
        actions = [a for a in _commands()[name]._actions
                   if not isinstance(a, argparse._HelpAction)
                   and a.dest != "verbose"]  # fmt: skip
        assert sorted(a.dest for a in actions) == sorted(declared), name
        for action in actions:
            f = declared[action.dest]
            default = default_of(f)
            assert action.default == (None if default is MISSING else default)
            assert action.choices == f.metadata.get("choices"), action.dest
            assert action.type is f.metadata.get("domain"), action.dest
    added = [
        node.args[-1].value
        for module in (cli, parser)
        for node in ast.walk(ast.parse(Path(module.__file__).read_text()))
        if isinstance(node, ast.Call)
        and getattr(node.func, "attr", "") == "add_argument"
    ]
    assert sorted(added) == ["--verbose", "--version"]


def test_an_option_jobs_share_is_declared_once():
    """frontier offers evaluate's options as evaluate declares them (its own help
    where it words one), and evaluate query's map, queries and decoders."""
    declared = _declared()
    frontier, evaluate, query = (declared[c] for c in ("frontier", "evaluate", "query"))
    for dest in ("tolerance", "ground_truth_format", "recall_over", "json"):
        assert frontier[dest].metadata == evaluate[dest].metadata, dest
    for dest in ("ground_truth", "tolerance_m"):
        same = {k: v for k, v in frontier[dest].metadata.items() if k != "help"}
        assert same == {k: v for k, v in evaluate[dest].metadata.items() if k != "help"}
        assert frontier[dest].default == evaluate[dest].default
        assert frontier[dest].metadata["help"] != evaluate[dest].metadata["help"]
    for dest in ("map", "source", "decode"):
        assert evaluate[dest].metadata == query[dest].metadata, dest
    assert declared["info"]["json"].metadata == evaluate["json"].metadata


def test_every_numeric_option_states_its_domain(capsys):
    """--help states the domain of every option that declares one."""
    stated = set()
    for name, declared in _declared().items():
        assert main([name, "--help"]) == 0
        text = " ".join(capsys.readouterr().out.split())
        text = re.sub(r"(?<=[a-z])- (?=[a-z])", "-", text)  # a line broken at "-"
        for dest, f in declared.items():
            domain = f.metadata.get("domain")
            if domain is not None:
                assert f"[{domain.text()}]" in text, (name, dest)
                stated.add(dest)
    assert {"r", "tile", "memory", "codes", "seed", "budget"} <= stated


@pytest.mark.parametrize("value", ["nan", "-1e9", "1e400", "x", ""])
def test_every_domain_refuses_in_one_line(value, capsys):
    """Each numeric option of each command refuses a value outside its domain
    where it is parsed: exit 2, one line naming the flag."""
    for name, command in _commands().items():
        required = {"fit": ["a.npy", "--out", "m.map"], "learn": ["a", "b", "--out",
                    "e.emb"], "query": ["m", "q"], "evaluate": ["m", "q"],
                    "describe": ["d", "--out", "d.npy"], "frontier": ["a", "b"]}
        for action in command._actions:
            if action.type is None or not action.option_strings:
                continue
            if value == "-1e9" and action.dest == "threshold":
                continue  # any finite number
            if value in getattr(action.type, "words", ()):
                continue  # a word the option takes as it is (frontier --pq '')
            flag = action.option_strings[-1]
            argv = [name, *required.get(name, []), f"{flag}={value}"]
            assert main(argv) == 2, argv
            err = capsys.readouterr().err.splitlines()
            assert len(err) == 1 and f"argument {flag}: " in err[0], (argv, err)


def test_every_job_checks_its_domains():
    """A job made with a number below an option's domain refuses it in one line
    naming the setting (its part, as a map's configuration, may say it first)."""
    from rhythmic_jax.app.cli import JOBS, _parser
    from rhythmic_jax.app.options import make
    from rhythmic_jax.errors import InputError

    argvs = {"fit": ["a.npy", "--out", "m"], "query": ["m", "q"], "evaluate":
             ["m", "q"], "describe": ["d", "--out", "d.npy"], "frontier": ["a", "b"],
             "demo": []}  # fmt: skip
    checked = set()
    for name, argv in argvs.items():
        for dest, f in _declared()[name].items():
            domain = f.metadata.get("domain")
            if domain is None or domain.low is None:
                continue
            args = _parser().parse_args([name, *argv])
            setattr(args, dest, int(domain.low) - 1)
            with pytest.raises(InputError, match=rf"^({{opt:)?{dest}\b.* must be"):
                make(JOBS[name][0], args)
            checked.add(dest)
    assert {"r", "gap", "tile", "compile_min_frames", "memory", "top"} <= checked


def test_every_rule_and_path_names_options_of_its_commands():
    from rhythmic_jax.app.cli import JOBS

    for name, declared in _declared().items():
        for rule in JOBS[name][0].RULES:
            assert set(rule.options) <= set(declared), (name, rule.options)
        for dest, f in declared.items():
            assert f.metadata.get("path") in (None, "reads", "writes", "frames"), dest


@pytest.mark.parametrize("command", ["query", "info"])
def test_a_reader_that_leaves_early_ends_the_command_quietly(npy_route, command):
    """``rhythmic-jax query MAP Q | head -1``: when the reader has closed the
    pipe, the command stops with nothing on stderr and SIGPIPE's status 141, as
    the shell's own tools do (the reader here closes before a line is written)."""
    ref = str(npy_route / "ref.npy")
    assert main(["fit", ref, "--out", str(npy_route / "m.map"), "--no-progress"]) == 0
    args = [str(npy_route / "m.map")] + ([ref, "--no-progress"] * (command == "query"))
    code = "from rhythmic_jax.app.cli import run; run()"
    cmd = [sys.executable, "-c", code, command, *args]
    writer = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    writer.stdout.close()  # the reader is gone before the first line
    err = writer.stderr.read().decode()
    assert writer.wait(timeout=120) == 141, err
    assert err == ""


def test_an_option_scripts_pass_always_is_warned_once(npy_route, capsys):
    """--compile and --compile-min-frames on descriptor files: one warning line
    each, and the fit goes on."""
    code, out, err = run(
        capsys, "fit", str(npy_route / "ref.npy"), "--out", str(npy_route / "m.map"),
        "--compile", "never", "--compile-min-frames", "5", "--no-progress",
    )  # fmt: skip
    assert code == 0, err
    warned = [line for line in err.splitlines() if ": note: " not in line]
    assert warned == [
        "rhythmic-jax fit: warning: --compile-min-frames acts only with --compile "
        "auto; ignored",
        "rhythmic-jax fit: warning: --compile applies to images; .npy files are "
        "descriptors; ignored",
    ]
    assert "map " in out


def test_an_option_at_its_default_given_is_still_refused(npy_route, capsys):
    """Given explicitly, an option with no effect is refused even at its default
    value; left out, its default never is."""
    ref, out = str(npy_route / "ref.npy"), str(npy_route / "m.map")
    code, _, err = run(capsys, "fit", ref, "--out", out, "--epochs", "3")
    assert code == 2 and "--epochs needs --augment" in err
    code, _, err = run(capsys, "fit", ref, "--out", out, "--epochs=3", "--no-progress")
    assert code == 2 and "--epochs needs --augment" in err
    assert not (npy_route / "m.map").exists()


def test_help_examples_keep_their_lines(capsys):
    """A continued example ends its line with a backslash, the next line
    indented: no example line runs two commands' options together, and
    evaluate's examples name their plots for what they draw."""
    import re

    from rhythmic_jax.app.parser import EXAMPLES

    for name, text in EXAMPLES.items():
        for line in text.splitlines():
            assert not re.search(r"\S {4,}--", line), (name, line)
    assert "frontier.png" not in EXAMPLES["evaluate"]
    assert main(["learn", "--help"]) == 0
    out = capsys.readouterr().out
    assert "--out route.emb \\\n    --method invariant" in out
