"""CSV cells a spreadsheet opens as data (:mod:`rhythmic_jax.io.csv_cells`):
read back with the csv module, no text cell starts with a character that makes
a spreadsheet evaluate it (OWASP's list), names come back exact once the one
leading quote is removed, and numbers stay unquoted numbers."""

from __future__ import annotations

import csv
import io

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from rhythmic_jax.io.csv_cells import TRIGGERS, csv_text, inert, name_of

HOSTILE = ["=HYPERLINK(\"http://x\",\"y\")", "+1+cmd|' /C calc'!A0", "-2+3",
           "@SUM(1+1)*cmd|' /C calc'!A0", "\t=1+1", "\r=1", "'=1", "''",
           "@0543256.96@4178906.70@37.7@-122.4@@@@@@pitch1_yaw1@.jpg", "plain.png",
           "a,b\"c\nd", "", "=", " =1"]  # fmt: skip
# what OWASP lists, and what a name's text may hold around it
ALPHABET = st.sampled_from(list("=+-@\t\r'\",;|!$\\_^%{}() aZ0.\n"))


def _read(text: str) -> list[list[str]]:
    return list(csv.reader(io.StringIO(text)))


def _is_inert(cell: str) -> bool:
    return not cell.startswith(TRIGGERS)


def test_formulas_and_markup_are_written_inert_and_read_back_exactly():
    rows = [[name, i, -1, 0.25, None] for i, name in enumerate(HOSTILE)]
    text = csv_text(["name", "place", "none", "score", "empty"], rows)
    back = _read(text)
    assert back[0] == ["name", "place", "none", "score", "empty"]
    for (name, i, *_), row in zip(rows, back[1:], strict=True):
        assert _is_inert(row[0]), row
        assert name_of(row[0]) == name
        assert row[1:] == [str(i), "-1", "0.25", ""]
    assert back[-6][0] == "'@0543256.96@4178906.70@37.7@-122.4@@@@@@pitch1_yaw1@.jpg"
    # numbers are written bare (a spreadsheet reads them as numbers), text quoted
    line = text.splitlines()[1]
    assert line == '"\'=HYPERLINK(""http://x"",""y"")",0,-1,0.25,""'


def test_numpy_numbers_stay_numbers_and_booleans_are_text():
    text = csv_text(["a", "b", "c", "d"], [[np.int64(-3), np.float32(0.5), True,
                                             np.nan]])  # fmt: skip
    assert text.splitlines()[1] == '-3,0.5,"True",nan'
    assert inert(np.int64(-3)) == -3 and type(inert(np.int64(-3))) is int


@settings(max_examples=300, deadline=None, database=None, derandomize=True)
@given(st.lists(st.text(ALPHABET, max_size=12), min_size=1, max_size=6))
def test_every_drawn_name_is_inert_and_round_trips(names):
    back = _read(csv_text([f"n{i}" for i in range(len(names))], [names]))[1]
    assert len(back) == len(names)
    for name, cell in zip(names, back, strict=True):
        assert _is_inert(cell), (name, cell)
        assert name_of(cell) == name
        assert cell == name or cell == "'" + name
