"""InputError: a ValueError whose message is always a single line."""

from __future__ import annotations

import pickle
from pathlib import Path

import pytest

from rhythmic_jax.errors import InputError
from rhythmic_jax.validate import check_features


def test_is_a_value_error():
    assert issubclass(InputError, ValueError)
    with pytest.raises(ValueError, match="bad input"):
        raise InputError("bad input")
    try:
        raise InputError("caught")
    except ValueError as err:  # library callers catch it as a ValueError
        assert type(err) is InputError


@pytest.mark.parametrize(
    ("message", "expected"),
    [
        ("one line", "one line"),
        ("two\nlines", "two lines"),
        ("  lead and trail \n", "lead and trail"),
        ("tabs\tand\r\nCRLF  and   runs", "tabs and CRLF and runs"),
        ("a\n\n\nb", "a b"),
        ("", ""),
    ],
)
def test_message_is_one_line(message, expected):
    err = InputError(message)
    assert str(err) == expected
    assert err.args == (expected,)
    assert "\n" not in str(err) and "\r" not in str(err)


@pytest.mark.parametrize(
    ("message", "expected"),
    [(42, "42"), (Path("a b/c"), "a b/c"), (KeyError("k"), "'k'")],
)
def test_non_string_messages_are_turned_into_text(message, expected):
    assert str(InputError(message)) == expected


def test_survives_pickling():
    err = pickle.loads(pickle.dumps(InputError("x:\n  broken")))
    assert type(err) is InputError and str(err) == "x: broken"


def test_library_messages_stay_one_line():
    """A name holding newlines (a file name, say) still gives one line."""
    with pytest.raises(InputError) as err:
        check_features([1.0, 2.0], name="odd\nname.npy")
    assert str(err.value) == (
        "odd name.npy: expected a 2-D array (frames x features), got shape (2,)"
    )


def test_a_setting_is_named_as_a_parameter_in_the_library_and_a_flag_on_the_cli():
    err = InputError("{option} must be a positive size, got 0", option="tile")
    assert str(err) == "tile must be a positive size, got 0"
    assert err.as_flag() == "--tile must be a positive size, got 0"
    plain = InputError("a {brace} with no option")
    assert str(plain) == plain.as_flag() == "a {brace} with no option"
    assert InputError("{option} x", option="max_iter").as_flag() == "--max-iter x"
    two = InputError("{opt:augment} needs images (folders or {opt:tile})")
    assert str(two) == "augment needs images (folders or tile)"
    assert two.as_flag() == "--augment needs images (folders or --tile)"


def test_library_errors_never_spell_a_flag():
    """Every InputError raised outside the command line names settings by their
    parameter names ({option}), never as --flags."""
    import ast
    import re

    package = Path(__file__).resolve().parents[1] / "rhythmic_jax"
    hits = []
    for path in package.rglob("*.py"):
        if path.name == "cli.py":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            name = getattr(getattr(node, "func", None), "id", None)
            if isinstance(node, ast.Call) and name == "InputError":
                text = " ".join(
                    str(c.value)
                    for arg in node.args
                    for c in ast.walk(arg)
                    if isinstance(c, ast.Constant)
                )
                if re.search(r"(^|\s|\()--[a-z]", text):
                    hits.append(f"{path.name}:{node.lineno}")
    assert not hits, hits
