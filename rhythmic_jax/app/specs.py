"""What a job is: the settings of each command, its options, and their rules.

A job is a frozen dataclass whose fields are the command's options
(:mod:`rhythmic_jax.app.options`: help, default, choices, domain); the command
line renders its parser from them and makes the job from what it parsed. A job
checks itself when it is made, before any work
(:class:`~rhythmic_jax.app.options.Checked`): each numeric setting against its
domain, and every setting against the others (the job's ``RULES``: an option
given where it has no effect, or without one it needs). Running a job is
:mod:`rhythmic_jax.app.jobs`; what it prints, :mod:`rhythmic_jax.app.render`.

Every default is stated once, in its option's declaration, and rendered into
``--help`` from there (:func:`rhythmic_jax.app.options.default_phrase`). The
parts jobs share (how frames are read, how a fit is spread) are
:mod:`rhythmic_jax.app.parts`; the jobs that judge a map on queries,
:mod:`rhythmic_jax.app.query_specs`; every job is named here.

Errors name settings by parameter (``{opt:tile}``); the command line spells them
as flags. Importing this module imports no numpy, JAX or torch.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rhythmic_jax.app.options import Checked, Rule, like, option, part
from rhythmic_jax.app.parts import (
    GRIDS,
    GROUND_TRUTH_FORMATS,
    IGNORED,
    READS,
    RECALL_OVER,
    SELECTS,
    FitInterrupted,
    Job,
    LearnSettings,
    Reading,
    Reported,
    ScaleJob,
    learn_config,
    recall_values,
)
from rhythmic_jax.app.query_specs import EvaluateJob, FrontierJob, QueryJob
from rhythmic_jax.errors import InputError
from rhythmic_jax.map.config import MapConfig
from rhythmic_jax.validate import Domain, int_option, number_option

__all__ = [
    "DemoJob", "DescribeJob", "EvaluateJob", "FitInterrupted", "FitJob",
    "FrontierJob", "GRIDS", "GROUND_TRUTH_FORMATS", "InfoJob", "LearnJob",
    "QueryJob", "RECALL_OVER", "Reading", "Reported", "ScaleJob", "learn_config",
    "recall_values",
]  # fmt: skip


#: The augmented fit's settings, whose defaults ``fit --epochs``, ``--batch-size``
#: and ``--checkpoint-every`` state (read without importing JAX).
AUGMENTED = "rhythmic_jax.augment.stream.AugmentedFit"


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

    sources: tuple[str, ...] = option(
        "descriptor .npy, image folder(s), image",
        positional=True,
        nargs="+",
        path="frames",
    )
    out: str = option("map folder to write", required=True, path="writes", output="map")
    config: MapConfig = part(MapConfig)
    pca: int | None = option(
        "project descriptors to K dims (saved)", domain=int_option(1)
    )
    augment: str | None = option(
        "train over frames augmented on the fly (image sources): comma-separated "
        "names from gaussian_blur, hflip, random_crop, elastic, contrast, invert, "
        "grayscale, or 'all'"
    )
    epochs: int | None = option(
        "augmented epochs", domain=int_option(1), default_from=AUGMENTED
    )
    batch_size: int | None = option(
        "augmented frames per step", domain=int_option(1), default_from=AUGMENTED
    )
    checkpoint: str | None = option(
        "checkpoint folder of an augmented fit; a killed or interrupted fit resumes "
        "from it when the same command runs again",
        path="writes",
        output="into",
        show_default="OUT.ckpt, removed once the map is saved",
    )
    checkpoint_every: int | None = option(
        "steps between checkpoints of an augmented fit",
        domain=int_option(1),
        default_from=AUGMENTED,
    )
    fusion: float | None = option(
        "the map's share of the fused score with --codes",
        domain=number_option(0, 1, closed=True),
        show_default="the weight the --embedding learned for these codes, else 0.5",
    )
    reading: Reading = part(Reading, helps={"select": "only the images of hloc .h5 "
        "sources whose names start with PREFIX (db/; the map keeps it for brute "
        "force)"})  # fmt: skip
    positions: tuple[str, ...] | None = option(
        "per-frame positions of the sources, one CSV/.npy per source "
        "(easting,northing metres or latitude,longitude), or 'names' for "
        "@easting@northing@ file names; saved for evaluate --ground-truth",
        nargs="+",
        path="reads",
    )
    places: int | None = option(
        "group the frames into K places by k-means over --positions (the RobotCar "
        "protocol); traversals may then differ in length",
        domain=int_option(1),
    )
    embedding: str | None = option(
        "embedding folder written by 'rhythmic-jax learn' (saved in the map and "
        "applied to every query; its descriptor unless --descriptor is given)",
        path="reads",
    )
    scale: ScaleJob = part(ScaleJob, group="scale (descriptor files or shard folders)")
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
class LearnJob(Job):
    """An embedding to learn from two or more traversals and write to ``out``:
    ``rhythmic-jax learn a.npy b.npy --out route.emb`` is
    ``learn(LearnJob(("a.npy", "b.npy"), "route.emb"))``; ``config``: a
    :class:`rhythmic_jax.LearnConfig`; ``codes``: those a map's fusion weight is
    learned for (:func:`rhythmic_jax.app.fusion.learn_fusion`; None: none)."""

    sources: tuple[str, ...] = option(
        "one source per traversal (same places)",
        positional=True,
        nargs="+",
        path="frames",
    )
    out: str = option(
        "embedding folder to write", required=True, path="writes", output="map"
    )
    config: Any = part(LearnSettings, None, make=learn_config)
    codes: int | str | None = option(
        "codes a map's fusion weight is learned for on these traversals and saved "
        "with the embedding for fit --embedding",
        "int8",
        metavar="BITS|int8",
        domain=Domain(True, 1, words=("int8",)),
    )
    reading: Reading = part(Reading)

    RULES = (
        *READS,
        Rule(("head", "steps", "seed"), "acts only with {opt:method} map or infonce "
             "(the closed forms take no steps)",
             lambda j: j.config is None or j.config.method in ("map", "infonce")),
        *IGNORED,
    )  # fmt: skip


@dataclass(frozen=True)
class DescribeJob(Job):
    """The frames of ``source`` described once and written to ``out``
    (:func:`rhythmic_jax.frames.route_descriptors.describe_frames`)."""

    source: str = option(
        "image folder (frames sorted by name), or one large image with --tile",
        positional=True,
        path="frames",
    )
    out: str = option(
        "descriptor file to write (.npy, float32, one row per frame)",
        required=True,
        path="writes",
        suffix=(".npy",),
    )
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

    out: str | None = option(
        "report folder",
        path="writes",
        output="into",
        show_default="a fresh folder under "
        "the system's temporary folder; the report line names "
        "it",
    )
    quick: bool = option("a smaller route (CI)", False)
