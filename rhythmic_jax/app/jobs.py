"""Jobs: what ``rhythmic-jax`` runs, as library functions notebooks call too.

A job is the policy around the library's pieces, written once:

- :func:`fit`: settings checked before any work (the map folder, the augmented
  fit's settings and checkpoint folder, the memory a full-batch fit needs), the
  sources read, the map fitted (plainly, or over frames augmented on the fly with
  a resumable checkpoint folder, default ``OUT.ckpt``, removed once the map is
  saved), provenance recorded (the sources' absolute paths and tiling, so that
  ``evaluate`` can find the reference frames again), the map saved atomically;
- :func:`query`: queries described the way the map was built, localised, and
  predictions written atomically;
- :func:`info`, :func:`evaluate` (beside brute force over the map's own
  reference frames when they are still there), :func:`demo`.

Errors name settings by parameter (``{opt:tile}``); the command line spells them
as flags. Nothing here prints; the ``*_summary`` functions return the lines the
command line shows.
"""

from __future__ import annotations

import shutil
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from rhythmic_jax.app.scale_jobs import ScaleJob, fit_scaled, wants_scale
from rhythmic_jax.errors import InputError
from rhythmic_jax.frames.compiled import (
    AUTO,
    BUILD_MIN_FRAMES,
    COMPILE_MODES,
    LOAD_MIN_FRAMES,
    CompilePolicy,
)
from rhythmic_jax.map.config import MapConfig
from rhythmic_jax.validate import Domain, check_int, int_option, number_option

__all__ = [
    "FitInterrupted",
    "FitJob",
    "Reading",
    "ScaleJob",
    "BUILD_MIN_FRAMES",
    "COMPILE_MODES",
    "CompilePolicy",
    "Domain",
    "LOAD_MIN_FRAMES",
    "augmentation_ablation",
    "demo",
    "evaluate",
    "evaluate_summary",
    "fit",
    "fit_scaled",
    "fit_summary",
    "FitInterrupted",
    "FitJob",
    "fusion_of",
    "info",
    "info_lines",
    "learn",
    "learn_fusion",
    "learn_summary",
    "LearnJob",
    "learn_config",
    "memory_bytes",
    "query",
    "int_option",
    "number_option",
    "query_summary",
    "quiet_io_threads",
    "wants_scale",
]


@dataclass(frozen=True)
class Reading:
    """How frames are read from a source (see :mod:`rhythmic_jax.frames.sources`).

    Attributes:
      descriptor: descriptor of image sources (a map remembers its own).
      weights: weights file of a descriptor that needs one; when querying a map,
        a moved copy of the file it was fitted with (its sha256 is checked).
      tile: cut one large image into tiles of this size.
      stride: the tiles' stride (default ``tile // 2``).
      compile: when a descriptor network runs compiled for this CPU
        (:class:`rhythmic_jax.frames.compiled.CompilePolicy`; by default when the job
        is large enough for compiling to pay).
    """

    descriptor: str | None = None
    weights: str | None = None
    tile: int | None = None
    stride: int | None = None
    compile: CompilePolicy = AUTO


@dataclass(frozen=True)
class FitJob:
    """A map to fit from reference sources and write to ``out``.

    ``rhythmic-jax fit ref.npy --out route.map`` is ``fit(FitJob(("ref.npy",),
    "route.map"))``. ``config`` is the map's :class:`rhythmic_jax.MapConfig` (its
    descriptor is the sources', and its fusion weight ``fusion``'s); ``pca``
    projects the descriptors to that many dimensions first. ``augment``
    (comma-separated kornia operation names, or ``"all"``) trains over frames
    augmented on the fly for ``epochs`` passes of ``batch_size`` frames,
    checkpointed every ``checkpoint_every`` steps in ``checkpoint`` (default
    ``OUT.ckpt``, removed once the map is saved; a given folder is kept).
    ``positions`` (one CSV/.npy per source, or ``("names",)`` for
    ``@easting@northing@`` file names) are saved in the map for :func:`evaluate`'s
    ground truth; ``places`` groups the frames into that many places by k-means
    over them (the RobotCar protocol; traversals may then differ in length).
    ``embedding`` names a folder written by :func:`learn`: it is saved inside the
    map and applied to every query (with codes, ITQ is fitted on the embedded
    reference frames); image sources are described with its descriptor unless
    ``reading`` names one, and ``fusion`` None takes the weight it learned for
    the config's codes (else 0.5, the weight without one).
    """

    sources: tuple[str, ...]
    out: str
    config: MapConfig = field(default_factory=MapConfig)
    pca: int | None = None
    augment: str | None = None
    epochs: int = 3
    batch_size: int = 128
    checkpoint: str | None = None
    checkpoint_every: int = 50
    fusion: float | None = None
    reading: Reading = Reading()
    positions: tuple[str, ...] | None = None
    places: int | None = None
    embedding: str | None = None


def memory_bytes(text: str) -> int:
    """``--memory``'s text (``1GiB``, ``800M``) in bytes; ``ValueError`` when it
    is no size (:func:`rhythmic_jax.fitting.scale_fit.parse_bytes`)."""
    from rhythmic_jax.fitting.scale_fit import parse_bytes

    return parse_bytes(text)


def _check_reading(reading: Reading) -> None:
    if reading.stride is not None and reading.tile is None:
        from rhythmic_jax.frames.sources import STRIDE_NEEDS_TILE

        raise InputError(STRIDE_NEEDS_TILE)


def quiet_io_threads() -> None:
    """Keep orbax's late "Event loop is closed" reports (its I/O threads answering
    after a failed map read or write) off stderr for the rest of the process."""
    import sys

    from rhythmic_jax.io.checkpoint import without_closed_loop

    sys.unraisablehook = without_closed_loop(sys.unraisablehook)


class FitInterrupted(KeyboardInterrupt):
    """Ctrl-C during an augmented fit; ``note`` says where its checkpoint is kept."""

    def __init__(self, note: str):
        super().__init__(note)
        self.note = note


def _augmented_settings(job: FitJob):
    """The augmented fit's settings and checkpoint folder, checked before any work."""
    from rhythmic_jax.augment.kornia_ops import AugmentConfig
    from rhythmic_jax.augment.stream import AugmentedFit

    if job.pca is not None:
        raise InputError("{opt:augment} and {opt:pca} together are not supported")
    for name in ("epochs", "batch_size", "checkpoint_every"):
        value = getattr(job, name)
        check_int(value, name, 1, msg=f"{{opt:{name}}} must be >= 1, got {value}")
    names = tuple(job.augment.split(","))
    AugmentConfig(names=names)  # unknown names end here, not after describing
    config = AugmentedFit(
        names=names,
        epochs=job.epochs,
        batch_size=job.batch_size,
        checkpoint_every=job.checkpoint_every,
    )
    ckpt = Path(job.checkpoint or str(Path(job.out)) + ".ckpt").absolute()
    if ckpt.exists() and not ckpt.is_dir():
        raise InputError(f"{{opt:checkpoint}} {ckpt}: a file, not a folder")
    return config, ckpt


def _fit_augmented(
    model,
    feats,
    config,
    ckpt: Path,
    progress: bool,
    policy: CompilePolicy = AUTO,
    fit_plan=None,
) -> None:
    from rhythmic_jax.augment.stream import fit_map_augmented
    from rhythmic_jax.frames.compiled import FastDescriptor

    if feats.images is None:
        raise InputError(
            "{opt:augment} needs image sources (folders or {opt:tile}), not .npy"
        )
    frames = len(feats.images) * config.epochs  # frames the network will see
    descriptor = FastDescriptor(feats.describer, frames, policy)
    try:
        fit_map_augmented(
            model, feats.images, feats.x, descriptor, config, feats.labels,
            progress=progress, checkpoint=ckpt, plan=fit_plan,
        )  # fmt: skip
    except KeyboardInterrupt:
        raise FitInterrupted(
            f"the augmented fit's checkpoint is kept in {ckpt}; "
            "run the same command again to resume"
        ) from None


def _check_sources_memory(sources: Sequence[str], config: MapConfig) -> None:
    """Refuse descriptor files too large for a full-batch fit, from their headers.

    Only ``.npy`` sources that exist are looked at (anything else is reported
    when it is read), planned with ``config``
    (:func:`rhythmic_jax.fitting.fit_plan.plan`); settings that plan no fit are left to
    the fit to report. See :func:`rhythmic_jax.solvers.memory.check_memory`.
    """
    from rhythmic_jax.fitting.fit_plan import plan
    from rhythmic_jax.io.descriptor_files import descriptor_shape

    if not all(s.lower().endswith(".npy") and Path(s).is_file() for s in sources):
        return
    shapes = [descriptor_shape(s) for s in sources]
    if any(len(s) != 2 or s != shapes[0] for s in shapes) or 0 in shapes[0]:
        return  # reading them says what is wrong
    n, d = shapes[0]
    try:
        fit_plan = plan(replace(config, codes=None), n, d)
    except InputError:
        return  # the map's settings say what is wrong
    fit_plan.check_memory(n * len(shapes))


def fit(job: FitJob, progress: bool = False):
    """Fit, record provenance and save the map of ``job``; returns the map.

    Everything the settings alone decide is refused before any source is read:
    the map folder, the augmented fit's settings, the memory a fit of descriptor
    files needs (from their headers); the plan of the fit
    (:func:`rhythmic_jax.fitting.fit_plan.plan`) and the disk it needs, once the frames
    are read and before the solve.
    """
    from rhythmic_jax.fitting.fit_plan import plan
    from rhythmic_jax.frames.sources import load_sources
    from rhythmic_jax.io.checkpoint import check_space, check_target
    from rhythmic_jax.rhythmic_map import RhythmicMap

    _check_reading(job.reading)
    augmented = _augmented_settings(job) if job.augment else None
    if job.places is not None and job.positions is None:
        raise InputError("{opt:places} groups frames by their {opt:positions}")
    learned, read = _learned(job)  # before describing: its descriptor
    check_target(job.out)  # before the fit, not after it
    _check_sources_memory(job.sources, job.config)
    feats = load_sources(
        job.sources, read.descriptor, read.tile, read.stride, progress,
        pca=job.pca, weights=read.weights, same_length=job.places is None,
        compile=read.compile, keep_images=augmented is not None,
    )  # fmt: skip
    emb = _embedding_for(job.embedding, learned, feats)
    fusion = fusion_of(job.fusion, job.config.codes, learned and learned[1])
    reference = _provenance(job, read, fusion)
    if job.positions is not None:
        feats = _with_positions(feats, job)
    config = replace(
        job.config, descriptor=feats.descriptor, descriptor_settings=feats.settings,
        fusion=fusion["weight"],
    )  # fmt: skip
    dim = feats.x.shape[1] if emb is None else emb.k
    if isinstance(config.codes, int) and config.codes > dim:
        what = "descriptors'" if emb is None else "embedding's"
        raise InputError(
            f"{{opt:codes}} {config.codes}: at most d={dim} bits (the {what} dimension)"
        )
    model = RhythmicMap(config, embedding=emb)
    fit_plan = plan(config, int(feats.labels.max()) + 1, int(dim))
    fit_plan.check_memory(len(feats.x))
    extra = sum(np.asarray(v).nbytes for v in feats.extra.values())
    check_space(job.out, fit_plan.largest_bytes + extra)  # said before the solve
    if augmented is not None:
        _fit_augmented(model, feats, *augmented, progress, read.compile, fit_plan)
    else:
        model.fit(feats.x, feats.labels, progress=progress, plan=fit_plan)
    model.extra.update(feats.extra)
    model.reference = reference
    model.save(job.out)
    if augmented is not None and job.checkpoint is None:
        shutil.rmtree(augmented[1], ignore_errors=True)  # the map holds the result
    return model


def _provenance(job: FitJob, read: Reading, fusion: dict[str, Any]) -> dict:
    """Where a map's reference frames came from (the sources' absolute paths and
    tiling), and its embedding and fusion weight."""
    ref = {
        "sources": [str(Path(src).expanduser().absolute()) for src in job.sources],
        "tile": read.tile,
        "stride": read.stride,
    }
    if job.embedding is not None:
        ref["embedding"] = str(Path(job.embedding).expanduser().absolute())
        ref["descriptor_from_embedding"] = read != job.reading
    if job.config.codes is not None:
        ref["fusion"] = fusion
    return ref


def _with_positions(feats, job: FitJob):
    """Features whose extra holds the frames' positions (and k-means places)."""
    import dataclasses

    from rhythmic_jax.eval.ground_truth_files import in_metres, positions_of_sources
    from rhythmic_jax.io.images import gps_places

    xy, unit = positions_of_sources(job.positions, job.sources)
    if len(xy) != len(feats.x):
        raise InputError(
            f"{{opt:positions}}: {len(xy)} positions for {len(feats.x)} reference "
            "frames"
        )
    extra = dict(feats.extra)
    extra["reference_positions"] = xy
    extra["reference_positions_degrees"] = np.asarray(int(unit == "degrees"))
    labels = feats.labels
    if job.places is not None:
        labels = gps_places(in_metres((xy, unit))[0], job.places)
        extra["reference_labels"] = labels
    return dataclasses.replace(feats, labels=labels, extra=extra)


def _learned(job: FitJob) -> tuple[Any, Reading]:
    """``(embedding, meta)`` of ``fit --embedding`` (None without one) and the
    reading of the sources that follows from it (:func:`_reading_of_embedding`)."""
    if job.embedding is None:
        return None, job.reading
    from rhythmic_jax.map.embedding import load_embedding

    learned = load_embedding(job.embedding)
    return learned, _reading_of_embedding(job.reading, learned, job.sources)


def _reading_of_embedding(read: Reading, learned, sources) -> Reading:
    """``read`` with the embedding's descriptor (and weights) when it names none
    and the sources are images (.npy files are descriptors already)."""
    if learned is None or read.descriptor is not None:
        return read
    meta = learned[1]
    name = meta.get("descriptor")
    if name in (None, "features") or all(
        str(s).lower().endswith(".npy") for s in sources
    ):
        return read
    weights = read.weights or (meta.get("descriptor_settings") or {}).get("weights")
    return replace(read, descriptor=name, weights=weights)


def fusion_of(option: float | None, codes, meta: dict | None) -> dict[str, Any]:
    """The map's share of the fused score and where it comes from: ``option``
    when given, else the weight an embedding's ``meta`` learned for ``codes``,
    else 0.5. Returns ``{"weight": w, "from": "option" | "embedding" |
    "default", "note": why}``."""
    if option is not None:
        return {"weight": option, "from": "option", "note": "given with --fusion"}
    learned = (meta or {}).get("fusion")
    if meta is None:
        note = "no embedding"
    elif not learned:
        note = "the embedding holds no learned weight (saved before learn kept one)"
    elif learned.get("codes") != codes:
        note = f"the embedding's weight was learned for {learned.get('codes')} codes"
    else:
        return {
            "weight": float(learned["weight"]),
            "from": "embedding",
            "note": f"learned with the embedding for {codes} codes: R@1 "
            f"{learned['recall']:.3f} on its {learned['places']} training places",
        }
    return {"weight": 0.5, "from": "default", "note": note}


def _embedding_for(path: str | None, learned, feats):
    """The embedding of ``fit --embedding``, checked against the features."""
    if learned is None:
        return None
    emb, meta = learned
    if meta.get("descriptor") != feats.descriptor:
        raise InputError(
            f"{{opt:embedding}} {path}: learned on {meta.get('descriptor')!r} "
            "descriptors, "
            f"the map's are {feats.descriptor!r}"
        )
    if emb.d != feats.x.shape[1]:
        raise InputError(
            f"{{opt:embedding}} {path}: expects {emb.d}-d descriptors, "
            f"got {feats.x.shape[1]}"
        )
    return emb


@dataclass(frozen=True)
class LearnJob:
    """An embedding to learn from two or more traversals and write to ``out``.

    ``rhythmic-jax learn a.npy b.npy --out route.emb`` is
    ``learn(LearnJob(("a.npy", "b.npy"), "route.emb"))``; ``config`` is a
    :class:`rhythmic_jax.LearnConfig` (method, head, k, steps, seed). ``codes``
    (a number of ITQ bits, or int8; None: none) are those a map's fusion weight
    is learned for on the same traversals (:func:`learn_fusion`), saved with
    the embedding for ``fit --embedding``.
    """

    sources: tuple[str, ...]
    out: str
    config: Any = None
    reading: Reading = Reading()
    codes: int | str | None = "int8"


FUSION_TOLERANCE = 1  # places: a match within one place counts, as in the reports


def learn_fusion(traversals, emb, codes="int8") -> dict[str, Any]:
    """The map's share ``w`` of the fused score, learned on training traversals.

    For each traversal a map of the default settings (:class:`MapConfig`) with
    ``codes`` is fitted on its embedded frames and queried with every other
    traversal; ``w`` is the weight of the best recall@1 (within
    ``FUSION_TOLERANCE`` places) averaged over those pairs, ties nearest 0.5
    (:func:`rhythmic_jax.decoding.fusion.learn_weight`). traversals: two or
    more (n, d) arrays, row i = place i. Returns ``{"weight", "codes",
    "recall", "places", "table": [[w, recall@1], ...], "seconds"}``.
    """
    import time

    from rhythmic_jax.decoding.fusion import learn_weight
    from rhythmic_jax.map.embedding import apply
    from rhythmic_jax.rhythmic_map import RhythmicMap

    t0 = time.perf_counter()
    n = len(traversals[0])
    gt, tables = np.arange(n), []
    for a, ref in enumerate(traversals):
        m = RhythmicMap(embedding=emb, codes=codes).fit(ref, progress=False)
        for b, qry in enumerate(traversals):
            if a != b:
                sims = m.codebook.similarity(apply(emb, qry))
                _, table = learn_weight(
                    m.scores(qry), sims, m.periods, m.n, gt, FUSION_TOLERANCE
                )
                tables.append(table)
    mean = {w: float(np.mean([t[w] for t in tables])) for w in tables[0]}
    best = max(mean.values())
    w = min((w for w, r in mean.items() if r == best), key=lambda w: abs(w - 0.5))
    return {
        "weight": w, "codes": codes, "recall": best, "places": n,
        "table": [[k, r] for k, r in mean.items()],
        "seconds": time.perf_counter() - t0,
    }  # fmt: skip


def learn_config(**settings) -> Any:
    """A :class:`rhythmic_jax.LearnConfig` (method, head, k, steps, seed)."""
    from rhythmic_jax.fitting.learn import LearnConfig

    return LearnConfig(**settings)


def learn(job: LearnJob, progress: bool = True) -> tuple[Any, dict[str, Any]]:
    """Learn, save and return ``(embedding, info)`` of ``job``; with ``job.codes``
    also the fusion weight for them (``info["fusion"]``, saved beside it)."""
    from rhythmic_jax.fitting.learn import LearnConfig, learn_embedding
    from rhythmic_jax.frames.sources import load_sources
    from rhythmic_jax.io.checkpoint import check_target
    from rhythmic_jax.map.embedding import save_embedding

    check_target(job.out)
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
    )  # fmt: skip
    traversals = np.split(feats.x, len(job.sources))
    emb, info = learn_embedding(traversals, config)
    if job.codes is not None:
        info["fusion"] = learn_fusion(traversals, emb, job.codes)
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


def learn_summary(out: str, emb, info: dict[str, Any]) -> str:
    """One line about a saved embedding (and the fusion weight learned with it)."""
    line = (
        f"embedding {out}: {emb.kind} {emb.d} -> {emb.k} dims, "
        f"{info['seconds']:.1f} s on {info['places']} places x "
        f"{info['traversals']} traversals"
    )
    fusion = info.get("fusion")
    if fusion:
        line += (
            f"; fusion {fusion['weight']:g} for {fusion['codes']} codes (R@1 "
            f"{fusion['recall']:.3f} on the training places, {fusion['seconds']:.1f} s)"
        )
    return line


def fit_summary(out: str, info: dict[str, Any]) -> str:
    """One line about a saved map: size, periods, storage and compression."""
    codes = ""
    if info.get("codes_bits"):
        kind = info.get("codes_kind") or "itq"
        bits = f"{info['codes_bits']}-bit"
        codes = f" with {'int8' if kind == 'int8' else bits} codes"
    return (
        f"map {out}: n={info['n']} d={info['d']} {info['layout']}"
        f"{codes} storage={info['storage_bytes']:,} B "
        f"(ratio {info['compression_ratio']:.4f} of {info['database_bytes']:,} B)"
    )


def _load_queries(map_path: str, source: str, reading: Reading, progress: bool):
    from rhythmic_jax.frames.sources import load_query_source
    from rhythmic_jax.rhythmic_map import RhythmicMap

    _check_reading(reading)
    model = RhythmicMap.load(map_path)
    feats = load_query_source(
        source, model, reading.descriptor, reading.tile, reading.stride, progress,
        weights=reading.weights, compile=reading.compile,
    )  # fmt: skip
    return model, feats


def query(
    map_path: str,
    source: str,
    *,
    decode: str | None = None,
    sequence: int | None = None,
    threshold: float | None = None,
    out: str | None = None,
    reading: Reading = Reading(),
    progress: bool = False,
) -> np.ndarray:
    """Localise the frames of ``source`` with the map at ``map_path``: (b,) int64.

    ``-1`` is no match. With ``out`` the predictions are also written there
    (``.npy``, atomically); its folder must exist.
    """
    if out and not Path(out).parent.is_dir():
        raise InputError(f"{{opt:out}} {out}: folder {Path(out).parent} not found")
    model, feats = _load_queries(map_path, source, reading, progress)
    pred = model.predict(feats.x, decode, sequence=sequence, threshold=threshold)
    pred = np.asarray(pred).astype(np.int64)
    if out:
        from rhythmic_jax.io.atomic import save_npy

        save_npy(out, pred)
    return pred


def query_summary(pred: np.ndarray, out: str) -> str:
    """One line about predictions written to ``out``."""
    return f"{len(pred)} predictions ({int((pred < 0).sum())} no match) -> {out}"


def info(map_path: str) -> dict[str, Any]:
    """What a map holds (:meth:`rhythmic_jax.RhythmicMap.info`), read from disk.

    A map whose metadata is complete and consistent, with its arrays listed as
    saved, is described from ``map.json`` alone (no JAX, no array data read); any
    other goes through :meth:`rhythmic_jax.RhythmicMap.load`, which says what is
    wrong with it (:func:`rhythmic_jax.map.map_file.info`).
    """
    from rhythmic_jax.map import map_file

    return map_file.info(map_path, _loaded_info)


def _loaded_info(map_path: str) -> dict[str, Any]:
    from rhythmic_jax.rhythmic_map import RhythmicMap

    return RhythmicMap.load(map_path).info()


def info_lines(info: dict[str, Any]) -> str:
    """The text form of :func:`info`: one setting a line, then each candidate."""
    if info.get("kind") == "embedding":
        return _embedding_lines(info)
    keys = ("n", "d", "layout", "storage_bytes", "embedding_bytes", "embedding",
            "compression_ratio", "c")  # fmt: skip
    lines = [f"{key:>18}: {info[key]}" for key in keys]
    lines += _learned_lines(info)
    st = info["storage"]
    lines += [
        f"{'storage fixed':>18}: {st['fixed']:,} B (code transform)",
        f"{'per place':>18}: {st['per_place']:,} B (codes)",
    ]
    lines += [
        f"{'period ' + t:>18}: {b:,} B (templates)" for t, b in st["per_period"].items()
    ]
    lines.append(f"{'share':>18}: {st['share']:.4f} of the float32 database")
    if info.get("checksums"):
        lines.append(f"{'checksums':>18}: {info['checksums']}")
    lines += [
        f"{'period ' + str(t):>18}: training error {e:.4f}"
        for t, e in zip(info["candidates"], info["candidate_errors"], strict=True)
    ]
    return "\n".join(lines)


def _embedding_lines(info: dict[str, Any]) -> str:
    learned = info.get("learn") or {}
    method = (learned.get("config") or {}).get("method")
    lines = [
        f"{'embedding':>18}: {info['head']} {info['d']} -> {info['k']} dims"
        + (f", {method} on {learned.get('places')} places" if method else ""),
        f"{'descriptor':>18}: {info['descriptor']} "
        + (
            "(descriptor files: fit --embedding takes .npy)"
            if info["descriptor"] == "features"
            else "(fit --embedding describes images with it)"
        ),
    ]
    fusion = info.get("fusion")
    if fusion:
        line = (
            f"{fusion['weight']:g} for {fusion['codes']} codes (R@1 "
            f"{fusion['recall']:.3f} on the training places; fit --embedding "
            f"--codes {fusion['codes']} uses it)"
        )
    else:
        line = "none learned (saved before learn kept one): maps fuse at 0.5"
    lines.append(f"{'fusion':>18}: {line}")
    return "\n".join(lines)


def _learned_lines(info: dict[str, Any]) -> list[str]:
    """Where a map's embedding, descriptor and fusion weight came from (the
    fusion line only with codes; maps saved before say only what they hold)."""
    ref, lines = info.get("reference") or {}, []
    if ref.get("embedding"):
        taken = (
            f"; descriptor {info['descriptor']} taken from it"
            if ref.get("descriptor_from_embedding")
            else ""
        )
        lines.append(f"{'embedding from':>18}: {ref['embedding']}{taken}")
    if info.get("codes_bits"):
        w = (info.get("config") or {}).get("fusion")
        fusion = ref.get("fusion")
        how = f" ({fusion['from']}: {fusion['note']})" if fusion else ""
        lines.append(f"{'fusion':>18}: {w:g}{how}")
    return lines


def evaluate(
    map_path: str,
    source: str,
    *,
    reference: str | None = None,
    tolerance: int = 0,
    decode: str | None = None,
    sequence: int | None = None,
    ground_truth: tuple[str, ...] | None = None,
    tolerance_m: float = 25.0,
    plot: str | None = None,
    reading: Reading = Reading(),
    progress: bool = False,
) -> dict[str, Any]:
    """Judge the map on the queries of ``source``, beside brute force.

    ``plot``: a .png to draw recall (within ``tolerance``, with the decode and
    sequence asked for) against storage: the map, with codes also the hybrid and
    the codes alone, and brute force (:func:`rhythmic_jax.eval.figures.plot_frontier`).

    Brute force searches ``reference`` when given, else the sources the map was
    fitted on when they are still there; ``reference_note`` says which, or why
    there is no brute-force line. ``ground_truth`` names the right places
    (:func:`rhythmic_jax.eval.ground_truth_files.load_ground_truth`; default: query
    i is place i, give or take ``tolerance`` frames); ``plot`` writes PR curves
    and recall@K bars (.png). See :func:`rhythmic_jax.eval.report.evaluate_map`.
    """
    from rhythmic_jax.eval.report import evaluate_map
    from rhythmic_jax.frames.sources import reference_features

    if plot and not str(plot).lower().endswith(".png"):
        raise InputError(f"{{opt:plot}} {plot}: give a .png file name")
    model, feats = _load_queries(map_path, source, reading, progress)
    ref, labels, note = reference_features(
        model, reference, reading.descriptor, reading.tile, reading.stride, progress,
        weights=reading.weights, compile=reading.compile,
    )  # fmt: skip
    if ref is not None and reference is None and "reference_labels" in model.extra:
        labels = model.extra["reference_labels"]  # frames grouped into places
    truth = None
    if ground_truth is not None:
        from rhythmic_jax.eval.ground_truth_files import load_ground_truth

        refs = [reference] if reference else model.reference.get("sources") or []
        truth = load_ground_truth(
            ground_truth, n_queries=len(feats.x), n_places=model.n,
            query_source=source, reference_sources=refs, map_extra=model.extra,
            tolerance_m=tolerance_m,
        )  # fmt: skip
    result = evaluate_map(
        model, feats.x, reference=ref, reference_labels=labels, tolerance=tolerance,
        method=decode, sequence=sequence, ground_truth=truth, curves=bool(plot),
    )  # fmt: skip
    result["reference_note"] = note
    if plot:
        from rhythmic_jax.eval.figures import plot_evaluation

        plot_evaluation(result, path=plot)
        for row in result["methods"].values():
            row.pop("pr_curve", None)
        result["plot"] = str(plot)
    return result


def evaluate_summary(result: dict[str, Any]) -> str:
    """The text form of :func:`evaluate`: the table, then the reference note."""
    from rhythmic_jax.eval.report import format_evaluation

    lines = format_evaluation(result) + "\n" + result["reference_note"]
    if result.get("plot"):
        lines += f"\nPR curves and recall@K -> {result['plot']}"
    return lines


def demo(out: str = "rhythmic_demo", quick: bool = False, progress: bool = False):
    """The bundled demo (:func:`rhythmic_jax.app.demo.run_demo`); writes its report."""
    from rhythmic_jax.app.demo import run_demo

    return run_demo(out, quick=quick, progress=progress)


def augmentation_ablation(
    routes: dict[str, tuple[np.ndarray, np.ndarray, int]],
    variants: dict[str, tuple[str, ...]],
    descriptor,
    *,
    level: int = 1,
    epochs: int = 3,
    seed: int = 0,
) -> tuple[dict[str, dict[str, dict]], dict[str, dict[str, dict]]]:
    """Maps trained plainly and over each augmentation, judged on other-appearance
    queries beside brute force (paper Fig. 6).

    Args:
      routes: name -> (map frames uint8 (n, H, W, 3), query frames of the same
        places, frame tolerance).
      variants: label -> augmentation names (``("all",)``: the seven merged).
      descriptor: a :mod:`rhythmic_jax.frames.features` descriptor (cached per route).

    Returns:
      ``(results, timings)``: route -> label -> the map's metrics of
      :func:`rhythmic_jax.eval.report.evaluate_map` (``"plain map"``, ``"brute
      force"`` and each variant), and route -> label -> seconds (``"fit"`` and the
      augmented fit's own parts).
    """
    import time

    from rhythmic_jax.augment.stream import AugmentedFit, fit_map_augmented
    from rhythmic_jax.eval.report import evaluate_map
    from rhythmic_jax.frames.features import cached_describe
    from rhythmic_jax.rhythmic_map import RhythmicMap

    results: dict[str, dict[str, dict]] = {}
    timings: dict[str, dict[str, dict]] = {}
    for route, (frames, queries, tol) in routes.items():
        x_map = cached_describe(
            frames, descriptor, key=f"nb-{route}-map", progress=False
        )
        x_qry = cached_describe(
            queries, descriptor, key=f"nb-{route}-qry", progress=False
        )
        t0 = time.perf_counter()
        plain = RhythmicMap(level=level).fit(x_map, progress=False)
        timings[route] = {"plain map": {"fit": time.perf_counter() - t0}}
        judged = evaluate_map(
            plain, x_qry, reference=x_map, tolerance=tol, timing=False
        )
        results[route] = {
            "plain map": judged["methods"]["map"],
            "brute force": judged["methods"]["brute force"],
        }
        for label, names in variants.items():
            config = AugmentedFit(names=names, epochs=epochs, seed=seed)
            t0 = time.perf_counter()
            model = fit_map_augmented(
                RhythmicMap(level=level), frames, x_map, descriptor, config,
                progress=False,
            )  # fmt: skip
            timings[route][label] = {**model.timings, "fit": time.perf_counter() - t0}
            judged = evaluate_map(model, x_qry, tolerance=tol, timing=False)
            results[route][label] = judged["methods"]["map"]
    return results, timings
