"""CSV that a spreadsheet opens as data: every text cell inert, numbers as numbers.

A spreadsheet evaluates a cell that starts with ``=``, ``+``, ``-`` or ``@``
(and, in some, a tab or carriage return before one): a frame named
``=HYPERLINK(...)`` or ``+1+cmd|' /C calc'!A0`` would run when the file is
opened (OWASP's "CSV injection"). As OWASP recommends, :func:`inert` puts a
single quote before such a text cell, and :func:`csv_text` quotes every text
cell, so the spreadsheet shows the name as text, quote first.

The quote is added to a text that starts with one of :data:`TRIGGERS` or with a
quote itself, so the rule is reversible: a reader gets the exact name back by
removing one leading ``'`` where a cell starts with one (:func:`name_of`).
Pitts/VPR names stay readable: ``@0543256.96@4178906.70@...`` is written
``'@0543256.96@4178906.70@...``. Numbers (Python or numpy ints and floats; a
place of -1, no match) are written as numbers, unquoted: a number in a numeric
column is not a name. Imports no numpy.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Iterable, Sequence
from typing import Any

__all__ = ["TRIGGERS", "csv_text", "inert", "name_of"]

#: A text starting with one of these is evaluated by some spreadsheet (OWASP).
TRIGGERS = ("=", "+", "-", "@", "\t", "\r")
_QUOTE = "'"


def _is_number(cell: Any) -> bool:
    if isinstance(cell, bool):
        return False
    if isinstance(cell, int | float):
        return True
    kind = type(cell).__module__  # a numpy scalar, without importing numpy
    return kind == "numpy" and hasattr(cell, "dtype") and cell.dtype.kind in "iuf"


def inert(cell: Any) -> Any:
    """A cell a spreadsheet shows as it is: a number as it is (a numpy scalar
    as a Python number), None as an empty cell, anything else as text with a
    ``'`` before it when it starts with one of :data:`TRIGGERS` or a quote."""
    if cell is None:
        return ""
    if _is_number(cell):
        return cell.item() if hasattr(cell, "item") else cell
    text = str(cell)
    if text.startswith((*TRIGGERS, _QUOTE)):
        return _QUOTE + text
    return text


def name_of(cell: str) -> str:
    """The text :func:`inert` was given, from the cell it wrote."""
    return cell[1:] if cell.startswith(_QUOTE) else cell


def csv_text(head: Sequence[str], rows: Iterable[Sequence[Any]]) -> str:
    """CSV of a header and rows (``\\n`` line ends), every cell through
    :func:`inert` and every text cell quoted (``csv.QUOTE_NONNUMERIC``)."""
    buf = io.StringIO()
    out = csv.writer(buf, lineterminator="\n", quoting=csv.QUOTE_NONNUMERIC)
    out.writerow([inert(h) for h in head])
    for row in rows:
        out.writerow([inert(c) for c in row])
    return buf.getvalue()
