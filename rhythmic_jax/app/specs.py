"""What a job is: the settings of each command, and the rules they obey.

A job is a frozen dataclass that checks itself when it is made, before any
work: each numeric setting against its domain (:data:`DOMAINS`, which the
command line also parses its options with and states in ``--help``) and every
setting against the others (the job's ``RULES``, :class:`Rule`: an option given
where it has no effect, or without one it needs). :func:`check_paths` refuses a
command whose outputs would overwrite what it reads. Running a job is
:mod:`rhythmic_jax.app.jobs`; what it prints, :mod:`rhythmic_jax.app.render`.

Errors name settings by parameter (``{opt:tile}``); the command line spells them
as flags. Importing this module imports no numpy, JAX or torch: the command
line builds its parser and its jobs from it at once.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import MISSING, dataclass, field, fields, is_dataclass
from pathlib import Path
from typing import Any, ClassVar

from rhythmic_jax.errors import InputError
from rhythmic_jax.frames.compile_policy import AUTO, CompilePolicy
from rhythmic_jax.map.config import MapConfig
from rhythmic_jax.validate import Domain, int_option, is_number, number_option

__all__ = [
    "DOMAINS", "DescribeJob", "EvaluateJob", "FitInterrupted", "FitJob", "GRIDS",
    "LearnJob", "OptionRefused", "QueryJob", "Reading", "Reported", "Rule",
    "ScaleJob", "check_paths", "learn_config", "GROUND_TRUTH_FORMATS", "RECALL_OVER",
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
    "top": int_option(1),
    "threshold": number_option(),
    "tolerance": int_option(0),
    "tolerance_m": number_option(0),
    "budget": number_option(0),
}


# ground-truth formats (rhythmic_jax.eval.ground_truth_formats.FORMATS) and
# recall@K's denominators (rhythmic_jax.eval.metrics.RECALL_OVER), named here
# for the parser, which imports no numpy
GROUND_TRUTH_FORMATS = ("vpr-bench", "openvprlab", "vpr-tutorial", "patch-netvlad",
                        "positions")  # fmt: skip
RECALL_OVER = ("matched", "all")

MAPS = tuple((r, level) for r in (2, 3) for level in (1, 2, 3, 4))
#: What each ``frontier --grid`` fits: maps as (r, level), ITQ bits, PQ
#: sub-quantisers; ``--maps``, ``--bits`` and ``--pq`` replace a grid's own.
#: ``small`` runs in a couple of minutes on a few thousand places.
GRIDS = {
    "small": {"maps": ((2, 1), (2, 2), (3, 1)), "bits": (64, 128, 256), "pq": (16, 32)},
    "full": {"maps": MAPS, "bits": (32, 64, 128, 256, 512), "pq": (8, 16, 32, 64)},
}


def grid_text(name: str) -> str:
    """A grid in the options' words: ``maps 2:1,2:2,3:1; bits 64,..; pq 16,32``."""
    g = GRIDS[name]
    maps = ",".join(f"{r}:{level}" for r, level in g["maps"])
    return (f"maps {maps}; bits {','.join(map(str, g['bits']))}; "
            f"pq {','.join(map(str, g['pq']))}")  # fmt: skip


class OptionRefused(InputError):
    """A setting given where it has no effect, or without one it needs."""


class FitInterrupted(KeyboardInterrupt):
    """Ctrl-C during an augmented fit; ``note`` says where its checkpoint is kept."""

    def __init__(self, note: str):
        super().__init__(note)
        self.note = note


class Reported(Exception):
    """A failure whose one line a process of the command has printed already:
    the command ends with ``status`` and says nothing more."""

    def __init__(self, status: int):
        super().__init__(status)
        self.status = status


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

    @property
    def images(self) -> bool:
        """Whether a source of the job may be images (not only .npy descriptors)."""
        return not all(str(s).lower().endswith(".npy") for s in self.read_sources)


READS = (
    Rule(("stride",), "needs {opt:tile} (it is the step between tiles)",
         lambda j: j.reading.tile is not None),
    Rule(("descriptor", "weights"), "applies to images; .npy files are descriptors",
         lambda j: j.images),
)  # fmt: skip
SELECTS = (  # fit, query, evaluate
    Rule(("select",), "picks the images of hloc .h5 files by name; give .h5 "
         "files", lambda j: _named_rows(j)),
)  # fmt: skip


def _named_rows(job) -> bool:
    """Whether every source ``select`` applies to is an hloc ``.h5`` file."""
    sources = job.sources if hasattr(job, "sources") else (job.source,)
    return all(Path(s).suffix.lower() in (".h5", ".hdf5") for s in sources)


IGNORED = (
    Rule(("compile_min_frames",), "acts only with {opt:compile} auto; ignored",
         lambda j: j.reading.compile.mode == "auto", warn=True),
    Rule(("compile", "compile_min_frames"), "applies to images; .npy files are "
         "descriptors; ignored", lambda j: j.images, warn=True),
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
      select: the rows of hloc ``.h5`` sources whose image names start with it
        (``"db/"``, ``"query/"``); a map remembers the prefix it was fitted
        with, for brute force over its reference.
    """

    descriptor: str | None = None
    weights: str | None = None
    tile: int | None = None
    stride: int | None = None
    compile: CompilePolicy = AUTO
    select: str | None = None


@dataclass(frozen=True)
class ScaleJob:
    """How a fit from files is spread and bounded (see ``rhythmic-jax fit
    --help``; run by :mod:`rhythmic_jax.app.scale_jobs`); its settings are
    checked with the fit job's (:class:`FitJob`)."""

    processes: int = 1
    coordinator: str | None = None
    num_processes: int | None = None
    process_id: int | None = None
    memory: str | None = None
    stream: bool = False
    shards: str | None = None

    @property
    def asked(self) -> bool:
        """Whether a fit from files is asked for by a setting of its own
        (processes, a cluster, a memory bound or streaming)."""
        return bool(
            (self.processes or 1) != 1 or self.coordinator or self.memory or self.stream
        )


def _layout(job):
    """The job's ``--layout`` (:func:`rhythmic_jax.map.groups.parse_layout`)."""
    from rhythmic_jax.map.groups import parse_layout

    return parse_layout(job.config.layout)


def _scaled(job) -> bool:
    """Whether a fit may run from files at scale (where a checkpoint acts too)."""
    s = job.scale
    return bool(s.asked or s.shards or any(Path(p).is_dir() for p in job.sources))


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
    for the ground truth of :func:`rhythmic_jax.app.jobs.evaluate`; ``places``
    groups the frames into that many places by k-means over them (the RobotCar
    protocol; traversals may then differ in length). ``embedding`` names a
    folder written by :func:`rhythmic_jax.app.jobs.learn`: it is saved inside
    the map and applied to every query (with codes, ITQ is fitted on the
    embedded reference frames); image sources are described with its
    descriptor unless ``reading`` names one, and ``fusion`` None takes the
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
        *SELECTS,
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


@dataclass(frozen=True)
class LearnJob(Checked):
    """An embedding to learn from two or more traversals and write to ``out``.

    ``rhythmic-jax learn a.npy b.npy --out route.emb`` is
    ``learn(LearnJob(("a.npy", "b.npy"), "route.emb"))``; ``config`` is a
    :class:`rhythmic_jax.LearnConfig` (method, head, k, steps, seed). ``codes``
    (a number of ITQ bits, or int8; None: none) are those a map's fusion weight
    is learned for on the same traversals
    (:func:`rhythmic_jax.app.fusion.learn_fusion`), saved with the embedding
    for ``fit --embedding``. ``given``: see :class:`Checked`.
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


def learn_config(**settings) -> Any:
    """A :class:`rhythmic_jax.LearnConfig` (method, head, k, steps, seed)."""
    from rhythmic_jax.fitting.learn import LearnConfig

    return LearnConfig(**settings)


@dataclass(frozen=True)
class QueryJob(Checked):
    """Queries of ``source`` to localise with the map at ``map``.

    ``rhythmic-jax query route.map q.npy --out pred.npy`` is
    ``query(QueryJob("route.map", "q.npy", out="pred.npy"))``: ``decode``,
    ``sequence`` and ``threshold`` as :meth:`rhythmic_jax.RhythmicMap.predict`
    takes them; with ``out`` the predictions are also written there (``.npy``,
    atomically; its folder must exist). ``top`` best places per query, with
    their scores, go to ``csv`` (a file, atomically) and, with ``json``, to the
    printed JSON (:func:`rhythmic_jax.app.jobs.query_results`). ``given``: see
    :class:`Checked`.
    """

    map: str
    source: str
    decode: str | None = None
    sequence: int | None = None
    threshold: float | None = None
    out: str | None = None
    top: int = 5
    csv: str | None = None
    json: bool = False
    reading: Reading = Reading()
    given: frozenset[str] = frozenset()

    RULES = (
        *READS,
        *SELECTS,
        Rule(("top",), "needs {opt:json} or {opt:csv} (the results per query it "
             "sizes)", lambda j: j.json or j.csv is not None),
        *IGNORED,
    )  # fmt: skip

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
    ``tolerance_m`` metres); ``ground_truth_format`` names its format (one
    of :data:`GROUND_TRUTH_FORMATS`; None: read from what the file holds);
    ``recall_over``: recall@K's denominator (:data:`RECALL_OVER`: the queries
    with a right place, or all); ``plot``: a .png of PR curves, recall at
    N = 1..20 and the predicted place along the route; ``matches``: a .png of
    queries beside the place chosen and the right place (image folders).
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
    matches: str | None = None
    reading: Reading = Reading()
    given: frozenset[str] = frozenset()
    ground_truth_format: str | None = None
    recall_over: str = "matched"

    RULES = (
        *READS,
        *SELECTS,
        Rule(("tolerance",), "acts only without {opt:ground_truth} (which names the "
             "right places itself)", lambda j: j.ground_truth is None),
        Rule(("tolerance_m",), "needs {opt:ground_truth} (positions or names: it is "
             "their radius of a right match)", lambda j: j.ground_truth is not None),
        Rule(("ground_truth_format",), "needs {opt:ground_truth} (it names that "
             "file's format)", lambda j: j.ground_truth is not None),
        *IGNORED,
    )  # fmt: skip

    @property
    def read_sources(self) -> tuple[str, ...]:
        return (self.source,) + ((self.reference,) if self.reference else ())


@dataclass(frozen=True)
class DescribeJob(Checked):
    """The frames of ``source`` described once and written to ``out`` (.npy).

    ``rhythmic-jax describe summer/ --descriptor efficientnet_lite0 --out
    summer.npy`` is ``describe(DescribeJob("summer/", "summer.npy",
    Reading(descriptor="efficientnet_lite0")))``
    (:func:`rhythmic_jax.frames.route_descriptors.describe_frames`); ``fit``,
    ``query``, ``evaluate`` and ``frontier`` then read the file. ``given``: see
    :class:`Checked`.
    """

    source: str
    out: str
    reading: Reading = Reading()
    given: frozenset[str] = frozenset()

    RULES = (
        Rule(("stride",), "needs {opt:tile} (it is the step between tiles)",
             lambda j: j.reading.tile is not None),
        *IGNORED[:1],
    )  # fmt: skip

    @property
    def read_sources(self) -> tuple[str, ...]:
        return (self.source,)


# What each command writes and reads, by destination: no path written may be,
# hold or lie inside another the job reads or writes.
WRITTEN = {
    "fit": ("out", "checkpoint", "shards"),
    "learn": ("out",),
    "query": ("out", "csv"),
    "evaluate": ("plot", "matches"),
    "frontier": ("csv", "plot"),
    "describe": ("out",),
}
READ = {
    "fit": ("sources", "embedding", "positions", "weights"),
    "learn": ("sources", "weights"),
    "query": ("map", "source", "weights"),
    "evaluate": ("map", "source", "reference", "ground_truth", "weights"),
    "frontier": ("reference", "queries", "ground_truth"),
    "describe": ("source", "weights"),
}
ROLES = {
    "map": "the map",
    "source": "the queries",
    "sources": "the source",
    "queries": "the queries",
}
NAMES = ("names",)  # --positions / --ground-truth names: no file


def _flag(dest: str) -> str:
    return ROLES.get(dest) or "--" + dest.replace("_", "-")


def _paths(args, dests) -> list[tuple[str, str]]:
    """(dest, path) of every path given to ``dests`` (lists flattened)."""
    out = []
    for dest in dests:
        value = getattr(args, dest, None)
        for v in value if isinstance(value, list | tuple) else [value]:
            if v is not None and v not in NAMES:
                out.append((dest, str(v)))
    return out


def _clash(w: Path, r: Path) -> str | None:
    if w == r:
        return "the same path as"
    if r in w.parents and not r.is_file():  # under a file: no path (said later)
        return "inside"
    if w in r.parents:
        return "holding"
    return None


def check_paths(args) -> str | None:
    """The line refusing a path the job would write over something it reads
    (or writes twice), compared resolved (through links and ``..``), or None."""
    writes = _paths(args, WRITTEN.get(args.command, ()))
    if args.command == "fit" and args.checkpoint is None:
        writes.append(("checkpoint", str(args.out) + ".ckpt"))  # its default
    reads = _paths(args, READ.get(args.command, ()))
    for i, (dest, path) in enumerate(writes):
        w = Path(path).expanduser().resolve()
        others = [(d, p, "reads") for d, p in reads]
        others += [(d, p, "writes") for d, p in writes[i + 1 :]]
        for other, opath, verb in others:
            how = _clash(w, Path(opath).expanduser().resolve())
            if how is not None:
                return (
                    f"{_flag(dest)} {path}: {how} {_flag(other)} {opath}, which "
                    f"this job {verb}; give another path"
                )
    return None
