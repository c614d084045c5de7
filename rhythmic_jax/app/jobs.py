"""Running the jobs of ``rhythmic-jax``, as library functions notebooks call too.

Each function takes a job of :mod:`rhythmic_jax.app.specs` (which checked its
settings when it was made) and does its work:

- :func:`fit`: the augmented fit's settings and checkpoint folder and the
  fit's plan (from descriptor files' headers when it can, so a
  fit too large for memory ends before they are read) settled first, the
  sources read, the map fitted (plainly, or over frames augmented on the fly
  with a resumable checkpoint folder, default ``OUT.ckpt``, removed once the map
  is saved), provenance recorded (the sources' absolute paths and tiling, so
  that ``evaluate`` finds the reference frames again), the map saved atomically;
  a fit from files at scale is :mod:`rhythmic_jax.app.scale_jobs`;
- :func:`learn`: an embedding (and the fusion weight for its codes,
  :mod:`rhythmic_jax.app.fusion`) learned and saved;
- :func:`query`: queries described the way the map was built, localised, and
  predictions written atomically;
- :func:`info`, :func:`evaluate` (beside brute force over the map's own
  reference frames when they are still there).

Nothing here prints: the command line shows what they return through
:mod:`rhythmic_jax.app.render`, and checks where a job writes before it runs
(a failed write said there in one line, :mod:`rhythmic_jax.app.cli`).
"""

from __future__ import annotations

import contextlib
import shutil
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

from rhythmic_jax.app.fusion import learn_fusion
from rhythmic_jax.app.specs import (
    DescribeJob,
    EvaluateJob,
    FitInterrupted,
    FitJob,
    LearnJob,
    QueryJob,
    Reading,
)
from rhythmic_jax.errors import InputError

if TYPE_CHECKING:
    import numpy as np

__all__ = [
    "describe", "evaluate", "fit", "info", "learn", "query", "query_results",
    "quiet_io_threads",
]  # fmt: skip


def quiet_io_threads() -> None:
    """Keep orbax's late "Event loop is closed" reports (its I/O threads answering
    after a failed map read or write) off stderr for the rest of the process."""
    import sys

    from rhythmic_jax.io.checkpoint import without_closed_loop

    sys.unraisablehook = without_closed_loop(sys.unraisablehook)


class Settled(NamedTuple):
    """What a fit's settings and its sources' headers decide before any source
    is read (:func:`_before_reading`)."""

    augmented: tuple[Any, Path] | None  # (AugmentedFit, checkpoint folder)
    learned: tuple[Any, dict] | None  # (embedding, meta) of fit --embedding
    placed: tuple[Any, dict] | None  # (place labels or None, positions kept)
    reading: Reading  # with the embedding's descriptor for images naming none
    reference: dict[str, Any]  # the map's provenance besides its sources
    fusion: float  # the map's share of a fused score
    plan: Any  # the FitPlan, or None where only reading the sources tells


def _before_reading(job: FitJob) -> Settled:
    """What a fit's settings and its sources' headers decide, refused before
    any source is read: the frames' positions and their places
    (:func:`rhythmic_jax.fitting.places.frame_places`), the augmented
    fit's settings (and checkpoint folder), the embedding of ``fit
    --embedding`` and the reading of the sources it implies (its descriptor and
    weights, for images that name none), the fusion weight, the map's
    provenance (the sources' absolute paths and tiling, so that
    :func:`evaluate` finds the reference frames again; the embedding and the
    fusion weight), for descriptor files of one shape the plan and its
    memory. The plan is None where only reading the sources tells
    (images, files missing or of other shapes, ``pca``, ``places``, an
    embedding of another dimension: reading them says what is wrong).
    """
    from rhythmic_jax.fitting.fit_plan import plan as plan_fit
    from rhythmic_jax.fitting.places import frame_places, positions_of_sources
    from rhythmic_jax.io.descriptor_files import descriptor_shape
    from rhythmic_jax.map.embedding import (
        embedding_descriptor,
        fusion_of,
        load_embedding,
    )

    augmented = learned = placed = fit_plan = None
    read, sources = job.reading, job.sources
    if job.positions is not None:  # a bad file is refused before any frame is read
        located = positions_of_sources(job.positions, sources)
        placed = frame_places(located, job.places)  # k-means: before reading too
    if job.augment:
        from rhythmic_jax.augment.kornia_ops import AugmentConfig
        from rhythmic_jax.augment.stream import AugmentedFit

        if job.pca is not None:
            raise InputError("{opt:augment} and {opt:pca} together are not supported")
        names = tuple(job.augment.split(","))
        AugmentConfig(names=names)  # unknown names end here, not after describing
        shape = ("epochs", "batch_size", "checkpoint_every")  # else AugmentedFit's
        given = {k: getattr(job, k) for k in shape if getattr(job, k) is not None}
        augmented = AugmentedFit(names=names, **given), job.checkpoint_folder
    if job.embedding is not None:
        learned = load_embedding(job.embedding)
        name, weights = embedding_descriptor(learned[1])
        if read.descriptor is None and name is not None and job.images:
            read = replace(read, descriptor=name, weights=read.weights or weights,
                           input_size=read.input_size or _size_of(learned[1]))
    fusion = fusion_of(job.fusion, job.config.codes, (learned or (None, None))[1])
    ref = {"tile": read.tile, "stride": read.stride}
    if read.select is not None:
        ref["select"] = read.select  # brute force reads the same rows
    if job.embedding is not None:
        ref["embedding"] = str(Path(job.embedding).expanduser().absolute())
        ref["descriptor_from_embedding"] = read != job.reading
    if job.config.codes is not None:
        ref["fusion"] = fusion
    files = (
        job.pca is None
        and job.places is None
        and all(s.lower().endswith(".npy") and Path(s).is_file() for s in sources)
    )
    shapes = {descriptor_shape(s) for s in sources} if files else set()
    shape = shapes.pop() if len(shapes) == 1 else ()
    n, d = shape if len(shape) == 2 and 0 not in shape else (0, 0)
    if n and (learned is None or learned[0].d == d):
        k = d if learned is None else learned[0].k
        fit_plan = plan_fit(job.config, n, k, n * len(sources))
    return Settled(augmented, learned, placed, read, ref, fusion["weight"], fit_plan)


def fit(job: FitJob, progress: bool = False):
    """Fit, record provenance and save the map of ``job``; returns the map
    (a :class:`~rhythmic_jax.decoding.held.HeldMap` of the fitted
    :class:`~rhythmic_jax.map.pytree.Map`).

    Everything the settings alone decide is refused before any source is read
    (:func:`_before_reading`: for descriptor files the fit's plan and the memory
    it needs, from their headers); for images the plan once they are read, with
    the disk the map needs before the solve. The one plan is the fit's
    (:func:`rhythmic_jax.fitting.fit_plan.plan`), and the fit is
    :func:`rhythmic_jax.fitting.fit_map.fit`; the frames' positions and places
    are :func:`rhythmic_jax.fitting.places.frame_places`. An augmented fit (image
    sources) keeps a checkpoint folder, default ``OUT.ckpt``, removed once the
    map is saved; Ctrl-C raises :class:`FitInterrupted`, which says where it is
    kept.
    """
    import numpy as np

    from rhythmic_jax.decoding.held import HeldMap
    from rhythmic_jax.fitting.fit_map import fit as fit_map
    from rhythmic_jax.fitting.fit_plan import plan as plan_fit
    from rhythmic_jax.frames.sources import load_sources
    from rhythmic_jax.io.checkpoint import check_space
    from rhythmic_jax.map import map_file
    from rhythmic_jax.validate import frames_digest

    augmented, learned, placed, read, ref, weight, fit_plan = _before_reading(job)
    feats = load_sources(
        job.sources, read.descriptor, read.tile, read.stride, progress,
        pca=job.pca, weights=read.weights, same_length=job.places is None,
        compile=read.compile, keep_images=augmented is not None, select=read.select,
        input_size=_input_size(read),
    )  # fmt: skip
    emb, meta = learned or (None, None)
    if meta is not None and meta.get("descriptor") != feats.descriptor:
        raise InputError(
            f"{{opt:embedding}} {job.embedding}: learned on "
            f"{meta.get('descriptor')!r} descriptors, the map's are "
            f"{feats.descriptor!r}"
            + ("; files that name no descriptor: declare it with {opt:descriptor}"
               if feats.descriptor == "features" else "")
        )
    if meta is not None and _size_of(meta) not in (None, _size_of(feats.settings)):
        raise InputError(
            f"{{opt:embedding}} {job.embedding}: learned on frames described at "
            f"{_size_of(meta)}, the map's at {_size_of(feats.settings)}"
        )
    if emb is not None and emb.d != feats.x.shape[1]:
        raise InputError(
            f"{{opt:embedding}} {job.embedding}: expects {emb.d}-d descriptors, "
            f"got {feats.x.shape[1]}"
        )
    labels, extra = feats.labels, feats.extra
    if placed is not None:
        places, kept = placed
        xy = kept["reference_positions"]
        if len(xy) != len(feats.x):
            raise InputError(f"{{opt:positions}}: {len(xy)} positions for "
                             f"{len(feats.x)} reference frames")  # fmt: skip
        labels = labels if places is None else places
        extra = {**extra, **kept}
    if fit_plan is None:
        d = feats.x.shape[1] if emb is None else emb.k
        fit_plan = plan_fit(job.config, int(labels.max()) + 1, int(d), len(feats.x))
    config = replace(
        job.config, descriptor=feats.descriptor, descriptor_settings=feats.settings,
        fusion=weight,
    )  # fmt: skip
    stored = sum(np.asarray(v).nbytes for v in extra.values())
    check_space(job.out, fit_plan.largest_bytes + stored)  # said before the solve
    with _augmenting(augmented, feats, labels, read, progress) as refine:
        fitted = fit_map(feats.x, config, labels=labels, embedding=emb,
                         progress=progress, refine=refine, plan=fit_plan)  # fmt: skip
    if job.pca is None and all(str(s).lower().endswith(".npy") for s in job.sources):
        ref = {**ref, "frames_sha256": frames_digest(feats.x)}  # evaluate --reference
    fitted = replace(fitted, extra={**fitted.extra, **extra},
                     reference=map_file.reference(job.sources, **ref))  # fmt: skip
    map_file.save(job.out, fitted)
    if augmented is not None and job.checkpoint is None:
        shutil.rmtree(augmented[1], ignore_errors=True)  # the map holds the result
    return HeldMap(fitted)


def _input_size(read: Reading) -> tuple[int, int] | None:
    """``--input-size`` as (width, height), or None (the descriptor's own)."""
    from rhythmic_jax.frames.sources import parse_input_size

    return parse_input_size(read.input_size)


def _size_of(record: dict | None) -> str | None:
    """``"WxH"`` recorded in descriptor settings (or an embedding's meta, under
    ``descriptor_settings``), or None where none is recorded."""
    settings = (record or {}).get("descriptor_settings", record) or {}
    if settings.get("width") is None:
        return None
    return f"{settings['width']}x{settings['height']}"


@contextlib.contextmanager
def _augmenting(augmented, feats, labels, read: Reading, progress: bool):
    """The fit's ``refine`` over frames augmented on the fly
    (:func:`rhythmic_jax.augment.stream.refining`), or None for a plain fit;
    within, a checkpoint that cannot be written is one line, and Ctrl-C raises
    :class:`FitInterrupted`, which says where the checkpoint is kept."""
    if augmented is None:
        yield None
        return
    from rhythmic_jax.app import signals
    from rhythmic_jax.augment.stream import refining
    from rhythmic_jax.frames.compiled import FastDescriptor

    if feats.images is None:
        raise InputError(
            "{opt:augment} needs image sources (folders or {opt:tile}), not .npy"
        )
    config, ckpt = augmented
    frames = len(feats.images) * config.epochs  # frames the network will see
    kept = (f"the augmented fit's checkpoint is kept in {ckpt}; run the same "
            "command again to resume")  # fmt: skip
    signals.set_note(kept)
    refine = refining(
        feats.images, feats.x, labels,
        FastDescriptor(feats.describer, frames, read.compile), config,
        progress=progress, checkpoint=ckpt,
    )  # fmt: skip
    try:
        yield refine
    except KeyboardInterrupt:
        raise FitInterrupted(kept) from None


def learn(job: LearnJob, progress: bool = True) -> tuple[Any, dict[str, Any]]:
    """Learn, save and return ``(embedding, info)`` of ``job``; with ``job.codes``
    also the fusion weight for them (``info["fusion"]``, saved beside it), on
    the learning places. ``info["held_out"]``: the codes' recall on the places
    held out of learning (:func:`rhythmic_jax.fitting.learn.learn_embedding`,
    which warns when the embedding does worse there than the raw descriptors)."""
    import numpy as np

    from rhythmic_jax.fitting.learn import LearnConfig, learn_embedding
    from rhythmic_jax.frames.sources import load_sources
    from rhythmic_jax.map.embedding import save_embedding

    if len(job.sources) < 2:
        raise InputError("learn needs two or more traversals of the training route")
    bits = isinstance(job.codes, int) and not isinstance(job.codes, bool)
    if job.codes not in (None, "int8") and not (bits and job.codes >= 1):
        raise InputError(
            f"{{opt:codes}} must be a number of bits >= 1 or int8, got {job.codes}"
        )
    config = job.config or LearnConfig()
    if bits and job.codes > config.k:
        raise InputError(
            f"{{opt:codes}} {job.codes}: at most k={config.k} bits (the embedding's "
            "dimension)"
        )
    read = job.reading
    feats = load_sources(
        job.sources, read.descriptor, read.tile, read.stride, progress,
        weights=read.weights, compile=read.compile, keep_images=False,
        input_size=_input_size(read),
    )  # fmt: skip
    traversals = np.split(feats.x, len(job.sources))
    emb, info = learn_embedding(traversals, config, codes=job.codes or "int8")
    if job.codes is not None:  # on the learning places only, as the embedding
        import warnings

        from rhythmic_jax.solvers.newton import FitWarning

        learning = [t[: info["learn_places"]] for t in traversals]
        with warnings.catch_warnings():  # its maps are a means: their fits unsaid
            warnings.simplefilter("ignore", FitWarning)
            info["fusion"] = learn_fusion(learning, emb, job.codes)
    meta = dict(
        descriptor=feats.descriptor,
        descriptor_settings=feats.settings,
        learn={k: v for k, v in info.items() if k not in ("val_loss", "fusion")},
        sources=[str(Path(s).expanduser().absolute()) for s in job.sources],
        fusion=info.get("fusion"),
    )
    save_embedding(job.out, emb, meta)
    info["traversals"] = len(job.sources)
    return emb, info


def describe(job: DescribeJob, progress: bool = False) -> np.ndarray:
    """The descriptors (n, d) float32 of ``job``'s frames, written to ``job.out``
    (:func:`rhythmic_jax.frames.route_descriptors.describe_frames`)."""
    from rhythmic_jax.frames.route_descriptors import describe_frames

    read = job.reading
    return describe_frames(
        job.source, read.descriptor, weights=read.weights, tile=read.tile,
        stride=read.stride, out=job.out, progress=progress, compile=read.compile,
        input_size=_input_size(read),
    )  # fmt: skip


def _load_queries(job, progress: bool):
    from rhythmic_jax.decoding.held import HeldMap
    from rhythmic_jax.frames.sources import load_query_source
    from rhythmic_jax.map import map_file

    model, read = HeldMap(map_file.load(job.map)), job.reading
    feats = load_query_source(
        job.source, model, read.descriptor, read.tile, read.stride, progress,
        weights=read.weights, compile=read.compile, select=read.select,
        input_size=_input_size(read),
    )  # fmt: skip
    return model, feats


def query(job: QueryJob, progress: bool = False) -> np.ndarray:
    """The predicted places of ``job``'s queries: (b,) int64, ``-1`` no match."""
    return _queried(job, progress)[2]


def query_results(job: QueryJob, progress: bool = False) -> dict[str, Any]:
    """``job``'s queries one by one (:mod:`rhythmic_jax.app.query_results`):
    ``{"predictions" (b,), "queries": [{"query" (its name, a string),
    "index", "place", "place_name", "score", "confidence", "top": [{"place",
    "name", "score"}] * top}], "ranks", "decode", "sequence"}``, each record
    with ``"correct"`` under ``job.ground_truth``; with ``job.csv`` the records
    are also written there as CSV, with ``job.pairs`` hloc's retrieval pairs
    (atomically)."""
    from rhythmic_jax.app import query_results as qr

    model, feats, pred = _queried(job, progress)
    result = qr.per_query(model, feats.x, pred, method=job.decode,
                          sequence=job.sequence, top=job.top)  # fmt: skip
    queries = qr.source_names(job.source, job.reading.select)
    rows = qr.records(result, queries, qr.place_names(model))
    extra: tuple[str, ...] = ()
    truth = _ground_truth(job, model, len(pred))
    if truth is not None:
        for r, ok in zip(rows, truth.hits(pred).tolist(), strict=True):
            r["correct"] = bool(ok)
        extra = ("correct",)
    if job.pairs:
        _write_pairs(job, model, queries, result["top"])
    if job.csv:
        from rhythmic_jax.io.atomic import write_file

        write_file(job.csv, qr.csv_text(rows, extra=extra))
    return {"predictions": pred.tolist(), "queries": rows, "ranks": result["ranks"],
            "decode": job.decode or model.config.decode, "sequence": job.sequence}


def _write_pairs(job: QueryJob, model, queries, top) -> None:
    """``query --pairs``: hloc's retrieval pairs of the K best places
    (:func:`rhythmic_jax.app.per_query.pairs_text`); queries and places must
    have names."""
    from rhythmic_jax.app import query_results as qr
    from rhythmic_jax.app.per_query import pairs_text
    from rhythmic_jax.io.atomic import write_file

    places = qr.place_names(model)
    if queries is None or places is None:
        what = "queries" if queries is None else "map's places"
        raise InputError(
            f"{{opt:pairs}}: the {what} have no names (hloc's pairs name images); "
            "give image folders, hloc .h5 files or .npy files describe wrote"
        )
    write_file(job.pairs, pairs_text(queries, top, places))


def _queried(job: QueryJob, progress: bool):
    """``(map, query features, predictions (b,) int64)`` of ``job``, the
    predictions written to ``job.out`` (``.npy``) when given."""
    import numpy as np

    out = job.out
    model, feats = _load_queries(job, progress)
    from rhythmic_jax.decoding import held

    pred = held.predict(
        model.value, feats.x, job.decode, sequence=job.sequence,
        threshold=job.threshold,
    )  # fmt: skip
    pred = np.asarray(pred).astype(np.int64)
    if out:
        from rhythmic_jax.io.atomic import save_npy

        save_npy(out, pred)
    return model, feats, pred


def info(map_path: str) -> dict[str, Any]:
    """What a map holds (:func:`rhythmic_jax.map.map_file.describe`), read from disk.

    A map whose metadata is complete and consistent, with its arrays listed as
    saved, is described from ``map.json`` alone (no JAX, no array data read); any
    other goes through :func:`rhythmic_jax.map.map_file.load`, which says what is
    wrong with it (:func:`rhythmic_jax.map.map_file.info`).
    """
    from rhythmic_jax.map import map_file

    return map_file.info(map_path, _loaded_info)


def _loaded_info(map_path: str) -> dict[str, Any]:
    from rhythmic_jax.map import map_file

    return map_file.describe(map_file.load(map_path))


def _ground_truth(job, model, b: int, reference: str | None = None):
    """The GroundTruth of ``job.ground_truth`` for ``b`` queries of ``model``
    (None without one); ``--tolerance-m`` given for a file that lists the right
    places itself (it would act on nothing) is refused."""
    if job.ground_truth is None:
        return None
    from rhythmic_jax.eval.ground_truth_files import idle_tolerance, load_ground_truth

    refs = [reference] if reference else model.reference.get("sources") or []
    truth = load_ground_truth(
        job.ground_truth, n_queries=b, n_places=model.n,
        query_source=job.source, reference_sources=refs, map_extra=model.extra,
        tolerance_m=job.tolerance_m, fmt=job.ground_truth_format,
    )  # fmt: skip
    return idle_tolerance(truth, job.given)


def _write_per_query(job: EvaluateJob, model, x, result: dict) -> None:
    """``evaluate --per-query``: each query's answer judged as the evaluation
    judged it (:mod:`rhythmic_jax.app.per_query`), written atomically."""
    from rhythmic_jax.app import query_results as qr
    from rhythmic_jax.app.per_query import judged, write_records

    row = result["methods"]["map"]
    pred = row["predictions"]
    scored = qr.per_query(model, x, pred, method=job.decode, sequence=job.sequence,
                          top=job.num_preds)  # fmt: skip
    names = qr.source_names(job.source, job.reading.select)
    rows = judged(qr.records(scored, names, qr.place_names(model)),
                  result["right_places"], row["correct"])  # fmt: skip
    about = {k: result[k] for k in ("ground_truth", "decode", "sequence",
                                    "tolerance")}  # fmt: skip
    about["ranks"] = scored["ranks"]
    write_records(job.per_query, rows, about)
    result["per_query"] = str(job.per_query)


def evaluate(job: EvaluateJob, progress: bool = False) -> dict[str, Any]:
    """Judge the map on the queries of ``job`` beside brute force, a baseline at
    the map's bytes and, for an embedded map, brute force on the embedding
    (:func:`rhythmic_jax.eval.report.evaluate_map`: every row timed from the
    query descriptors to a place); ``reference_note`` says which frames they
    searched, or why there are no such lines."""
    from rhythmic_jax.app.specs import recall_values
    from rhythmic_jax.eval.report import evaluate_map
    from rhythmic_jax.frames.sources import reference_features
    from rhythmic_jax.validate import check_reference, frames_digest

    plot, reference, read = job.plot, job.reference, job.reading
    drawn = None
    if job.matches:
        from rhythmic_jax.app import matches

        drawn = matches.query_frames(job.source, job.query_images)
    model, feats = _load_queries(job, progress)
    if drawn is not None and len(drawn) != len(feats.x):
        raise InputError(f"{{opt:matches}}: {len(drawn)} query frames for "
                         f"{len(feats.x)} queries")  # fmt: skip
    places = None if drawn is None else matches.reference_folder(
        model, reference, job.reference_images)
    ref, labels, note = reference_features(
        model, reference, read.descriptor, read.tile, read.stride, progress,
        weights=read.weights, compile=read.compile,
    )  # fmt: skip
    grouped = model.extra.get("reference_labels")  # frames grouped into places
    if ref is not None and reference:
        kept = model.reference.get("frames_sha256")  # fitted on descriptor files
        check_reference(len(ref), model.n if grouped is None else len(grouped),
                        reference, kept and frames_digest(ref), kept)  # fmt: skip
    if ref is not None and grouped is not None:
        labels = grouped
    truth = _ground_truth(job, model, len(feats.x), reference)
    result = evaluate_map(
        model, feats.x, reference=ref, reference_labels=labels, tolerance=job.tolerance,
        method=job.decode, sequence=job.sequence, ground_truth=truth,
        curves=bool(plot or drawn or job.per_query), recall_over=job.recall_over,
        recall_values=recall_values(job.recall_values),
    )  # fmt: skip
    result["reference_note"] = note
    if job.per_query:
        _write_per_query(job, model, feats.x, result)
    if plot:
        from rhythmic_jax.eval.figures import plot_evaluation

        plot_evaluation(result, path=plot)
        result["plot"] = str(plot)
    if drawn is not None:
        from rhythmic_jax.eval.figures import plot_matches

        rows = matches.match_rows(result, drawn, places)
        plot_matches(rows, path=job.matches)
        result["matches"] = str(job.matches)
    for row in result["methods"].values():  # the figures' data, not the summary's
        for key in ("pr_curve", "recall_curve", "predictions", "confidence", "correct"):
            row.pop(key, None)
    result.pop("right_places", None)
    return result
