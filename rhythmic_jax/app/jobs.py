"""Jobs: what ``rhythmic-jax`` runs, as library functions notebooks call too.

A job is a frozen dataclass that checks itself when it is made, before any work:
each numeric setting against its domain (:data:`DOMAINS`, which the command line
also parses its options with) and every setting against the others (the job's
``RULES``: an option given where it has no effect, or without one it needs).
The command line builds the job from its options and reports the first refusal.
Then:

- :func:`fit`: the map folder, the augmented fit's settings and checkpoint
  folder and the fit's plan (from descriptor files' headers when it can, so a
  fit too large for memory ends before they are read) settled first, the
  sources read, the map fitted (plainly, or over frames augmented on the fly
  with a resumable checkpoint folder, default ``OUT.ckpt``, removed once the map
  is saved), provenance recorded (the sources' absolute paths and tiling, so
  that ``evaluate`` finds the reference frames again), the map saved atomically;
- :func:`query`: queries described the way the map was built, localised, and
  predictions written atomically;
- :func:`info`, :func:`evaluate` (beside brute force over the map's own
  reference frames when they are still there), :func:`demo`.

Errors name settings by parameter (``{opt:tile}``); the command line spells them
as flags. Nothing here prints; the ``*_summary`` functions return the lines the
command line shows. Importing this module imports no numpy: the command line
builds its parser from :data:`DOMAINS`.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from dataclasses import MISSING, dataclass, field, fields, is_dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

from rhythmic_jax.app.scale_jobs import ScaleJob, fit_scaled, wants_scale
from rhythmic_jax.errors import InputError
from rhythmic_jax.frames.compile_policy import AUTO, CompilePolicy
from rhythmic_jax.io.outputs import check_place, write_errors
from rhythmic_jax.jit_options import describe as compile_options
from rhythmic_jax.map.config import MapConfig
from rhythmic_jax.validate import Domain, int_option, is_number, number_option

if TYPE_CHECKING:
    import numpy as np

__all__ = [
    "DOMAINS", "EvaluateJob", "FitInterrupted", "FitJob", "LearnJob", "OptionRefused",
    "QueryJob", "Reading", "ScaleJob", "augmentation_ablation", "demo", "evaluate",
    "evaluate_summary", "fit", "fit_scaled", "fit_summary", "fusion_of", "info",
    "info_lines", "learn", "learn_config", "learn_fusion", "learn_summary", "query",
    "query_summary", "quiet_io_threads", "wants_scale",
]  # fmt: skip


def memory_bytes(text: str) -> int:
    """``--memory``'s text (``1GiB``, ``800M``) in bytes; ``ValueError`` when it
    is no size (:func:`rhythmic_jax.fitting.scale_fit.parse_bytes`)."""
    from rhythmic_jax.fitting.scale_fit import parse_bytes

    return parse_bytes(text)


# Every numeric setting's domain, by name (the same in every job that has it): a
# job checks its values with it, and the command line parses its options with it
# and states it in --help.
DOMAINS: dict[str, Domain] = {
    "r": int_option(2),
    "level": int_option(1),
    "count": int_option(2),
    "c": number_option(0),
    "gap": number_option(0, 1),
    "epochs": int_option(1),
    "batch_size": int_option(1),
    "checkpoint_every": int_option(1),
    "pca": int_option(1),
    "processes": int_option(1),
    "num_processes": int_option(1),
    "process_id": int_option(0),
    "memory": Domain(True, 1, parse=memory_bytes, what="a size (1GiB, 800M)"),
    "places": int_option(1),
    "codes": Domain(True, 1, words=("int8",)),
    "fusion": number_option(0, 1, closed=True),
    "tile": int_option(1),
    "stride": int_option(1),
    "compile_min_frames": int_option(0),
    "k": int_option(1),
    "steps": int_option(1),
    "seed": int_option(0, 2**32 - 1),
    "sequence": int_option(1),
    "threshold": number_option(),
    "tolerance": int_option(0),
    "tolerance_m": number_option(0),
    "budget": number_option(0),
}


class OptionRefused(InputError):
    """A setting given where it has no effect, or without one it needs."""


@dataclass(frozen=True)
class Rule:
    """Where a setting acts: given (away from its default, or named in the job's
    ``given``) where ``holds(job)`` is false, each of ``options`` is refused with
    the line ``{opt:OPTION} says``, or, for options that scripts pass always
    (``warn``), named in one warning line and ignored."""

    options: tuple[str, ...]
    says: str
    holds: Callable[[Any], bool]
    warn: bool = False


PARTS = ("reading", "compile", "scale", "config")  # a job's nested settings
RENAMED = {"mode": "compile", "min_frames": "compile_min_frames"}  # their options


def _settings(obj) -> dict[str, tuple[Any, Any]]:
    """``{setting: (value, default)}`` of a job and of the parts it holds
    (:data:`PARTS`, flattened; a name of the job itself, or of an earlier part,
    wins)."""
    own = {}
    for f in fields(obj):
        if f.name not in PARTS:
            default = f.default if f.default_factory is MISSING else f.default_factory()
            own[RENAMED.get(f.name, f.name)] = (getattr(obj, f.name), default)
    for part in PARTS:
        value = getattr(obj, part, None)
        if is_dataclass(value):
            own = {**_settings(value), **own}
    return own


@dataclass(frozen=True)
class Checked:
    """A job that checks itself when made: every numeric setting against its
    :data:`DOMAINS` entry, then every rule of ``RULES`` (:class:`Rule`); a
    refused rule raises :class:`OptionRefused`, and ``warnings`` holds the
    lines naming settings a warning rule ignores.

    ``given`` (a field of each job) names settings given explicitly, as the
    command line's options are: a rule refuses them even at their default.
    """

    RULES: ClassVar[tuple[Rule, ...]] = ()
    warnings: tuple[str, ...] = field(default=(), init=False, compare=False)

    def __post_init__(self):
        values = _settings(self)
        for name, (value, _) in values.items():
            if name in DOMAINS and is_number(value):
                try:
                    DOMAINS[name].check(value)
                except InputError as err:
                    raise InputError(f"{{opt:{name}}} {err}") from None
        given = {k for k, (v, d) in values.items() if v != d} | set(self.given)
        warned: dict[str, str] = {}
        for rule in self.RULES:
            named = [o for o in rule.options if o in given]
            if not named or rule.holds(self):
                continue
            for option in named:
                line = f"{{opt:{option}}} {rule.says}"
                if not rule.warn:
                    raise OptionRefused(line)
                warned.setdefault(option, line)
        object.__setattr__(self, "warnings", tuple(warned.values()))


def _images(job) -> bool:
    """Whether a source of the job may be images (not only .npy descriptors)."""
    return not all(str(s).lower().endswith(".npy") for s in job.read_sources)


READS = (
    Rule(("stride",), "needs {opt:tile} (it is the step between tiles)",
         lambda j: j.reading.tile is not None),
    Rule(("descriptor", "weights"), "applies to images; .npy files are descriptors",
         _images),
)  # fmt: skip
IGNORED = (
    Rule(("compile_min_frames",), "acts only with {opt:compile} auto; ignored",
         lambda j: j.reading.compile.mode == "auto", warn=True),
    Rule(("compile", "compile_min_frames"), "applies to images; .npy files are "
         "descriptors; ignored", _images, warn=True),
)  # fmt: skip


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


def _layout(job):
    """The job's ``--layout`` (:func:`rhythmic_jax.map.groups.parse_layout`)."""
    from rhythmic_jax.map.groups import parse_layout

    return parse_layout(job.config.layout)


def _scaled(job) -> bool:
    """Whether a fit may run from files at scale (where a checkpoint acts too)."""
    s = job.scale
    wanted = (s.processes or 1) != 1 or s.coordinator or s.memory or s.stream
    return bool(wanted or s.shards or any(Path(p).is_dir() for p in job.sources))


@dataclass(frozen=True)
class FitJob(Checked):
    """A map to fit from reference sources and write to ``out``.

    ``rhythmic-jax fit ref.npy --out route.map`` is ``fit(FitJob(("ref.npy",),
    "route.map"))``. ``config`` is the map's :class:`rhythmic_jax.MapConfig` (its
    descriptor is the sources', and its fusion weight ``fusion``'s); ``pca``
    projects the descriptors to that many dimensions first. ``augment``
    (comma-separated kornia operation names, or ``"all"``) trains over frames
    augmented on the fly for ``epochs`` passes (None: 3) of ``batch_size``
    frames (None: 128), checkpointed every ``checkpoint_every`` steps (None: 50)
    in ``checkpoint`` (default ``OUT.ckpt``, removed once the map is saved; a
    given folder is kept). ``positions`` (one CSV/.npy per source, or
    ``("names",)`` for ``@easting@northing@`` file names) are saved in the map
    for :func:`evaluate`'s ground truth; ``places`` groups the frames into that
    many places by k-means over them (the RobotCar protocol; traversals may then
    differ in length). ``embedding`` names a folder written by :func:`learn`: it
    is saved inside the map and applied to every query (with codes, ITQ is
    fitted on the embedded reference frames); image sources are described with
    its descriptor unless ``reading`` names one, and ``fusion`` None takes the
    weight it learned for the config's codes (else 0.5, the weight without
    one). ``scale`` spreads and bounds a fit from files
    (:mod:`rhythmic_jax.app.scale_jobs`); ``given``: see :class:`Checked`.
    """

    sources: tuple[str, ...]
    out: str
    config: MapConfig = field(default_factory=MapConfig)
    pca: int | None = None
    augment: str | None = None
    epochs: int | None = None
    batch_size: int | None = None
    checkpoint: str | None = None
    checkpoint_every: int | None = None
    fusion: float | None = None
    reading: Reading = Reading()
    positions: tuple[str, ...] | None = None
    places: int | None = None
    embedding: str | None = None
    scale: ScaleJob = ScaleJob()
    given: frozenset[str] = frozenset()

    RULES = (
        *READS,
        Rule(("epochs", "batch_size", "checkpoint_every"),
             "needs {opt:augment} (it shapes the augmented fit)",
             lambda j: bool(j.augment)),
        Rule(("checkpoint",), "needs {opt:augment} or a fit from files at scale (it "
             "keeps their progress)", lambda j: bool(j.augment) or _scaled(j)),
        Rule(("fusion",), "needs {opt:codes} (it weighs the map's scores against "
             "the codes')", lambda j: j.config.codes is not None),
        Rule(("codes",), "needs a periods layout ({opt:layout} periods or "
             "periods:T1,T2): codes fuse with its place scores",
             lambda j: _layout(j).kind == "periods"),
        Rule(("count",), "acts only with {opt:layout} periods (the map chooses its "
             "periods among {opt:count} candidates)",
             lambda j: _layout(j).kind == "periods" and not _layout(j).sizes),
        Rule(("level",), "acts only with a {opt:layout} that leaves its sizes out",
             lambda j: not (_layout(j).sizes or _layout(j).segment)),
        Rule(("r",), "acts only with a {opt:layout} that leaves its sizes out",
             lambda j: not (_layout(j).sizes or _layout(j).fine)),
        Rule(("gap",), "acts only with {opt:solver} newton (where Newton stops)",
             lambda j: j.config.solver == "newton"),
        Rule(("places",), "needs {opt:positions} (it groups the frames by them)",
             lambda j: j.positions is not None),
        Rule(("num_processes", "process_id"), "needs {opt:coordinator}",
             lambda j: j.scale.coordinator is not None),
        Rule(("coordinator",), "needs {opt:num_processes} and {opt:process_id}",
             lambda j: None not in (j.scale.num_processes, j.scale.process_id)),
        Rule(("process_id",), "must be below {opt:num_processes}",
             lambda j: j.scale.num_processes is None
             or j.scale.process_id < j.scale.num_processes),
        Rule(("processes",), "acts only without {opt:coordinator} (each host then "
             "runs one process)", lambda j: j.scale.coordinator is None),
        *IGNORED,
    )  # fmt: skip

    @property
    def read_sources(self) -> tuple[str, ...]:
        return self.sources

    @property
    def checkpoint_folder(self) -> Path:
        """The checkpoint folder (default ``OUT.ckpt``); refused when a file."""
        ckpt = Path(self.checkpoint or str(Path(self.out)) + ".ckpt").absolute()
        if ckpt.exists() and not ckpt.is_dir():
            raise InputError(f"{{opt:checkpoint}} {ckpt}: a file, not a folder")
        return ckpt


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


def _before_reading(job: FitJob):
    """What a fit's settings and its sources' headers decide, refused before
    any source is read: the augmented fit's settings (and checkpoint folder),
    the embedding of ``fit --embedding`` and the reading of the sources it
    implies (its descriptor and weights, for images that name none), the map
    folder, and for descriptor files of one shape the plan and its memory.

    Returns ``(augmented, learned, reading, plan)``: ``(AugmentedFit, checkpoint
    folder)`` or None, ``(embedding, meta)`` or None, the :class:`Reading`, and
    the :class:`~rhythmic_jax.fitting.fit_plan.FitPlan`, or None where only
    reading the sources tells (images, files missing or of other shapes,
    ``pca``, ``places``, an embedding of another dimension: reading them says
    what is wrong).
    """
    from rhythmic_jax.io.checkpoint import check_target
    from rhythmic_jax.io.descriptor_files import descriptor_shape

    check_place("out", job.out)
    if job.augment:
        check_place("checkpoint", job.checkpoint_folder, inside=True)
    augmented = learned = fit_plan = None
    read, sources = job.reading, job.sources
    if job.augment:
        from rhythmic_jax.augment.kornia_ops import AugmentConfig
        from rhythmic_jax.augment.stream import AugmentedFit

        if job.pca is not None:
            raise InputError("{opt:augment} and {opt:pca} together are not supported")
        names = tuple(job.augment.split(","))
        AugmentConfig(names=names)  # unknown names end here, not after describing
        augmented = AugmentedFit(
            names=names, epochs=job.epochs or 3, batch_size=job.batch_size or 128,
            checkpoint_every=job.checkpoint_every or 50,
        ), job.checkpoint_folder  # fmt: skip
    if job.embedding is not None:
        from rhythmic_jax.map.embedding import load_embedding

        learned = load_embedding(job.embedding)
        read = _reading_of_embedding(read, learned, sources)
    check_target(job.out)  # before the fit, not after it
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
        fit_plan = _planned(job.config, n * len(sources), n, k, learned)
    return augmented, learned, read, fit_plan


def _reading_of_embedding(read: Reading, learned, sources) -> Reading:
    """``read`` with the embedding's descriptor (and weights) when it names none
    and the sources are images (.npy files are descriptors already)."""
    name = learned[1].get("descriptor") if learned is not None else None
    if (
        read.descriptor is not None
        or name in (None, "features")
        or all(str(s).lower().endswith(".npy") for s in sources)
    ):
        return read
    settings = learned[1].get("descriptor_settings") or {}
    return replace(
        read, descriptor=name, weights=read.weights or settings.get("weights")
    )


def _planned(config: MapConfig, frames: int, n: int, d: int, learned):
    """The fit's plan for ``n`` places of ``d`` features (the templates'), its
    memory for ``frames`` rows checked (:func:`rhythmic_jax.fitting.fit_plan.plan`);
    codes of more bits than ``d`` are refused in the job's words."""
    from rhythmic_jax.fitting import fit_plan

    if isinstance(config.codes, int) and config.codes > d:
        what = "descriptors'" if learned is None else "embedding's"
        raise InputError(
            f"{{opt:codes}} {config.codes}: at most d={d} bits (the {what} dimension)"
        )
    return fit_plan.plan(config, n, d, frames)


def _after_reading(job: FitJob, learned, read: Reading, fit_plan, feats):
    """The map to fit on the read ``feats``: the embedding checked against them,
    the frames' positions (and k-means places) added, the plan made where the
    headers could not tell, the disk the map needs checked (before the solve),
    and the map's settings and provenance (the sources' absolute paths and
    tiling, so that :func:`evaluate` finds the reference frames again; the
    embedding and the fusion weight). Returns ``(config, embedding or None,
    provenance, feats, plan)``."""
    import numpy as np

    from rhythmic_jax.io.checkpoint import check_space

    emb, meta = learned or (None, None)
    if meta is not None and meta.get("descriptor") != feats.descriptor:
        raise InputError(
            f"{{opt:embedding}} {job.embedding}: learned on "
            f"{meta.get('descriptor')!r} descriptors, the map's are "
            f"{feats.descriptor!r}"
        )
    if emb is not None and emb.d != feats.x.shape[1]:
        raise InputError(
            f"{{opt:embedding}} {job.embedding}: expects {emb.d}-d descriptors, "
            f"got {feats.x.shape[1]}"
        )
    fusion = fusion_of(job.fusion, job.config.codes, meta)
    if job.positions is not None:
        feats = _with_positions(feats, job)
    if fit_plan is None:
        d = feats.x.shape[1] if emb is None else emb.k
        n = int(feats.labels.max()) + 1
        fit_plan = _planned(job.config, len(feats.x), n, int(d), learned)
    extra = sum(np.asarray(v).nbytes for v in feats.extra.values())
    check_space(job.out, fit_plan.largest_bytes + extra)  # said before the solve
    config = replace(
        job.config, descriptor=feats.descriptor, descriptor_settings=feats.settings,
        fusion=fusion["weight"],
    )  # fmt: skip
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
    return config, emb, ref, feats, fit_plan


def fit(job: FitJob, progress: bool = False):
    """Fit, record provenance and save the map of ``job``; returns the map.

    Everything the settings alone decide is refused before any source is read
    (:func:`_before_reading`: for descriptor files the fit's plan and the memory
    it needs, from their headers); for images the plan once they are read
    (:func:`_after_reading`), with the disk the map needs before the solve. The
    one plan is the fit's (:func:`rhythmic_jax.fitting.fit_plan.plan`). An
    augmented fit (image sources) keeps a checkpoint folder, default
    ``OUT.ckpt``, removed once the map is saved; Ctrl-C raises
    :class:`FitInterrupted`, which says where it is kept.
    """
    from rhythmic_jax.frames.sources import load_sources
    from rhythmic_jax.rhythmic_map import RhythmicMap

    augmented, learned, read, fit_plan = _before_reading(job)
    feats = load_sources(
        job.sources, read.descriptor, read.tile, read.stride, progress,
        pca=job.pca, weights=read.weights, same_length=job.places is None,
        compile=read.compile, keep_images=augmented is not None,
    )  # fmt: skip
    config, emb, ref, feats, fit_plan = _after_reading(
        job, learned, read, fit_plan, feats
    )
    model = RhythmicMap(config, embedding=emb)
    model.extra.update(feats.extra)
    model.reference = ref
    if augmented is None:
        model.fit(feats.x, feats.labels, progress=progress, plan=fit_plan)
    else:
        from rhythmic_jax.augment.stream import fit_map_augmented
        from rhythmic_jax.frames.compiled import FastDescriptor

        if feats.images is None:
            raise InputError(
                "{opt:augment} needs image sources (folders or {opt:tile}), not .npy"
            )
        from rhythmic_jax.app import signals

        config, ckpt = augmented
        frames = len(feats.images) * config.epochs  # frames the network will see
        kept = (f"the augmented fit's checkpoint is kept in {ckpt}; run the same "
                "command again to resume")  # fmt: skip
        signals.set_note(kept)
        try:
            with write_errors("checkpoint", ckpt):
                fit_map_augmented(
                    model, feats.images, feats.x,
                    FastDescriptor(feats.describer, frames, read.compile), config,
                    feats.labels, progress=progress, checkpoint=ckpt, plan=fit_plan,
                )  # fmt: skip
        except KeyboardInterrupt:
            raise FitInterrupted(kept) from None
    with write_errors("out", job.out):
        model.save(job.out)
    if augmented is not None and job.checkpoint is None:
        shutil.rmtree(augmented[1], ignore_errors=True)  # the map holds the result
    return model


def _with_positions(feats, job: FitJob):
    """Features whose extra holds the frames' positions (and k-means places)."""
    import dataclasses

    import numpy as np

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


@dataclass(frozen=True)
class LearnJob(Checked):
    """An embedding to learn from two or more traversals and write to ``out``.

    ``rhythmic-jax learn a.npy b.npy --out route.emb`` is
    ``learn(LearnJob(("a.npy", "b.npy"), "route.emb"))``; ``config`` is a
    :class:`rhythmic_jax.LearnConfig` (method, head, k, steps, seed). ``codes``
    (a number of ITQ bits, or int8; None: none) are those a map's fusion weight
    is learned for on the same traversals (:func:`learn_fusion`), saved with
    the embedding for ``fit --embedding``. ``given``: see :class:`Checked`.
    """

    sources: tuple[str, ...]
    out: str
    config: Any = None
    reading: Reading = Reading()
    codes: int | str | None = "int8"
    given: frozenset[str] = frozenset()

    RULES = (
        *READS,
        Rule(("head", "steps", "seed"), "acts only with {opt:method} map or infonce "
             "(the closed forms take no steps)",
             lambda j: j.config is None or j.config.method in ("map", "infonce")),
        *IGNORED,
    )  # fmt: skip

    @property
    def read_sources(self) -> tuple[str, ...]:
        return self.sources


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

    import numpy as np

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
    import numpy as np

    from rhythmic_jax.fitting.learn import LearnConfig, learn_embedding
    from rhythmic_jax.frames.sources import load_sources
    from rhythmic_jax.io.checkpoint import check_target
    from rhythmic_jax.map.embedding import save_embedding

    check_target(job.out)
    check_place("out", job.out)
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
    with write_errors("out", job.out):
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


@dataclass(frozen=True)
class QueryJob(Checked):
    """Queries of ``source`` to localise with the map at ``map``.

    ``rhythmic-jax query route.map q.npy --out pred.npy`` is
    ``query(QueryJob("route.map", "q.npy", out="pred.npy"))``: ``decode``,
    ``sequence`` and ``threshold`` as :meth:`rhythmic_jax.RhythmicMap.predict`
    takes them; with ``out`` the predictions are also written there (``.npy``,
    atomically; its folder must exist). ``given``: see :class:`Checked`.
    """

    map: str
    source: str
    decode: str | None = None
    sequence: int | None = None
    threshold: float | None = None
    out: str | None = None
    reading: Reading = Reading()
    given: frozenset[str] = frozenset()

    RULES = (*READS, *IGNORED)

    @property
    def read_sources(self) -> tuple[str, ...]:
        return (self.source,)


@dataclass(frozen=True)
class EvaluateJob(Checked):
    """The map at ``map`` judged on the queries of ``source``, beside brute force.

    Brute force searches ``reference`` when given, else the sources the map was
    fitted on when they are still there. ``ground_truth`` names the right places
    (:func:`rhythmic_jax.eval.ground_truth_files.load_ground_truth`; None: query
    i is place i, give or take ``tolerance`` frames; positions match within
    ``tolerance_m`` metres); ``plot``: a .png of PR curves and recall@K bars.
    ``decode`` and ``sequence`` as :class:`QueryJob`'s; ``given``: see
    :class:`Checked`.
    """

    map: str
    source: str
    reference: str | None = None
    tolerance: int = 0
    decode: str | None = None
    sequence: int | None = None
    ground_truth: tuple[str, ...] | None = None
    tolerance_m: float = 25.0
    plot: str | None = None
    reading: Reading = Reading()
    given: frozenset[str] = frozenset()

    RULES = (
        *READS,
        Rule(("tolerance",), "acts only without {opt:ground_truth} (which names the "
             "right places itself)", lambda j: j.ground_truth is None),
        Rule(("tolerance_m",), "needs {opt:ground_truth} (positions or names: it is "
             "their radius of a right match)", lambda j: j.ground_truth is not None),
        *IGNORED,
    )  # fmt: skip

    @property
    def read_sources(self) -> tuple[str, ...]:
        return (self.source,) + ((self.reference,) if self.reference else ())


def _load_queries(job, progress: bool):
    from rhythmic_jax.frames.sources import load_query_source
    from rhythmic_jax.rhythmic_map import RhythmicMap

    model, read = RhythmicMap.load(job.map), job.reading
    feats = load_query_source(
        job.source, model, read.descriptor, read.tile, read.stride, progress,
        weights=read.weights, compile=read.compile,
    )  # fmt: skip
    return model, feats


def query(job: QueryJob, progress: bool = False) -> np.ndarray:
    """The predicted places of ``job``'s queries: (b,) int64, ``-1`` no match."""
    import numpy as np

    out = job.out
    if out and not Path(out).parent.is_dir():
        raise InputError(f"{{opt:out}} {out}: folder {Path(out).parent} not found")
    if out:
        check_place("out", out)
    model, feats = _load_queries(job, progress)
    pred = model.predict(
        feats.x, job.decode, sequence=job.sequence, threshold=job.threshold
    )
    pred = np.asarray(pred).astype(np.int64)
    if out:
        from rhythmic_jax.io.atomic import save_npy

        with write_errors("out", out):
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
    return "\n".join(lines + [f"{'compile options':>18}: {compile_options()}"])


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


def evaluate(job: EvaluateJob, progress: bool = False) -> dict[str, Any]:
    """Judge the map on the queries of ``job`` beside brute force
    (:func:`rhythmic_jax.eval.report.evaluate_map`); ``reference_note`` says
    which frames brute force searched, or why there is no brute-force line."""
    from rhythmic_jax.eval.report import evaluate_map
    from rhythmic_jax.frames.sources import reference_features

    plot, reference, read = job.plot, job.reference, job.reading
    if plot and not str(plot).lower().endswith(".png"):
        raise InputError(f"{{opt:plot}} {plot}: give a .png file name")
    if plot:
        check_place("plot", plot)
    model, feats = _load_queries(job, progress)
    ref, labels, note = reference_features(
        model, reference, read.descriptor, read.tile, read.stride, progress,
        weights=read.weights, compile=read.compile,
    )  # fmt: skip
    if ref is not None and reference is None and "reference_labels" in model.extra:
        labels = model.extra["reference_labels"]  # frames grouped into places
    truth = None
    if job.ground_truth is not None:
        from rhythmic_jax.eval.ground_truth_files import load_ground_truth

        refs = [reference] if reference else model.reference.get("sources") or []
        truth = load_ground_truth(
            job.ground_truth, n_queries=len(feats.x), n_places=model.n,
            query_source=job.source, reference_sources=refs, map_extra=model.extra,
            tolerance_m=job.tolerance_m,
        )  # fmt: skip
    result = evaluate_map(
        model, feats.x, reference=ref, reference_labels=labels, tolerance=job.tolerance,
        method=job.decode, sequence=job.sequence, ground_truth=truth, curves=bool(plot),
    )  # fmt: skip
    result["reference_note"] = note
    if plot:
        from rhythmic_jax.eval.figures import plot_evaluation

        with write_errors("plot", plot):
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
