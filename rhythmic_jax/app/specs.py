"""What a job is: the settings of each command, its options, and their rules.

A job is a frozen dataclass whose fields are the command's options
(:mod:`rhythmic_jax.app.options`: help, default, choices, domain); the command
line renders its parser from them and makes the job from what it parsed. A job
checks itself when it is made, before any work
(:class:`~rhythmic_jax.app.options.Checked`): each numeric setting against its
domain, and every setting against the others (the job's ``RULES``: an option
given where it has no effect, or without one it needs). Running a job is
:mod:`rhythmic_jax.app.jobs`; what it prints, :mod:`rhythmic_jax.app.render`.

Errors name settings by parameter (``{opt:tile}``); the command line spells them
as flags. Importing this module imports no numpy, JAX or torch.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from rhythmic_jax.app.options import Checked, Rule, like, option, part
from rhythmic_jax.errors import InputError
from rhythmic_jax.frames.compile_policy import CompilePolicy
from rhythmic_jax.map.config import DECODERS, MapConfig
from rhythmic_jax.validate import (
    Domain,
    int_option,
    number_option,
    parse_bytes,
)

__all__ = [
    "DemoJob", "DescribeJob", "EvaluateJob", "FitInterrupted", "FitJob",
    "FrontierJob", "GRIDS", "GROUND_TRUTH_FORMATS", "InfoJob", "LearnJob",
    "QueryJob", "RECALL_OVER", "Reading", "Reported", "ScaleJob", "learn_config",
]  # fmt: skip


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


@dataclass(frozen=True, kw_only=True)
class Job(Checked):
    """A job that shows its progress unless told not to."""

    no_progress: bool = option("hide progress bars", False)


READS = (
    Rule(("stride",), "needs {opt:tile} (it is the step between tiles)",
         lambda j: j.reading.tile is not None),
    Rule(("weights",), "applies to images, or with {opt:descriptor} to .npy files "
         "it declares", lambda j: j.images or j.reading.descriptor is not None),
    Rule(("input_size",), "must be WIDTHxHEIGHT in pixels, such as 224x112",
         lambda j: _size_ok(j.reading.input_size)),
)  # fmt: skip


def recall_values(text: str) -> tuple[int, ...] | None:
    """``"1,5,10"`` -> ``(1, 5, 10)`` sorted and unique; None for other text."""
    parts = [p.strip() for p in str(text).split(",")]
    if not parts or not all(p.isdigit() and int(p) >= 1 for p in parts):
        return None
    return tuple(sorted({int(p) for p in parts}))


def _size_ok(text: str | None) -> bool:
    w, sep, h = str(text).lower().partition("x")
    return bool(sep) and w.isdigit() and h.isdigit() and int(w) > 0 and int(h) > 0
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
    """How frames are read from a source (:mod:`rhythmic_jax.frames.sources`);
    ``compile``: :class:`rhythmic_jax.frames.compile_policy.CompilePolicy`.
    ``select`` (rows of hloc ``.h5`` sources) is worded by each job offering it;
    a map remembers its prefix, for brute force over its reference."""

    descriptor: str | None = option(
        "descriptor for image sources (patchnorm, hog, efficientnet_lite0, "
        "vgg16_fc7; default patchnorm, or an --embedding's); for a .npy without "
        "describe's record, the descriptor that made it; a map remembers its own")
    input_size: str | None = option(
        "the descriptor's input in pixels, width x height, frames resized to it "
        "(default: patchnorm and hog 64x32 grey, efficientnet_lite0 224x112, "
        "vgg16_fc7 224x224); maps, embeddings and described files record it, and "
        "a map takes queries described at its own", metavar="WxH")
    weights: str | None = option(
        "weights file of vgg16_fc7 (a state dict); when querying a map, a moved "
        "copy of the file it was fitted with (its sha256 is checked)", path="reads")
    tile: int | None = option("tile a large image: size (queries of a tiled map: "
                              "the map's own)", domain=int_option(1))
    stride: int | None = option("tile stride, with --tile (default size/2)",
                                domain=int_option(1))
    compile: CompilePolicy = part(CompilePolicy)
    select: str | None = option(None, metavar="PREFIX")


@dataclass(frozen=True)
class ScaleJob:
    """How a fit from files is spread and bounded (run by
    :mod:`rhythmic_jax.app.scale_jobs`); checked with its :class:`FitJob`."""

    processes: int = option("start this many local processes for one fit (frames "
                            "split by rows)", 1, domain=int_option(1, 256))
    coordinator: str | None = option("HOST:PORT of process 0")
    num_processes: int | None = option("K hosts", domain=int_option(1, 65536))
    process_id: int | None = option("this one's i", domain=int_option(0, 65535))
    memory: str | None = option(
        "bytes each process may use (1GiB, 800M); frames that do not fit are "
        "streamed from disk in blocks",
        domain=Domain(True, 1, 2**50, parse=parse_bytes,
                      what="a size (1GiB, 800M)"))
    stream: bool = option("stream the frames from disk always", False)
    shards: str | None = option(
        "image sources: describe them into this folder of .npy shards as they are "
        "read, then fit from the shards", path="writes")

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
class FitJob(Job):
    """A map to fit from reference sources and write to ``out``:
    ``rhythmic-jax fit ref.npy --out route.map`` is ``fit(FitJob(("ref.npy",),
    "route.map"))``. ``config``'s descriptor is the sources' and its fusion
    weight ``fusion``'s; ``positions`` ``("names",)`` reads ``@easting@northing@``
    file names; an ``embedding``'s descriptor reads image sources unless
    ``reading`` names one, and with codes ITQ is fitted on the embedded frames.
    """

    sources: tuple[str, ...] = option("descriptor .npy, image folder(s), image",
                                      positional=True, nargs="+", path="frames")
    out: str = option("map folder to write", required=True, path="writes")
    config: MapConfig = part(MapConfig)
    pca: int | None = option("project descriptors to K dims (saved)",
                             domain=int_option(1))
    augment: str | None = option(
        "train over frames augmented on the fly (image sources): comma-separated "
        "names from gaussian_blur, hflip, random_crop, elastic, contrast, invert, "
        "grayscale, or 'all'")
    epochs: int | None = option("augmented epochs (default 3)", domain=int_option(1))
    batch_size: int | None = option("augmented frames per step (default 128)",
                                    domain=int_option(1))
    checkpoint: str | None = option(
        "checkpoint folder of an augmented fit (default OUT.ckpt, removed once the "
        "map is saved); a killed or interrupted fit resumes from it when the same "
        "command runs again", path="writes")
    checkpoint_every: int | None = option(
        "steps between checkpoints of an augmented fit (default 50)",
        domain=int_option(1))
    fusion: float | None = option(
        "the map's share of the fused score with --codes (default: the weight the "
        "--embedding learned for these codes, else 0.5)",
        domain=number_option(0, 1, closed=True))
    reading: Reading = part(Reading, helps={"select": "only the images of hloc .h5 "
        "sources whose names start with PREFIX (db/; the map keeps it for brute "
        "force)"})  # fmt: skip
    positions: tuple[str, ...] | None = option(
        "per-frame positions of the sources, one CSV/.npy per source "
        "(easting,northing metres or latitude,longitude), or 'names' for "
        "@easting@northing@ file names; saved for evaluate --ground-truth",
        nargs="+", path="reads")
    places: int | None = option(
        "group the frames into K places by k-means over --positions (the RobotCar "
        "protocol); traversals may then differ in length", domain=int_option(1))
    embedding: str | None = option(
        "embedding folder written by 'rhythmic-jax learn' (saved in the map and "
        "applied to every query; its descriptor unless --descriptor is given)",
        path="reads")
    scale: ScaleJob = part(ScaleJob, group="scale (descriptor files or shard "
                           "folders)")
    json: bool = option("print the map's info as JSON", False)

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

    def implied_writes(self) -> list[tuple[str, str]]:
        """The checkpoint folder's default, ``OUT.ckpt``, when none is given."""
        if self.checkpoint is not None:
            return []
        return [("checkpoint", str(self.out) + ".ckpt")]

    @property
    def checkpoint_folder(self) -> Path:
        """The checkpoint folder (default ``OUT.ckpt``); refused when a file."""
        ckpt = Path(self.checkpoint or str(Path(self.out)) + ".ckpt").absolute()
        if ckpt.exists() and not ckpt.is_dir():
            raise InputError(f"{{opt:checkpoint}} {ckpt}: a file, not a folder")
        return ckpt


@dataclass(frozen=True)
class LearnSettings:
    """The settings of :class:`rhythmic_jax.fitting.learn.LearnConfig` that
    ``learn`` offers, with the command's defaults."""

    method: str = option(
        "invariant: closed form, pca: principal axes only, map: learned through the "
        "map, infonce: InfoNCE", "invariant",
        choices=("invariant", "pca", "map", "infonce"))
    head: str = option("the learned head of --method map or infonce: linear (k x "
                       "k) or mlp (plus a residual ReLU layer)", "linear",
                       choices=("linear", "mlp"))
    k: int = option("output dimensions", 256, domain=int_option(1))
    holdout: float = option(
        "share of the route's places (its end, after a gap) never learned from, "
        "where the embedding's codes are measured against the raw descriptors'",
        0.2, domain=number_option(0, 0.5, closed=True))
    steps: int = option("gradient steps", 300, domain=int_option(1))
    seed: int = option("PRNG seed", 0, domain=int_option(0, 2**32 - 1))


def learn_config(**settings) -> Any:
    """A :class:`rhythmic_jax.LearnConfig` (method, head, k, holdout, steps, seed)."""
    from rhythmic_jax.fitting.learn import LearnConfig

    return LearnConfig(**settings)


@dataclass(frozen=True)
class LearnJob(Job):
    """An embedding to learn from two or more traversals and write to ``out``:
    ``rhythmic-jax learn a.npy b.npy --out route.emb`` is
    ``learn(LearnJob(("a.npy", "b.npy"), "route.emb"))``; ``config``: a
    :class:`rhythmic_jax.LearnConfig`; ``codes``: those a map's fusion weight is
    learned for (:func:`rhythmic_jax.app.fusion.learn_fusion`; None: none)."""

    sources: tuple[str, ...] = option("one source per traversal (same places)",
                                      positional=True, nargs="+", path="frames")
    out: str = option("embedding folder to write", required=True, path="writes")
    config: Any = part(LearnSettings, None, make=learn_config)
    codes: int | str | None = option(
        "codes a map's fusion weight is learned for on these traversals and saved "
        "with the embedding for fit --embedding", "int8", metavar="BITS|int8",
        domain=Domain(True, 1, words=("int8",)))
    reading: Reading = part(Reading)

    RULES = (
        *READS,
        Rule(("head", "steps", "seed"), "acts only with {opt:method} map or infonce "
             "(the closed forms take no steps)",
             lambda j: j.config is None or j.config.method in ("map", "infonce")),
        *IGNORED,
    )  # fmt: skip


SELECT = "only the queries of an hloc .h5 whose names start with PREFIX (query/)"


@dataclass(frozen=True)
class QueryJob(Job):
    """Queries of ``source`` to localise with the map at ``map``:
    ``rhythmic-jax query route.map q.npy --out pred.npy`` is
    ``query(QueryJob("route.map", "q.npy", out="pred.npy"))``; ``decode``,
    ``sequence`` and ``threshold`` as :meth:`rhythmic_jax.RhythmicMap.predict`
    takes them (:func:`rhythmic_jax.app.jobs.query_results`: ``top``)."""

    map: str = option("map folder", positional=True, path="reads")
    source: str = option("query descriptors .npy, image folder or image",
                         positional=True, path="frames")
    decode: str | None = option(
        "how a query's place is read from the map's scores: hard (the best phase of "
        "each period, joined by the Chinese remainder; -1, no match, when they name "
        "no place of the route), soft (the place of the highest summed phase "
        "scores), topm (soft among the top best phases of each period); default the "
        "map's own (fit: hard)", choices=DECODERS)
    sequence: int | None = option("sequence length L (at most the number of "
                                  "queries; default off: single frames)",
                                  domain=int_option(1))
    threshold: float | None = option("reject queries whose confidence is below "
                                     "this (default none: every query gets a "
                                     "place)", domain=number_option())
    out: str | None = option("write predictions to this .npy", path="writes")
    top: int = option("best places listed per query (--json, --csv)", 5,
                      domain=int_option(1))
    csv: str | None = option(
        "write the results per query as CSV (query, place, place_name, score, "
        "confidence, top1, top1_name, top1_score, ...)", path="writes")
    json: bool = option(
        "print JSON: the predictions, and per query its name (file name, else "
        "row number, as a string) and index (row), the place chosen (and its name "
        "where the map's reference names it), its score and confidence, and the "
        "--top best places with their scores", False)
    pairs: str | None = option(
        "write hloc's retrieval pairs: 'query_name reference_name' per line, the "
        "--top best places of each query in rank order (as hloc's "
        "pairs_from_retrieval writes them), for hloc's local matching; the queries "
        "and places must have names (image folders, hloc .h5, or described .npy)",
        path="writes")
    ground_truth: tuple[str, ...] | None = option(
        "with --csv or --json: add whether each answer is right ('correct'), "
        "the ground truth read as evaluate reads it", nargs="+", metavar="FILE",
        path="reads")
    ground_truth_format: str | None = option(
        "the --ground-truth file's format (default: read from what it holds)",
        choices=GROUND_TRUTH_FORMATS)
    tolerance_m: float = option("radius of a right match for positions, metres "
                                "(default %(default)g)", 25.0,
                                domain=number_option(0))
    reading: Reading = part(Reading, helps={"select": SELECT})

    RULES = (
        *READS,
        *SELECTS,
        Rule(("top",), "needs {opt:json}, {opt:csv} or {opt:pairs} (the results "
             "per query it sizes)",
             lambda j: j.json or j.csv is not None or j.pairs is not None),
        Rule(("ground_truth",), "needs {opt:json} or {opt:csv} (it adds their "
             "'correct')", lambda j: j.json or j.csv is not None),
        Rule(("ground_truth_format",), "needs {opt:ground_truth} (it names that "
             "file's format)", lambda j: j.ground_truth is not None),
        Rule(("tolerance_m",), "needs {opt:ground_truth} (positions or names: it "
             "is their radius of a right match)", lambda j: j.ground_truth is not None),
        *IGNORED,
    )  # fmt: skip


@dataclass(frozen=True)
class EvaluateJob(Job):
    """The map at ``map`` judged on the queries of ``source``, beside brute force,
    a baseline at the map's own bytes (int8 per place, else PCA) and, for an
    embedded map, brute force on its embedding, all over the reference frames
    (:func:`rhythmic_jax.app.jobs.evaluate`); ``ground_truth`` as
    :func:`rhythmic_jax.eval.ground_truth_files.load_ground_truth` reads it."""

    map: str = like(QueryJob, "map")
    source: str = like(QueryJob, "source")
    reference: str | None = option(
        "reference source for the brute-force line and the baselines at the "
        "map's bytes (default: the sources the map was fitted on, when they are "
        "still there)", path="frames")
    tolerance: int = option("frame tolerance (default 0)", 0, domain=int_option(0))
    decode: str | None = like(QueryJob, "decode")
    sequence: int | None = option(
        "sequence length L, at most the number of queries (accuracy, PR and "
        "recall@K use the sequence scores; default off)", domain=int_option(1))
    ground_truth: tuple[str, ...] | None = option(
        "VPR-Bench ground_truth_new.npy; or QUERY_POSITIONS (the map's from fit "
        "--positions); or REF_POSITIONS QUERY_POSITIONS; or 'names' "
        "(@easting@northing@ file names). Default: query i is place i",
        nargs="+", metavar="FILE", path="reads")
    ground_truth_format: str | None = option(
        "the --ground-truth file's format (default: read from what it holds; its "
        "name only breaks a tie)", choices=GROUND_TRUTH_FORMATS)
    tolerance_m: float = option("radius of a right match for positions, metres "
                                "(default %(default)g)", 25.0,
                                domain=number_option(0))
    recall_over: str = option(
        "recall@K's denominator: the queries with a right place (matched, "
        "VPR_Tutorial's; default) or every query (all, VPR-methods-evaluation's); "
        "the table says which", "matched", choices=RECALL_OVER)
    plot: str | None = option(
        "write PR curves, recall@N (N = 1..20) and the predicted place against "
        "query index along the route (.png)", path="writes")
    matches: str | None = option(
        "draw queries beside the place chosen and the right place, 4 successes and "
        "the 4 most confident failures (.png; the queries and the reference as "
        "image folders, or descriptor files describe wrote, which name their "
        "frames)", path="writes")
    reference_images: str | None = option(
        "with --matches: the reference frames' image folder (default: the map's "
        "reference, or the folder its descriptor file's record names)", path="reads")
    query_images: str | None = option(
        "with --matches: the query frames' image folder (default: the queries, or "
        "the folder their descriptor file's record names)", path="reads")
    per_query: str | None = option(
        "write each query's result (.csv or .json by the suffix): its name and "
        "index, the place chosen and its name, the right places, correct or not, "
        "score, confidence and its --num-preds best places", path="writes")
    num_preds: int = option("best places kept per query in --per-query "
                            "(default %(default)s)", 5, domain=int_option(1))
    recall_values: str = option("the K of recall@K, comma-separated (default "
                                "%(default)s)", "1,5,10,20", metavar="K,K,...")
    json: bool = option("print JSON", False)
    reading: Reading = part(Reading, helps={
        "select": SELECT + " (an .h5 reference: the map's prefix)"})  # fmt: skip

    RULES = (
        *READS,
        *SELECTS,
        Rule(("tolerance",), "acts only without {opt:ground_truth} (which names the "
             "right places itself)", lambda j: j.ground_truth is None),
        Rule(("tolerance_m",), "needs {opt:ground_truth} (positions or names: it is "
             "their radius of a right match)", lambda j: j.ground_truth is not None),
        Rule(("ground_truth_format",), "needs {opt:ground_truth} (it names that "
             "file's format)", lambda j: j.ground_truth is not None),
        Rule(("reference_images", "query_images"), "needs {opt:matches} (it names "
             "the frames drawn)", lambda j: j.matches is not None),
        Rule(("num_preds",), "needs {opt:per_query} (the records it sizes)",
             lambda j: j.per_query is not None),
        Rule(("recall_values",), "must be integers >= 1, comma-separated (1,5,10)",
             lambda j: recall_values(j.recall_values) is not None),
        *IGNORED,
    )  # fmt: skip


@dataclass(frozen=True)
class DescribeJob(Job):
    """The frames of ``source`` described once and written to ``out``
    (:func:`rhythmic_jax.frames.route_descriptors.describe_frames`)."""

    source: str = option("image folder (frames sorted by name), or one large image "
                         "with --tile", positional=True, path="frames")
    out: str = option("descriptor file to write (.npy, float32, one row per frame)",
                      required=True, path="writes")
    reading: Reading = part(Reading)

    RULES = (READS[0], READS[2], IGNORED[0])


@dataclass(frozen=True)
class InfoJob(Checked):
    """A map's or an embedding's info (:func:`rhythmic_jax.app.jobs.info`)."""

    map: str = option("map folder (or embedding folder)", positional=True)
    json: bool = like(EvaluateJob, "json")


@dataclass(frozen=True)
class DemoJob(Job):
    """The demo (:func:`rhythmic_jax.app.demo.run_demo`)."""

    out: str | None = option("report folder (default: a fresh folder under the "
                             "system's temporary folder; the report line names it)")
    quick: bool = option("a smaller route (CI)", False)


def int_list(least: int = 1, empty: bool = False) -> Domain:
    """An argparse ``type``: comma-separated integers, each >= ``least`` (the
    text kept; ``empty``: '' taken too, for none)."""

    def smallest(text: str) -> int:
        return min(int(v) for v in str(text).split(","))

    return Domain(True, least, words=("",) * empty, parse=smallest,
                  what="comma-separated integers")  # fmt: skip


@dataclass(frozen=True)
class PairDomain(Domain):
    """:func:`pair_list`'s domain: its words name both ranges (``--help``)."""

    ranges: tuple[tuple[str, Domain], ...] = ()

    def text(self, whole: bool = True) -> str:
        each = ", ".join(f"{name} {d.bounds(whole)}" for name, d in self.ranges)
        return f"{self.what} ({each})"


def pair_list() -> Domain:
    """An argparse ``type``: comma-separated ``r:level`` pairs, each ``r`` and
    ``level`` in the domain ``fit`` gives ``--r`` and ``--level`` (the text
    kept)."""
    ranges = {f.name: f.metadata["domain"] for f in fields(MapConfig)
              if f.name in ("r", "level")}  # fmt: skip

    def pairs(text: str) -> int:
        for pair in str(text).split(","):
            values = pair.split(":")
            if len(values) != 2:
                raise ValueError(pair)
            for name, value in zip(ranges, map(int, values), strict=True):
                try:
                    ranges[name].check(value)
                except InputError as err:
                    raise argparse.ArgumentTypeError(
                        f"{name} {err} (in {pair!r})") from None
        return 1

    return PairDomain(True, 1, parse=pairs, what="comma-separated r:level pairs",
                      ranges=tuple(ranges.items()))


@dataclass(frozen=True)
class FrontierJob(Job):
    """The frontier's options; :func:`rhythmic_jax.app.frontier.main` reads them
    from the parsed command line."""

    reference: str = option("reference descriptors (.npy, .h5) or folder",
                            positional=True, path="reads")
    queries: str = option("query descriptors (.npy, .h5) or folder", positional=True,
                          path="reads")
    select: tuple[str, str] | None = option(
        "the images of hloc .h5 files whose names start with REF_PREFIX, "
        "QUERY_PREFIX ('' takes all): one file split in two",
        nargs=2, metavar=("REF_PREFIX", "QUERY_PREFIX"))
    ground_truth: tuple[str, ...] | None = like(
        EvaluateJob, "ground_truth", "as evaluate reads it (default: query i is "
        "place i)")
    ground_truth_format: str | None = like(EvaluateJob, "ground_truth_format")
    recall_over: str = like(EvaluateJob, "recall_over")
    tolerance: int = like(EvaluateJob, "tolerance")
    tolerance_m: float = like(EvaluateJob, "tolerance_m",
                              "radius for positions, m (default %(default)g)")
    budget: float | None = option("name the best representation within this many "
                                  "bytes", metavar="BYTES_PER_PLACE",
                                  domain=number_option(0))
    grid: str = option(
        "the representations fitted unless --maps, --bits or --pq say otherwise: "
        f"small ({grid_text('small')}: a couple of minutes on a few thousand "
        f"places), full ({grid_text('full')})", "small", choices=tuple(GRIDS))
    maps: str | None = option("maps as r:level,... (default: the --grid's)",
                              domain=pair_list())
    bits: str | None = option("ITQ code sizes, comma-separated (default: the "
                              "--grid's)", domain=int_list(1))
    pq: str | None = option("PQ sub-quantisers ('': none; default: the --grid's)",
                            domain=int_list(1, empty=True))
    lengths: str = option("sequence lengths L, each at most the queries", "1,5,10",
                          domain=int_list(1))
    descriptor: str | None = option("descriptor for image folders (default "
                                    "patchnorm)")
    input_size: str | None = like(Reading, "input_size")
    recall_values: str = like(
        EvaluateJob, "recall_values", "the K of each row's single-frame recall@K "
        "(rows, --json, --csv: recall@K L=1), comma-separated; given, the table "
        "shows them too (default %(default)s)")
    cache: str = option("folder keeping fitted maps and codes (default none)", "")
    csv: str | None = option("write the rows as CSV", path="writes")
    plot: str | None = option("draw the frontier (.png)", path="writes")
    json: bool = like(EvaluateJob, "json")

    RULES = (
        Rule(("input_size",), READS[2].says, lambda j: _size_ok(j.input_size)),
        Rule(("recall_values",), next(r.says for r in EvaluateJob.RULES
                                      if r.options == ("recall_values",)),
             lambda j: recall_values(j.recall_values) is not None),
    )  # fmt: skip
