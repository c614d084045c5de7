"""Results per query, as VPR tools save them: each query's answer, whether it is
right, and its K best places.

``evaluate --per-query PATH`` writes :func:`judged` records (``.csv`` or
``.json`` by the suffix, :func:`write_records`): per query its name and row,
the place chosen and its name, the right places, whether the answer is right
(the evaluation's own test: among the right places, within the tolerance), its
score and confidence, and its ``--num-preds`` K best places with their names
and scores (VPR-methods-evaluation's ``--num_preds_to_save``).
``query --pairs PATH`` writes :func:`pairs_text`: hloc's retrieval pairs, one
``query_name reference_name`` line per pair, each query's K best in rank order
(hloc's ``pairs_from_retrieval``), so hloc's local matching takes the map's
answers.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from rhythmic_jax.errors import InputError

__all__ = ["judged", "pairs_text", "write_records"]

SUFFIXES = (".csv", ".json")


def judged(rows: list[dict[str, Any]], right, correct) -> list[dict[str, Any]]:
    """Query records (:func:`rhythmic_jax.app.query_results.records`) with
    ``"right_places"`` (b lists of places) and ``"correct"`` (b bools) added
    after the confidence, and ``"index"`` (the query's row) after its name."""
    out = []
    for r, places, ok in zip(rows, right, correct, strict=True):
        head = {"query": r["query"], "index": r["index"]}
        rest = {k: v for k, v in r.items() if k not in head and k != "top"}
        out.append({**head, **rest, "right_places": [int(p) for p in places],
                    "correct": bool(ok), "top": r["top"]})  # fmt: skip
    return out


def check_suffix(option: str, path: str) -> None:
    """Refuse, before any work, a file name that says neither CSV nor JSON."""
    if Path(path).suffix.lower() not in SUFFIXES:
        raise InputError(f"{{opt:{option}}} {path}: give a .csv or .json file name")


def write_records(path: str, rows: list[dict[str, Any]], about: dict) -> None:
    """Write the records to ``path`` atomically: ``.json`` as ``{**about,
    "queries": rows}``, ``.csv`` one line per query (the right places joined by
    spaces) through the command line's CSV writer."""
    from rhythmic_jax.app.query_results import csv_text
    from rhythmic_jax.io.atomic import write_file

    if Path(path).suffix.lower() == ".json":
        write_file(path, json.dumps({**about, "queries": rows}, indent=1) + "\n")
        return
    flat = [{**r, "right_places": " ".join(map(str, r["right_places"]))} for r in rows]
    write_file(path, csv_text(flat, extra=("index", "right_places", "correct")))


def pairs_text(query_names: list[str], top, place_names: list[str]) -> str:
    """hloc's retrieval pairs: ``query_name reference_name`` per line, each
    query's ranked places (b, K) in rank order, the lines joined by newlines
    as ``pairs_from_retrieval`` writes them (no newline after the last);
    places below 0 (none) are left out. Names holding white space are refused:
    hloc splits each line on it."""
    spaced = next((n for n in [*query_names, *place_names] if len(n.split()) != 1),
                  None)  # fmt: skip
    if spaced is not None:
        raise InputError(
            f"{{opt:pairs}}: the image name {spaced!r} holds white space, which "
            "hloc's pairs files cannot hold"
        )
    lines = []
    for q, ranked in zip(query_names, np.asarray(top).tolist(), strict=True):
        lines += [f"{q} {place_names[p]}" for p in ranked if p >= 0]
    return "\n".join(lines)
