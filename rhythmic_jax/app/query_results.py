"""What ``rhythmic-jax query`` says about each query: the place chosen, its score
and confidence, and the K best places with their scores.

:func:`per_query` ranks every place of the map by the scores its decode reads
(:func:`ranked_scores`: the summed phase scores of the map's groups, fused with
the code similarities when the map has codes, accumulated along the sequence for
``--sequence`` on a periods layout) and takes the decode's confidence beside the
predictions. :func:`source_names` and :func:`place_names` name the queries and
the map's places where files carry names (an image folder's file names, an hloc
file's image names; rows of a ``.npy`` are numbered); :func:`records` joins
them, and :func:`csv_text` writes one line per query.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["csv_text", "per_query", "place_names", "ranked_scores", "records",
           "source_names"]  # fmt: skip

HDF5 = (".h5", ".hdf5")


def source_names(source: str | Path, select: str | None = None) -> list[str] | None:
    """The names of a source's rows: an image folder's file names (in the order
    frames are read), an hloc ``.h5`` file's image names (those starting with
    ``select`` when given, as the rows were read), the frames a described
    ``.npy`` file's record names; None for another ``.npy`` file or a tiled
    image (rows are then numbered)."""
    from rhythmic_jax.io.images import list_images

    path = Path(source)
    if path.is_dir():
        return [p.name for p in list_images(path, "query")]
    if path.suffix.lower() == ".npy" and path.is_file():
        from rhythmic_jax.io.descriptor_files import read_record

        record = read_record(path)
        return list(record["frames"]) if record and record.get("frames") else None
    if path.suffix.lower() in HDF5 and path.is_file():
        from rhythmic_jax.io.vpr_files import read_hloc_descriptors

        return list(read_hloc_descriptors(path, select)[0])
    return None


def place_names(model) -> list[str] | None:
    """Place i's name: row i of the first source the map was fitted on, when
    that source still names its rows and has one per place (None otherwise:
    gone, a ``.npy``, tiles, or frames grouped into places by positions)."""
    sources = (model.reference or {}).get("sources") or []
    if not sources or "reference_labels" in model.extra:
        return None
    try:
        names = source_names(sources[0], (model.reference or {}).get("select"))
    except Exception:  # a source that moved or changed: the places stay numbered
        return None
    return names if names is not None and len(names) == model.n else None


def ranked_scores(model, x: np.ndarray, sequence: int | None = None):
    """Every place's score for queries x (b, d): ``(total (b, n), what)``.

    The map's summed phase scores (its groups' evidence), fused with its codes'
    similarities when it has codes; with ``sequence`` L > 1 on a periods
    layout, accumulated over the L frames before each query (speed 1), as the
    sequence decode accumulates them. ``what`` names the scores ranked."""
    from rhythmic_jax.decoding.fusion import code_sequence_scores, fused_place_scores
    from rhythmic_jax.decoding.group_decode import place_scores
    from rhythmic_jax.decoding.queries import queries as embedded
    from rhythmic_jax.decoding.sequence import sequence_scores

    seq = sequence is not None and sequence > 1
    what = f"sequence scores (L={sequence}, speed 1)" if seq else "single-frame scores"
    if seq and model.groups.kind != "periods":
        seq = False  # place-domain sequences keep no per-group scores to rank
        what = "single-frame scores (this layout's sequences keep none)"
    s = model.scores(x)
    if seq:
        s = sequence_scores(s, model.periods, sequence)
    if model.codebook is None:
        return np.asarray(place_scores(s, model.groups, model.n)), what
    sims = model.codebook.similarity(embedded(model.value, x))
    if seq:
        sims = code_sequence_scores(sims, sequence)
    total = fused_place_scores(s, sims, model.periods, model.n, model.config.fusion)
    return np.asarray(total), f"fused {what}"


def per_query(model, x, pred, *, method=None, sequence=None, top: int = 5):
    """Per query of x (b, d) with predictions ``pred`` (b,) (-1: no match):
    ``{"place", "score" (the chosen place's ranked score, NaN for no match),
    "confidence" (the decode's), "top" (b, K) places, "top_scores" (b, K),
    "ranks" (what the scores are)}``."""
    total, what = ranked_scores(model, x, sequence)
    k = min(int(top), model.n)
    top_idx = np.argsort(-total, axis=1, kind="stable")[:, :k]
    top_scores = np.take_along_axis(total, top_idx, axis=1)
    if sequence is not None and sequence > 1:
        from rhythmic_jax.decoding.queries import decode_sequence

        conf = np.asarray(decode_sequence(model.value, x, sequence, method=method)[1])
    else:
        conf = np.asarray(model.decode(x, method).confidence)
    pred = np.asarray(pred, np.int64)
    rows = np.arange(len(pred))
    score = np.where(pred >= 0, total[rows, np.maximum(pred, 0)], np.nan)
    return {"place": pred, "score": score, "confidence": conf.astype(np.float64),
            "top": top_idx, "top_scores": top_scores, "ranks": what}  # fmt: skip


def _number(v) -> float | None:
    """A finite float, or None (JSON has no NaN or inf)."""
    v = float(v)
    return v if np.isfinite(v) else None


def records(result, queries: list[str] | None, places: list[str] | None) -> list:
    """One dict per query: ``{"query", "index", "place", "place_name", "score",
    "confidence", "top": [{"place", "name", "score"}, ...]}``; ``"query"`` is
    its name, a string always (its file's where it has one, else its row
    number), ``"index"`` its row; a place's name is None where the map names
    none (and for no match)."""

    def name(i: int):
        return None if places is None or i < 0 else places[i]

    out: list[dict[str, Any]] = []
    for q, p in enumerate(result["place"].tolist()):
        out.append({
            "query": queries[q] if queries is not None else str(q), "index": q,
            "place": p, "place_name": name(p),
            "score": _number(result["score"][q]),
            "confidence": _number(result["confidence"][q]),
            "top": [{"place": int(j), "name": name(int(j)), "score": _number(s)}
                    for j, s in zip(result["top"][q], result["top_scores"][q],
                                    strict=True)],
        })  # fmt: skip
    return out


def csv_text(rows: list[dict[str, Any]], extra: tuple[str, ...] = ()) -> str:
    """The records as CSV: query, place, place_name, score, confidence, the
    ``extra`` fields of each record (``correct``...), then top{k},
    top{k}_name, top{k}_score for k = 1..K; empty cells for none. Names are
    written inert (:mod:`rhythmic_jax.io.csv_cells`: a name a spreadsheet
    would evaluate gets a leading ``'``), numbers as numbers."""
    from rhythmic_jax.io import csv_cells

    k = max((len(r["top"]) for r in rows), default=0)
    head = ["query", "place", "place_name", "score", "confidence", *extra]
    for i in range(1, k + 1):
        head += [f"top{i}", f"top{i}_name", f"top{i}_score"]
    lines = []
    for r in rows:
        cells = [r["query"], r["place"], r["place_name"], r["score"], r["confidence"]]
        cells += [r[e] for e in extra]
        for t in r["top"]:
            cells += [t["place"], t["name"], t["score"]]
        lines.append(cells)
    return csv_cells.csv_text(head, lines)
