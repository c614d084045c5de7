"""Frames to descriptors with the network as the only thing a job waits for.

Reading (JPEG/PNG decoding in a small thread pool), conversion to float and the
descriptor's resize run in a background thread at most a few batches ahead of
the network (:func:`ahead`, a bounded queue); the caller's thread only runs the
network (:func:`rhythmic_jax.frames.compiled.network_runner`: compiled when the job is
large enough). Errors raised ahead (a bad image file) are raised in the caller
when their batch is reached.

Names: n frames, b batch, (H, W) frame size, d descriptor length.
"""

from __future__ import annotations

import functools
import hashlib
import itertools
import json
import queue
import threading
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.frames.compiled import AUTO, CompilePolicy, network_runner
from rhythmic_jax.progress import bar as progress_bar

if TYPE_CHECKING:  # torch loads when frames are described, not on a cache hit
    import torch

__all__ = [
    "ahead",
    "describe_chunks",
    "describe_files",
    "files_cache_path",
    "read_frames",
]

T = TypeVar("T")
_DONE = object()


class _Raised:
    def __init__(self, err: BaseException):
        self.err = err


def ahead(items: Iterable[T], depth: int = 2) -> Iterator[T]:
    """Iterate ``items`` in a background thread, at most ``depth`` items ahead.

    Yields the same items in the same order; an exception raised by ``items`` is
    raised here at its place in the order. Closing the iterator early stops the
    thread (it finishes the item it is making).
    """
    if depth < 1:
        raise InputError(f"prefetch depth must be >= 1, got {depth}")
    q: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def put(v) -> bool:
        while not stop.is_set():
            try:
                q.put(v, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def work() -> None:
        try:
            for item in items:
                if not put(item):
                    return
        except BaseException as err:  # handed to the consumer, raised there
            put(_Raised(err))
            return
        put(_DONE)

    thread = threading.Thread(target=work, name="rhythmic-prefetch", daemon=True)
    thread.start()
    try:
        while True:
            v = q.get()
            if v is _DONE:
                return
            if isinstance(v, _Raised):
                raise v.err
            yield v
    finally:
        stop.set()
        thread.join()


def read_frames(
    files: Sequence[Path],
    batch_size: int,
    workers: int = 2,
    at_least: tuple[int, int] | None = None,
) -> Iterator[np.ndarray]:
    """Decode image files in order, ``workers`` at a time: uint8 (b, H, W, 3) chunks.

    Every frame must have the first one's size (InputError naming the file).
    ``at_least`` (width, height): JPEGs are decoded at a reduced scale still at
    least this size (:func:`rhythmic_jax.io.images.read_rgb`).
    """
    from rhythmic_jax.io.images import read_rgb

    read = functools.partial(read_rgb, at_least=at_least)
    first: tuple[int, ...] | None = None
    with ThreadPoolExecutor(workers, thread_name_prefix="rhythmic-read") as pool:
        for i in range(0, len(files), batch_size):
            part = files[i : i + batch_size]
            frames = list(pool.map(read, part))
            for path, im in zip(part, frames, strict=True):
                if first is None:
                    first = im.shape
                elif im.shape != first:
                    raise InputError(
                        f"frame {path} is {im.shape[1]}x{im.shape[0]} but "
                        f"{files[0].name} is {first[1]}x{first[0]}; resize them to "
                        "one size"
                    )
            yield np.stack(frames)


def _to_batch(
    chunk: np.ndarray, shrink_to: tuple[int, int] | None = None
) -> torch.Tensor:
    """uint8 (b, H, W, 3) -> float32 (b, 3, H, W) in [0, 1] (channels-last).

    ``shrink_to`` (height, width): frames at least that large in both sides are
    first resized to it in uint8 (antialiased bilinear, half-pixel centres, as
    :func:`rhythmic_jax.frames.features.resize`, rounded to the nearest level): torch's
    uint8 kernel is several times faster than its float one, which took as long
    as reading the JPEGs for 640x320 frames going to a 224x112 network.
    """
    import torch

    t = torch.from_numpy(np.ascontiguousarray(chunk)).permute(0, 3, 1, 2)
    if shrink_to is not None:
        h, w = t.shape[-2:]
        if h >= shrink_to[0] and w >= shrink_to[1] and (h, w) != tuple(shrink_to):
            t = torch.nn.functional.interpolate(
                t, tuple(shrink_to), mode="bilinear", align_corners=False,
                antialias=True,
            )  # fmt: skip
    return t.float().div_(255.0)


def _network_size(descriptor) -> tuple[int, int] | None:
    """(height, width) a network descriptor resizes its frames to, or None for
    descriptors without a network (their own resize is left as it is)."""
    if getattr(descriptor, "prepare", None) is None:
        return None
    return int(descriptor.height), int(descriptor.width)


def describe_chunks(
    chunks: Iterable[np.ndarray],
    n: int,
    descriptor,
    policy: CompilePolicy = AUTO,
    progress: bool = False,
    keep: Callable[[int, np.ndarray], None] | None = None,
    depth: int = 2,
) -> np.ndarray:
    """Describe ``n`` frames arriving as uint8 (b, H, W, 3) chunks -> (n, d) float32.

    The chunks are made, converted and prepared (resized) in a background thread
    ``depth`` chunks ahead; this thread runs the network. ``keep(start, chunk)``,
    when given, sees every chunk (e.g. to keep the frames).
    """
    import torch

    prepare = getattr(descriptor, "prepare", None)
    size = _network_size(descriptor)

    def prepared() -> Iterator[tuple[np.ndarray, torch.Tensor]]:
        with torch.inference_mode():
            for chunk in chunks:
                batch = _to_batch(chunk, size)
                yield chunk, prepare(batch) if prepare is not None else batch

    out = np.zeros((n, descriptor.dim), np.float32)
    bar = progress_bar(total=n, show=progress, desc=descriptor.name, unit="frame")
    start = 0
    # the network loads (the eager one builds its module) while the first
    # chunks are read
    with ThreadPoolExecutor(1, thread_name_prefix="rhythmic-load") as pool:
        loading = pool.submit(network_runner, descriptor, n, policy)
        frames = ahead(prepared(), depth)
        try:
            first = next(frames, None)
        finally:
            run = loading.result()
    rest = frames if first is None else itertools.chain([first], frames)
    with torch.inference_mode(), bar:
        for chunk, x in rest:
            if start + len(chunk) > n:
                raise InputError(f"more than the {n} frames announced")
            out[start : start + len(chunk)] = run(x).numpy()
            if keep is not None:
                keep(start, chunk)
            start += len(chunk)
            bar.update(len(chunk))
    if start != n:
        raise InputError(f"{start} frames described, {n} announced")
    return out


def files_cache_path(
    files: Sequence[Path], descriptor, key: str, cache_dir=None
) -> Path:
    """``<cache>/<key>-<name>-<hash>.npy``: the hash covers the descriptor's name
    and settings and the files' names and bytes (in order)."""
    from rhythmic_jax.frames.cache_files import cache_key_check, default_cache_dir

    cache_key_check(key)
    h = hashlib.sha256()
    ident = [descriptor.name, descriptor.settings()]
    if _network_size(descriptor) is not None:
        ident.append("shrunk in uint8")  # values differ from the float resize's
        ident.append("JPEG decoded at a reduced scale")  # and from the full decode's
    h.update(json.dumps(ident, sort_keys=True, default=str).encode())
    from rhythmic_jax.io.reader import memory_budget, read_bytes

    limit = memory_budget()
    for f in files:
        data = read_bytes(f, limit)  # a regular file, of at most the budget
        h.update(f"{Path(f).name}|{len(data)}|".encode("utf-8", "surrogateescape"))
        h.update(data)
    folder = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    return folder / f"{key}-{descriptor.name}-files-{h.hexdigest()[:16]}.npy"


def describe_files(
    files: Sequence[Path],
    descriptor,
    key: str,
    keep_images: bool = False,
    progress: bool = False,
    policy: CompilePolicy = AUTO,
    batch_size: int = 64,
    cache_dir=None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Descriptors (n, d) of image files in order, memoised in the cache folder.

    Reading runs ahead of the network (:func:`describe_chunks`). A cache hit reads
    no image unless ``keep_images``. Returns ``(x, images)``, ``images`` uint8
    (n, H, W, 3) when ``keep_images`` else None. For a network descriptor,
    JPEGs are decoded at the smallest reduced scale still at least the
    network's input (:func:`read_frames`); kept images are decoded in full.
    """
    from rhythmic_jax.frames.cache_files import load_cached, save_cached

    files = [Path(f) for f in files]
    path = files_cache_path(files, descriptor, key, cache_dir)
    x = load_cached(path, (len(files), None))  # the name digests the settings
    if x is not None:
        if not keep_images:
            return x, None
        chunks = read_frames(files, batch_size)
        return x, np.concatenate(list(ahead(chunks))) if files else None
    store: list[np.ndarray] = []

    def keep(start: int, chunk: np.ndarray) -> None:
        if not store:
            store.append(np.empty((len(files), *chunk.shape[1:]), np.uint8))
        store[0][start : start + len(chunk)] = chunk

    size = _network_size(descriptor)
    at_least = None if keep_images or size is None else (size[1], size[0])
    chunks = read_frames(files, batch_size, at_least=at_least)
    x = describe_chunks(
        chunks, len(files), descriptor, policy, progress,
        keep if keep_images else None,
    )  # fmt: skip
    save_cached(path, x)
    return x, store[0] if store else None
