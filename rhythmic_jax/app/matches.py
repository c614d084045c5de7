"""The pictures of ``evaluate --matches``: queries beside the place chosen and
the right place, for a sample of successes and the worst failures.

:func:`pick` chooses the queries (successes spread along the route; failures
the most confident wrong answers first, as they mislead most);
:func:`image_files` finds the frames of an image folder, or of a descriptor
file through the record ``describe`` wrote beside it; :func:`match_rows`
reads only the frames drawn and captions them for
:func:`rhythmic_jax.eval.figures.plot_matches`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from rhythmic_jax.errors import InputError

__all__ = ["image_files", "match_rows", "pick", "query_frames", "reference_folder"]


def pick(correct, confidence, successes: int = 4, failures: int = 4):
    """``(right, wrong)`` query indices: up to ``successes`` right queries
    evenly spaced along the route, and up to ``failures`` wrong ones, the most
    confident first (a no match, confidence None, last)."""
    correct = np.asarray(correct, bool)
    conf = np.asarray([-np.inf if c is None else c for c in confidence], np.float64)
    good = np.flatnonzero(correct)
    if len(good) > successes:
        good = good[np.linspace(0, len(good) - 1, successes).round().astype(int)]
    bad = np.flatnonzero(~correct)
    bad = bad[np.argsort(-conf[bad], kind="stable")][:failures]
    return good.tolist(), bad.tolist()


def image_files(source: str | Path) -> list[Path] | None:
    """The frames of an image folder in route order, or of a descriptor file
    ``describe`` wrote from one (its record names the folder and the frames,
    row by row); None for anything else. Frames named but gone are refused."""
    from rhythmic_jax.io.descriptor_files import read_record
    from rhythmic_jax.io.images import list_images

    path = Path(source)
    if path.is_dir():
        return list_images(path, "image")
    if path.suffix.lower() != ".npy" or not path.is_file():
        return None
    record = read_record(path)
    if record is None or not record.get("frames"):
        return None
    folder = Path(record.get("folder", ""))
    files = [folder / name for name in record["frames"]]
    if not all(f.is_file() for f in files):
        raise InputError(
            f"{{opt:matches}}: the frames {path} was described from are gone from "
            f"{folder}; name their folder with {{opt:query_images}} or "
            "{opt:reference_images}"
        )
    return files


def query_frames(source: str, images: str | None) -> list[Path]:
    """The query frames ``--matches`` draws: the folder ``images`` where
    given, else the queries' own (an image folder, or the folder their
    descriptor file's record names); refused in one line when there is none."""
    files = image_files(images or source)
    if files is None:
        raise InputError(
            f"{{opt:matches}} draws the query frames: give the queries as an image "
            f"folder, or name their folder with {{opt:query_images}} ({source} holds "
            "descriptors that name no frames)"
        )
    return files


def reference_folder(model, reference: str | None, images: str | None = None):
    """The reference frames, one per place (a list of ``model.n`` paths):
    ``images``, else ``reference`` or the first source the map was fitted on,
    an image folder of ``model.n`` frames or a descriptor file naming them;
    refused in one line otherwise."""
    source = (
        images or reference or next(iter(model.reference.get("sources") or []), None)
    )
    files = None if source is None else image_files(source)
    if files is None or "reference_labels" in model.extra:
        what = source or "the map names no source"
        raise InputError(
            f"{{opt:matches}} draws the reference frames: they must be an image "
            f"folder of one frame per place ({what} is not; give "
            "{opt:reference_images} FOLDER)"
        )
    if len(files) < model.n:
        raise InputError(
            f"{{opt:matches}} {source}: {len(files)} frames for {model.n} places"
        )
    return files[: model.n]


def _caption(what: str, place: int, names: list[Path], extra: str = "") -> str:
    if place < 0:
        return f"{what}: no match"
    return f"{what}: place {place}{extra}\n{names[place].name}"


def match_rows(
    result: dict[str, Any],
    queries: list[Path],
    places: list[Path],
    successes: int = 4,
    failures: int = 4,
) -> list[dict[str, Any]]:
    """Rows for :func:`rhythmic_jax.eval.figures.plot_matches` from an
    evaluation kept with curves (``evaluate_map(..., curves=True)``): the map's
    picked queries, right ones first, each with its chosen and right place
    (the chosen one when right, else the middle of its right places) read from
    the files."""
    from rhythmic_jax.io.images import read_rgb

    row = result["methods"]["map"]
    pred, conf, right = row["predictions"], row["confidence"], result["right_places"]
    good, bad = pick(row["correct"], conf, successes, failures)
    out = []
    for q, verdict in [(q, "right") for q in good] + [(q, "wrong") for q in bad]:
        # the right place drawn: the one chosen when it is right, else the middle
        truth = (
            pred[q]
            if pred[q] in right[q]
            else (right[q][len(right[q]) // 2] if right[q] else -1)
        )
        c = conf[q]
        how = "" if c is None else f", confidence {c:.3g}"
        out.append({
            "query": read_rgb(queries[q]),
            "chosen": read_rgb(places[pred[q]]) if pred[q] >= 0 else None,
            "right": read_rgb(places[truth]) if truth >= 0 else None,
            "titles": (f"query {q}: {verdict}\n{queries[q].name}",
                       _caption("chosen", pred[q], places, how),
                       _caption("right", truth, places)),
        })  # fmt: skip
    return out
