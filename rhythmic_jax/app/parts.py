"""The parts jobs share: how frames are read, how a fit is spread, the rules
on reading, the frontier's grids and the domains of its lists.

The jobs of :mod:`rhythmic_jax.app.specs` are made of these (their fields'
options declared once here, :mod:`rhythmic_jax.app.options`). Importing this
module imports no numpy, JAX or torch.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from rhythmic_jax.app.options import Checked, Rule, option, part
from rhythmic_jax.errors import InputError
from rhythmic_jax.frames.compile_policy import CompilePolicy
from rhythmic_jax.map.config import MapConfig
from rhythmic_jax.validate import Domain, int_option, number_option, parse_bytes

__all__ = [
    "GRIDS", "GROUND_TRUTH_FORMATS", "IGNORED", "READS", "RECALL_OVER", "SELECTS",
    "FitInterrupted", "Job", "LearnSettings", "Reading", "Reported", "ScaleJob",
    "grid_text", "int_list", "learn_config", "pair_list", "recall_values",
    "size_ok",
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
         lambda j: size_ok(j.reading.input_size)),
)  # fmt: skip


def recall_values(text: str) -> tuple[int, ...] | None:
    """``"1,5,10"`` -> ``(1, 5, 10)`` sorted and unique; None for other text."""
    parts = [p.strip() for p in str(text).split(",")]
    if not parts or not all(p.isdigit() and int(p) >= 1 for p in parts):
        return None
    return tuple(sorted({int(p) for p in parts}))


def size_ok(text: str | None) -> bool:
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
        "vgg16_fc7); for a .npy without describe's record, the descriptor that made "
        "it; a map remembers its own",
        show_default="patchnorm, or an --embedding's",
    )
    input_size: str | None = option(
        "the descriptor's input in pixels, width x height, frames resized to it; "
        "maps, embeddings and described files record it, and a map takes queries "
        "described at its own",
        metavar="WxH",
        show_default="patchnorm and hog "
        "64x32 grey, efficientnet_lite0 224x112, vgg16_fc7 224x224",
    )
    weights: str | None = option(
        "weights file of vgg16_fc7 (a state dict); when querying a map, a moved "
        "copy of the file it was fitted with (its sha256 is checked)",
        path="reads",
    )
    tile: int | None = option(
        "tile a large image: size (queries of a tiled map: the map's own)",
        domain=int_option(1),
    )
    stride: int | None = option(
        "tile stride, with --tile", domain=int_option(1), show_default="size/2"
    )
    compile: CompilePolicy = part(CompilePolicy)
    select: str | None = option(None, metavar="PREFIX")


@dataclass(frozen=True)
class ScaleJob:
    """How a fit from files is spread and bounded (run by
    :mod:`rhythmic_jax.app.scale_jobs`); checked with its :class:`FitJob`."""

    processes: int = option(
        "start this many local processes for one fit (frames split by rows)",
        1,
        domain=int_option(1, 256),
    )
    coordinator: str | None = option("HOST:PORT of process 0")
    num_processes: int | None = option("K hosts", domain=int_option(1, 65536))
    process_id: int | None = option("this one's i", domain=int_option(0, 65535))
    memory: str | None = option(
        "bytes each process may use (1GiB, 800M); frames that do not fit are "
        "streamed from disk in blocks",
        domain=Domain(True, 1, 2**50, parse=parse_bytes, what="a size (1GiB, 800M)"),
    )
    stream: bool = option("stream the frames from disk always", False)
    shards: str | None = option(
        "image sources: describe them into this folder of .npy shards as they are "
        "read, then fit from the shards",
        path="writes",
        output="kept",
    )

    @property
    def asked(self) -> bool:
        """Whether a fit from files is asked for by a setting of its own
        (processes, a cluster, a memory bound or streaming)."""
        return bool(
            (self.processes or 1) != 1 or self.coordinator or self.memory or self.stream
        )


@dataclass(frozen=True)
class LearnSettings:
    """The settings of :class:`rhythmic_jax.fitting.learn.LearnConfig` that
    ``learn`` offers, with the command's defaults."""

    method: str = option(
        "invariant: closed form, pca: principal axes only, map: learned through the "
        "map, infonce: InfoNCE",
        "invariant",
        choices=("invariant", "pca", "map", "infonce"),
    )
    head: str = option(
        "the learned head of --method map or infonce: linear (k x "
        "k) or mlp (plus a residual ReLU layer)",
        "linear",
        choices=("linear", "mlp"),
    )
    k: int = option("output dimensions", 256, domain=int_option(1))
    holdout: float = option(
        "share of the route's places (its end, after a gap) never learned from, "
        "where the embedding's codes are measured against the raw descriptors'",
        0.2,
        domain=number_option(0, 0.5, closed=True),
    )
    steps: int = option("gradient steps", 300, domain=int_option(1))
    seed: int = option("PRNG seed", 0, domain=int_option(0, 2**32 - 1))


def learn_config(**settings) -> Any:
    """A :class:`rhythmic_jax.LearnConfig` (method, head, k, holdout, steps, seed)."""
    from rhythmic_jax.fitting.learn import LearnConfig

    return LearnConfig(**settings)


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
                        f"{name} {err} (in {pair!r})"
                    ) from None
        return 1

    return PairDomain(
        True,
        1,
        parse=pairs,
        what="comma-separated r:level pairs",
        ranges=tuple(ranges.items()),
    )
