"""Ground truth in the files VPR datasets ship, read without running their code.

* **VPR-Bench** (``DATASET/ref/``, ``DATASET/query/``, ``ground_truth_new.npy``):
  an object array of ``[query_index, [reference indices]]`` rows. An object
  ``.npy`` is a pickle; :func:`read_vpr_bench` unpickles it with an allowlist
  (ints, floats, lists, tuples and plain numpy arrays and scalars; nothing that
  names another callable) and refuses anything else in one line.
* **Positions** of queries and references, in a CSV or ``.npy`` or in
  ``@easting@northing@`` file names, as a fit reads its own
  (:mod:`rhythmic_jax.fitting.places`), matched within a radius.
* **OpenVPRLab** ``<name>_gt_25m.npy``, **VPR_Tutorial** ``GT.npz`` and
  **Patch-NetVLAD** ``.npz`` (``utmQ``, ``utmDb``, ``posDistThr``), read by
  :mod:`rhythmic_jax.io.vpr_files` (:func:`read_openvprlab`,
  :func:`read_tutorial_gt`, :func:`read_patchnetvlad_gt`).

Which format a file is in is read from what it holds
(:func:`rhythmic_jax.eval.ground_truth_formats.detect_format`: the arrays'
names, dtypes and shapes, an object array's rows), not from its name, which
only breaks a tie; ``fmt`` of :func:`load_ground_truth` says it outright.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.eval.ground_truth import GroundTruth, from_lists, from_positions
from rhythmic_jax.eval.ground_truth_formats import FORMATS, detect_format
from rhythmic_jax.fitting.places import (
    in_metres,
    positions_from_names,
    positions_of_sources,
    read_positions,
)
from rhythmic_jax.io.reader import npz_headers
from rhythmic_jax.io.vpr_files import safe_object_npy

__all__ = [
    "idle_tolerance",
    "SoftGroundTruth",
    "load_ground_truth",
    "read_openvprlab",
    "read_patchnetvlad_gt",
    "read_tutorial_gt",
    "read_vpr_bench",
    "safe_object_npy",
]



def _int(v, where: str) -> int:
    if isinstance(v, bool) or not isinstance(v, int | np.integer):
        raise InputError(f"{where}: expected an integer index, found {v!r}"[:200])
    return int(v)


def read_vpr_bench(path: str | Path, n_queries: int, n_places: int) -> GroundTruth:
    """VPR-Bench ``ground_truth_new.npy``: row ``[query_index, [ref indices]]``.

    Every query ``0..n_queries-1`` must have one row; reference indices are map
    places (rows of ``DATASET/ref`` in name order).
    """
    arr = safe_object_npy(path)
    rows = arr.tolist() if arr.dtype.hasobject else arr.tolist()
    lists: dict[int, list[int]] = {}
    for i, row in enumerate(rows):
        where = f"{path}: row {i}"
        if not isinstance(row, list | tuple) or len(row) != 2:
            raise InputError(f"{where}: expected [query_index, [reference indices]]")
        q, refs = row
        refs = refs.tolist() if isinstance(refs, np.ndarray) else refs
        refs = refs if isinstance(refs, list | tuple) else [refs]
        q = _int(q, where)
        if q in lists:
            raise InputError(f"{where}: query {q} appears twice")
        lists[q] = [_int(r, where) for r in refs]
    missing = [q for q in range(n_queries) if q not in lists]
    extra = sorted(q for q in lists if not 0 <= q < n_queries)
    if missing or extra:
        what = f"no row for query {missing[0]}" if missing else f"query {extra[0]}"
        raise InputError(f"{path}: {what} (there are {n_queries} queries)")
    src = f"VPR-Bench ground truth {Path(path).absolute()}"
    return from_lists([lists[q] for q in range(n_queries)], n_places, src)


def load_ground_truth(
    specs: Sequence[str],
    *,
    n_queries: int,
    n_places: int,
    query_source: str,
    reference_sources: Sequence[str] = (),
    map_extra: dict | None = None,
    tolerance_m: float = 25.0,
    fmt: str | None = None,
) -> GroundTruth:
    """What ``evaluate --ground-truth`` reads (see README "Datasets in the formats
    you have"):

    * one file of a VPR tool (VPR-Bench's lists, OpenVPRLab's positives,
      VPR_Tutorial's ``GT.npz``, Patch-NetVLAD's ``.npz``), its format read
      from what it holds (:mod:`rhythmic_jax.eval.ground_truth_formats`) or
      named by ``fmt`` (one of its ``FORMATS``);
    * ``names``: ``@easting@northing@`` names of the reference and query frames;
    * ``QUERY_POSITIONS``: positions of the queries, the reference's saved in the
      map by ``fit --positions``;
    * ``REF_POSITIONS QUERY_POSITIONS``: positions of both.

    Positions give every place with a reference frame within ``tolerance_m``.
    """
    from rhythmic_jax.io.descriptor_files import frame_names

    extra = map_extra or {}
    specs = list(specs)
    if not 1 <= len(specs) <= 2:
        raise InputError("{opt:ground_truth} takes one or two files (or 'names')")
    labels = extra.get("reference_labels")
    if fmt is not None and fmt not in FORMATS:
        raise InputError(f"{{opt:ground_truth_format}} {fmt!r}: one of {FORMATS}")
    if fmt not in (None, "positions") and (len(specs) != 1 or specs == ["names"]):
        raise InputError(
            f"{{opt:ground_truth_format}} {fmt}: one file, not {' '.join(specs)}"
        )
    given = fmt
    if fmt is None and len(specs) == 1 and specs != ["names"]:
        fmt = detect_format(specs[0])
    if specs == ["names"]:
        ref = positions_of_sources(["names"], reference_sources)
        qry = positions_from_names(frame_names(query_source, "query")), "metres"
        src = f"@easting@northing@ names of {query_source} and the reference"
    elif fmt not in (None, "positions"):
        read = _READERS[fmt]
        return read(specs[0], n_queries=n_queries, n_places=n_places)
    else:
        qry = _query_positions(specs[-1], guessed=len(specs) == 1 and given is None)
        if len(specs) == 2:
            ref = read_positions(specs[0])
        elif "reference_positions" in extra:
            unit = "degrees" if int(extra["reference_positions_degrees"]) else "metres"
            ref = np.asarray(extra["reference_positions"]), unit
        else:
            raise InputError(
                f"{{opt:ground_truth}} {specs[0]}: the map holds no reference "
                "positions (fit with {opt:positions}); give REF_POSITIONS "
                "QUERY_POSITIONS"
            )
        src = "positions " + " and ".join(str(Path(s).absolute()) for s in specs)
    ref_m, qry_m = in_metres(ref, qry)
    if len(qry_m) != n_queries:
        raise InputError(
            f"{{opt:ground_truth}}: {len(qry_m)} query positions for "
            f"{n_queries} queries"
        )
    if labels is None or len(labels) != len(ref_m):
        if len(ref_m) % n_places:
            raise InputError(
                f"{{opt:ground_truth}}: {len(ref_m)} reference positions for a map of "
                f"{n_places} places (give one per reference frame)"
            )
        labels = np.arange(len(ref_m)) % n_places  # traversals: row i is place i
    return from_positions(ref_m, qry_m, tolerance_m, labels, src)


def _query_positions(path: str, guessed: bool):
    """The query positions of ``path``; where its format was guessed (one
    file, no ``--ground-truth-format``), a file that is not positions either
    is refused as no ground-truth file at all."""
    try:
        return read_positions(path)
    except InputError as err:
        if not guessed:
            raise
        raise InputError(
            f"{{opt:ground_truth}} {path}: not a ground-truth file (none of "
            f"{', '.join(FORMATS)}; read as positions: {err})"
        ) from None


@dataclass(frozen=True, eq=False)
class SoftGroundTruth(GroundTruth):
    """Hard positives, and soft ones that are not counted wrong (VPR_Tutorial).

    ``soft``: b sorted int64 arrays of the places only in the soft set. Ranked
    candidates (b, K) skip them, as the tutorial's ``recallAtK`` does by
    setting their similarity to the minimum, so recall@K counts the first K
    places that are not soft-only; a single prediction (b,) on a soft-only
    place counts as right.
    """

    soft: tuple[np.ndarray, ...] = ()

    def hits(self, ranked) -> np.ndarray:
        ranked = np.asarray(ranked)
        plain = GroundTruth(self.positives, self.n_places, self.source)
        if ranked.ndim == 1:
            loose = GroundTruth(self.soft, self.n_places, self.source)
            return plain.hits(ranked) | loose.hits(ranked)
        skip = GroundTruth(self.soft, self.n_places, self.source).hits(ranked)
        order = np.argsort(skip, axis=1, kind="stable")  # soft-only to the end
        kept = np.where(np.take_along_axis(skip, order, 1), -1,
                        np.take_along_axis(ranked, order, 1))  # fmt: skip
        return plain.hits(kept)


def read_tutorial_gt(path, *, n_queries: int, n_places: int) -> GroundTruth:
    """VPR_Tutorial ``GT.npz``: hard positives, soft-only places not counted wrong."""
    from rhythmic_jax.io.vpr_files import read_vpr_tutorial

    for key, head in npz_headers(path).items():  # sizes before inflating
        if key in ("GThard", "GTsoft") and len(head.shape) == 2:
            _sizes(path, *head.shape, n_places, n_queries)
    hard, soft = read_vpr_tutorial(path)
    _sizes(path, hard.shape[0], hard.shape[1], n_places, n_queries)
    src = f"VPR_Tutorial GT.npz {Path(path).absolute()} (GThard; GTsoft not wrong)"
    pos = from_lists([np.flatnonzero(c) for c in hard.T], n_places, src).positives
    only = tuple(np.flatnonzero(c) for c in (soft & ~hard).T)
    return SoftGroundTruth(pos, n_places, src, soft=only)


def read_openvprlab(path, *, n_queries: int, n_places: int) -> GroundTruth:
    """OpenVPRLab ``<name>_gt_25m.npy`` positives; the ``<name>_dbImages.npy`` and
    ``<name>_qImages.npy`` beside it, when there, must list as many images."""
    from rhythmic_jax.io.vpr_files import read_image_list, read_openvprlab_positives

    path = Path(path)
    rows = read_openvprlab_positives(path, n_places)
    stem = path.name.split("_gt_")[0]
    sizes = {"db": n_places, "q": len(rows)}
    for tag in sizes:
        lst = path.with_name(f"{stem}_{tag}Images.npy")
        if lst.is_file() and len(read_image_list(lst)) != sizes[tag]:
            raise InputError(
                f"{lst}: {len(read_image_list(lst))} images, but "
                f"{'the map has' if tag == 'db' else path.name + ' has'} {sizes[tag]}"
            )
    _sizes(path, n_places, len(rows), n_places, n_queries)
    src = f"OpenVPRLab positives {path.absolute()}"
    return from_lists(rows, n_places, src)


def read_patchnetvlad_gt(path, *, n_queries: int, n_places: int) -> GroundTruth:
    """Patch-NetVLAD ``.npz``: database places within ``posDistThr`` metres."""
    from rhythmic_jax.io.vpr_files import read_patchnetvlad

    heads = npz_headers(path)  # sizes before inflating
    shapes = [heads[k].shape for k in ("utmDb", "utmQ") if k in heads]
    if len(shapes) == 2 and all(shapes):
        _sizes(path, shapes[0][0], shapes[1][0], n_places, n_queries)
    db, q, thr = read_patchnetvlad(path)
    if not np.isfinite(thr):  # an infinite radius counts every place as right
        raise InputError(f"{path}: posDistThr must be a finite radius, got {thr}")
    _sizes(path, len(db), len(q), n_places, n_queries)
    src = f"Patch-NetVLAD utmDb/utmQ {Path(path).absolute()}"
    gt = from_positions(db, q, thr, None, src)
    return GroundTruth(gt.positives, n_places, src, thr)


def _sizes(path, n_db: int, n_q: int, n_places: int, n_queries: int) -> None:
    if (n_db, n_q) != (n_places, n_queries):
        raise InputError(
            f"{{opt:ground_truth}} {path}: {n_db} database images and {n_q} queries, "
            f"but the map has {n_places} places and there are {n_queries} queries"
        )


def _read_vpr_bench(path, *, n_queries: int, n_places: int) -> GroundTruth:
    return read_vpr_bench(path, n_queries, n_places)


_READERS = {
    "vpr-bench": _read_vpr_bench,
    "openvprlab": read_openvprlab,
    "vpr-tutorial": read_tutorial_gt,
    "patch-netvlad": read_patchnetvlad_gt,
}


def idle_tolerance(truth, given):
    """``truth``, unless ``--tolerance-m`` is among the options ``given`` while
    ``truth`` lists the right places itself (it would act on nothing): refused."""
    if truth.tolerance_m is None and "tolerance_m" in given:
        raise InputError(
            f"{{opt:tolerance_m}} acts on positions; {truth.source} lists the right "
            "places itself, so it would act on nothing"
        )
    return truth
