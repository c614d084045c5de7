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
