"""The fit job at scale: K processes, a memory bound, shards written from images.

``rhythmic-jax fit`` comes here (:func:`fit_scaled`) when the sources are
descriptor files or shard folders and any of ``--processes``,
``--coordinator``, ``--memory``, ``--stream`` or ``--shards`` is given (the
job's :class:`rhythmic_jax.app.specs.ScaleJob`); the fit itself is
:func:`rhythmic_jax.fitting.scale_fit.fit_map_files`.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
from dataclasses import replace
from pathlib import Path

from rhythmic_jax.app.specs import Reported
from rhythmic_jax.errors import InputError
from rhythmic_jax.io.outputs import staged_folder
from rhythmic_jax.io.reader import read_json

__all__ = ["MANIFEST", "fit_scaled", "wants_scale"]

MANIFEST = "shards.json"  # written last into a --shards folder: it is complete
log = logging.getLogger(__name__)


def wants_scale(job) -> bool:
    """Whether ``job`` (a :class:`rhythmic_jax.app.specs.FitJob`) fits from files
    here."""
    from rhythmic_jax.io.frame_files import is_frame_source

    scale = job.scale
    files = all(is_frame_source(s) for s in job.sources)
    wanted = scale.asked
    dirs = any(Path(s).is_dir() for s in job.sources)
    if scale.shards is not None or (files and (wanted or dirs)):
        if job.augment or job.pca is not None:
            raise InputError(
                "{opt:augment} and {opt:pca} need an in-memory fit of one process"
            )
        _check_in_memory_only(job)
        return True
    if wanted:
        raise InputError(
            "{opt:processes}, {opt:coordinator}, {opt:memory} and {opt:stream} need "
            "descriptor "
            "files (.npy) or shard folders; describe images with {opt:shards} DIR"
        )
    return False


def _check_in_memory_only(job) -> None:
    """Refuse the settings a fit from files at scale would leave unused."""
    unused = [
        name
        for name, used in (
            ("codes", job.config.codes is not None),
            ("embedding", job.embedding is not None),
            ("positions", job.positions is not None),
            ("solver", job.config.solver != "newton"),
        )
        if used
    ]
    if unused:
        opts = ", ".join(f"{{opt:{name}}}" for name in unused)
        raise InputError(
            f"{opts}: not used by a fit from files at scale (descriptor files with "
            "{opt:processes}, {opt:coordinator}, {opt:memory}, {opt:stream}, shard "
            "folders or {opt:shards}); fit in memory without them"
        )


def _describe_to_shards(job, progress: bool) -> list[str]:
    """Describe image folders into ``--shards`` (one shard folder per source)."""
    from rhythmic_jax.frames.describe_shards import describe_to_shards
    from rhythmic_jax.io.frame_files import is_frame_source

    root = Path(job.scale.shards).expanduser().absolute()
    if any(is_frame_source(s) for s in job.sources):
        raise InputError("{opt:shards} describes image folders; these are descriptors")
    if job.reading.tile is not None:
        raise InputError("{opt:shards} takes image folders, not {opt:tile}")
    from rhythmic_jax.frames.sources import parse_input_size, size_settings

    name = job.reading.descriptor or "patchnorm"
    settings = size_settings(parse_input_size(job.reading.input_size))
    if job.reading.weights is not None:
        settings["weights"] = str(Path(job.reading.weights).expanduser().absolute())
    for src in job.sources:
        if not Path(src).is_dir():
            raise InputError(f"{src}: {{opt:shards}} needs image folders")
    names = [f"{i:02d}-{Path(src).name}" for i, src in enumerate(job.sources)]
    manifest = _manifest(job.sources, names, name, settings)
    if root.exists() or root.is_symlink():
        _check_reusable(root, manifest)
        log.info("%s: the shards of these images are described already", root)
        return [str(root / folder) for folder in names]
    # staged whole: a failed or killed run leaves no folder that blocks the next
    with staged_folder(root) as staged:
        for src, folder in zip(job.sources, names, strict=True):
            describe_to_shards(src, staged / folder, name, settings, progress=progress)
        (staged / MANIFEST).write_text(json.dumps(manifest, indent=2))
    return [str(root / folder) for folder in names]


def _listing(folder: str) -> str:
    """The sha256 of a folder's entries: names (as the OS gives them), sizes
    and modification times, so changed images are not taken for described."""
    digest = hashlib.sha256()
    with os.scandir(os.fsencode(Path(folder).expanduser().absolute())) as entries:
        for entry in sorted(entries, key=lambda e: e.name):
            with contextlib.suppress(OSError):
                st = entry.stat()
                line = b"%s\0%d\0%d\n" % (entry.name, st.st_size, st.st_mtime_ns)
                digest.update(line)
    return digest.hexdigest()


def _manifest(sources, names, descriptor: str, settings: dict) -> dict:
    """What a ``--shards`` folder holds: the descriptor and each source."""
    return json.loads(json.dumps({
        "written_by": "rhythmic-jax fit --shards",
        "descriptor": descriptor,
        "settings": settings,
        "sources": [
            {"path": os.fsdecode(Path(src).expanduser().absolute()), "folder": folder,
             "listing": _listing(src)}
            for src, folder in zip(sources, names, strict=True)
        ],
    }))  # fmt: skip


def _check_reusable(root: Path, manifest: dict) -> None:
    """Refuse (one line) an existing ``--shards`` folder that does not hold the
    shards ``manifest`` describes: not written by this command (or unfinished),
    or written from other images or with another descriptor."""
    try:
        got = read_json(root / MANIFEST, "shards manifest")
    except (OSError, InputError):
        raise InputError(
            f"{{opt:shards}} {root}: exists and holds no shards that a finished "
            "fit wrote there; give a new folder"
        ) from None
    if got != manifest:
        raise InputError(
            f"{{opt:shards}} {root}: holds the shards of other images or of another "
            "descriptor; give a new folder (or remove it)"
        )


def _child_argv(argv: list[str], sources: list[str], shard_sources) -> list[str]:
    """``argv`` without ``--processes`` (and with the shard folders in place of
    the image sources once they are described)."""
    out, skip, srcs = [], False, list(sources)
    for a in argv:
        if skip:
            skip = False
        elif a in ("--processes", "--shards"):
            skip = True
        elif a.startswith(("--processes=", "--shards=")):
            continue
        elif shard_sources is not None and a in srcs:
            srcs.remove(a)
        else:
            out.append(a)
    if shard_sources is None:
        return out
    at = out.index("fit") + 1
    return out[:at] + list(shard_sources) + out[at:]


def fit_scaled(job, argv: list[str], progress: bool = True):
    """Run the fit; returns ``(map, run)`` on the process that saved it, and
    ``(None, None)`` on the others (and in the launcher of local processes)."""
    import numpy as np

    from rhythmic_jax.fitting.scale_fit import fit_map_files, parse_bytes
    from rhythmic_jax.solvers import distributed

    scale = job.scale
    memory = parse_bytes(scale.memory) if scale.memory is not None else None
    sources = list(job.sources)
    shard_sources = None
    if scale.shards is not None:
        sources = shard_sources = _describe_to_shards(job, progress)
    if scale.coordinator is None and scale.processes > 1:
        child = _child_argv(argv, list(job.sources), shard_sources)
        status = distributed.launch_local(child, scale.processes)
        if status != 0:  # process 0 said why on the terminal
            raise Reported(status)
        return None, None
    if scale.coordinator is not None:  # with both (the job's rules)
        cluster = distributed.Cluster(
            scale.coordinator, scale.num_processes, scale.process_id
        )
        distributed.initialize(cluster)
    import jax

    from rhythmic_jax.decoding.held import HeldMap
    from rhythmic_jax.io.frame_files import shard_descriptor
    from rhythmic_jax.map import map_file

    name, settings = shard_descriptor(sources[0])
    declared = None
    if name == "features" and all(str(s).lower().endswith(".npy") for s in sources):
        from rhythmic_jax.frames.sources import files_descriptor, parse_input_size

        read = job.reading  # describe's records, or --descriptor declaring them
        name, settings, declared = files_descriptor(
            [Path(s) for s in sources], read.descriptor, read.weights,
            parse_input_size(read.input_size),
        )  # fmt: skip
        from rhythmic_jax.io.descriptor_files import descriptor_shape

        d = descriptor_shape(sources[0])[-1]
        if declared is not None and declared.dim != d:
            raise InputError(
                f"{sources[0]}: {d}-d rows, but {name} gives {declared.dim}-d; "
                "{opt:descriptor} names what described the file"
            )
    config = replace(job.config, descriptor=name, descriptor_settings=settings)
    ckpt = job.checkpoint_folder
    fitted, run = fit_map_files(
        config, sources, memory=memory, stream=scale.stream, progress=progress,
        checkpoint=ckpt,
    )  # fmt: skip
    if name == "features":
        settings = {"dim": fitted.d}

    fitted = replace(
        fitted, config=replace(fitted.config, descriptor_settings=settings),
        reference=map_file.reference(sources, tile=None, stride=None),
    )  # fmt: skip
    if jax.process_index() == 0:
        map_file.save(job.out, fitted)
    distributed.allreduce(np.zeros(1))  # every process waits for the saved map
    (ckpt / f"stream-{jax.process_index()}-of-{jax.process_count()}.npz").unlink(
        missing_ok=True
    )
    with contextlib.suppress(OSError):
        ckpt.rmdir()  # once every process has removed its file
    if jax.process_index() != 0:
        return None, None
    return HeldMap(fitted), run
