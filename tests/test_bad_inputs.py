"""A catalogue of bad inputs: each ends with one line naming what was wrong.

On the command line the line reads ``rhythmic-jax CMD: error: ...``, the exit
status is 2 and nothing appears in the output folder (no map, no prediction
file, no hidden temporary folder). Cases the command line cannot reach (weights
files, in-memory arrays) go through the library and raise ``InputError``.
"""

from __future__ import annotations

import ast
import contextlib
import errno
import io
import json
import os
import pickle
import re
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from skimage.io import imsave

from rhythmic_jax import RhythmicMap
from rhythmic_jax.app.cli import main
from rhythmic_jax.errors import InputError
from rhythmic_jax.frames.features import Hog, describe, get_descriptor
from rhythmic_jax.frames.nets import VGG16, EfficientNetLite0
from rhythmic_jax.io import checkpoint
from rhythmic_jax.io.images import read_rgb
from rhythmic_jax.io.tiles import tile_image
from rhythmic_jax.solvers.resumable import RunConfig, memmap_batches
from rhythmic_jax.validate import FLOAT_LIMIT

RNG = np.random.default_rng(0)
X = RNG.normal(size=(40, 18)).astype(np.float32)
# an 18-d HOG: its map and the descriptor-file map share one compiled solver
HOG = Hog(width=16, height=8, pixels_per_cell=8, cells_per_block=1)


class Mkdir:
    """An object whose unpickling creates a folder: proof that nothing unpickled."""

    def __init__(self, path: Path):
        self.path = str(path)

    def __reduce__(self):
        return (os.mkdir, (self.path,))


@pytest.fixture(scope="module")
def maps(tmp_path_factory) -> dict[str, Path]:
    """Small fitted maps: from 18-d descriptor files, from 'hog' images, and from
    'hog' tiles of one image (16-pixel tiles every 8 pixels)."""
    root = tmp_path_factory.mktemp("maps")
    RhythmicMap().fit(X, progress=False).save(root / "npy.map")
    xh = RNG.normal(size=X.shape).astype(np.float32)
    model = RhythmicMap(descriptor="hog", descriptor_settings=HOG.settings())
    model.fit(xh, progress=False).save(root / "hog.map")
    model.reference = {"sources": [str(root / "big.png")], "tile": 16, "stride": 8}
    model.save(root / "tiled.map")
    return {
        "npy": root / "npy.map",
        "hog": root / "hog.map",
        "tiled": root / "tiled.map",
    }


# ---------------------------------------------------------------- input makers


def npy(folder: Path, name: str, value) -> str:
    np.save(folder / name, value)
    return str(folder / name)


def frames(folder: Path, n: int, size=(16, 12), pattern="img{}.png") -> str:
    folder.mkdir(parents=True, exist_ok=True)
    for i in range(n):
        pixels = RNG.integers(0, 256, (size[1], size[0], 3), dtype=np.uint8)
        imsave(folder / pattern.format(i), pixels, check_contrast=False)
    return str(folder)


def empty_folder(src: Path) -> str:
    (src / "none").mkdir()
    return str(src / "none")


def with_nan(src: Path) -> str:
    x = X.copy()
    x[3, 2] = np.nan
    return npy(src, "nan.npy", x)


def with_inf(src: Path) -> str:
    x = X.copy()
    x[5, 0] = np.inf
    return npy(src, "inf.npy", x)


def object_array(src: Path) -> str:
    arr = np.empty(1, dtype=object)
    arr[0] = Mkdir(src / "unpickled")
    np.save(src / "obj.npy", arr, allow_pickle=True)
    return str(src / "obj.npy")


def raw_pickle(src: Path) -> str:
    (src / "raw.npy").write_bytes(pickle.dumps(Mkdir(src / "unpickled")))
    return str(src / "raw.npy")


def text_file(src: Path, name: str = "text.npy") -> str:
    (src / name).write_text("0.1 0.2 0.3\n0.4 0.5 0.6\n")
    return str(src / name)


def header_only(src: Path) -> str:
    """A .npy header declaring 10 million 4096-d rows, and no data behind it."""
    header = {"descr": "<f4", "fortran_order": False, "shape": (10_000_000, 4096)}
    with open(src / "huge.npy", "wb") as f:
        np.lib.format.write_array_header_1_0(f, header)
    return str(src / "huge.npy")


def dup_frames(src: Path) -> str:
    folder = frames(src / "dup", 3)
    shutil.copy(src / "dup" / "img1.png", src / "dup" / "img01.png")
    return folder


def two_patterns(src: Path) -> str:
    frames(src / "pat", 3)
    return frames(src / "pat", 2, pattern="frame{}.png")


def mixed_sizes(src: Path) -> str:
    frames(src / "mixed", 3)
    return frames(src / "mixed", 1, size=(30, 20), pattern="img3.png")


def truncated(src: Path) -> str:
    folder = frames(src / "trunc", 3)
    png = src / "trunc" / "img1.png"
    png.write_bytes(png.read_bytes()[: png.stat().st_size // 2])
    return folder


def not_an_image(src: Path) -> str:
    folder = frames(src / "junk", 3)
    (src / "junk" / "img2.png").write_bytes(b"these bytes are no picture")
    return folder


def dangling_link(src: Path) -> str:
    """Frames img0..img3 where img2.png is a link to a file that is gone."""
    folder = frames(src / "links", 4)
    (src / "links" / "img2.png").unlink()
    (src / "links" / "img2.png").symlink_to(src / "gone.png")
    return folder


def fifo_frame(src: Path) -> str:
    """Frames where img1.png is a named pipe: no image, and reading it would hang."""
    folder = frames(src / "fifo", 3)
    (src / "fifo" / "img1.png").unlink()
    os.mkfifo(src / "fifo" / "img1.png")
    return folder


def big_image(src: Path) -> str:
    """One 40 x 32 image: 15 tiles of 16 every 8 pixels."""
    pixels = RNG.integers(0, 256, (32, 40, 3), dtype=np.uint8)
    imsave(src / "big.png", pixels, check_contrast=False)
    return str(src / "big.png")


def copy_map(src: Path, maps, damage: Callable[[Path], None] | None = None) -> str:
    path = src / "copy.map"
    shutil.copytree(maps["npy"], path)
    if damage is not None:
        damage(path)
    return str(path)


def edit_meta(path: Path, edit: Callable[[dict], None]) -> None:
    meta = json.loads((path / "map.json").read_text())
    edit(meta)
    (path / "map.json").write_text(json.dumps(meta))


def cut_json(path: Path) -> None:
    meta = path / "map.json"
    meta.write_bytes(meta.read_bytes()[:60])


def delete_data(path: Path) -> None:
    for f in (path / "arrays").rglob("*"):
        if f.is_file() and f.parent.name == "d":
            f.unlink()


# ------------------------------------------------------- the command-line cases


class Case(NamedTuple):
    id: str
    argv: Callable  # (src folder, maps, out folder) -> argv
    match: str  # regex searched in the error line


def fit(*sources: Callable[[Path], str], extra=()) -> Callable:
    def argv(src, maps, out):
        paths = [s(src) for s in sources]
        target = str(out / "route.map")
        more = [e.replace("{out}", target) for e in extra]
        return ["fit", *paths, "--out", target, "--no-progress", *more]

    return argv


def query(map_: Callable, source: Callable[[Path], str], extra=()) -> Callable:
    def argv(src, maps, out):
        pred = str(out / "pred.npy")
        args = [map_(src, maps), source(src), "--out", pred, "--no-progress"]
        return ["query", *args, *extra]

    return argv


def info(map_: Callable) -> Callable:
    return lambda src, maps, out: ["info", map_(src, maps)]


def ok(src):
    return npy(src, "ok.npy", X)


def npy_map(src, maps):
    return str(maps["npy"])


def hog_map(src, maps):
    return str(maps["hog"])


def tiled_map(src, maps):
    return str(maps["tiled"])


def evaluate(map_: Callable, source: Callable[[Path], str], extra=()) -> Callable:
    def argv(src, maps, out):
        args = [map_(src, maps), source(src), "--reference", source(src)]
        more = [rows(int(e[5:-1]))(src) if e.startswith("{rows") else e
                for e in extra]  # fmt: skip
        return ["evaluate", *args, "--no-progress", *more]

    return argv


def damaged(damage):
    return lambda src, maps: copy_map(src, maps, damage)


CLI_CASES = [
    Case("nan-features", fit(with_nan), r"nan\.npy row 3 holds NaN or inf"),
    Case("inf-features", fit(with_inf), r"inf\.npy row 5 holds NaN or inf"),
    Case(
        "rank-1",
        fit(lambda s: npy(s, "row.npy", X[0])),
        r"row\.npy must be a non-empty \(n, d\) array, got \(18,\)",
    ),
    Case(
        "rank-3",
        fit(lambda s: npy(s, "cube.npy", X.reshape(4, 10, 18))),
        r"cube\.npy must be a non-empty \(n, d\) array, got \(4, 10, 18\)",
    ),
    Case(
        "empty-array",
        fit(lambda s: npy(s, "empty.npy", np.zeros((0, 8), np.float32))),
        r"empty\.npy must be a non-empty \(n, d\) array, got \(0, 8\)",
    ),
    Case(
        "empty-folder",
        fit(empty_folder),
        r"no PNG/JPG images in traversal folder .*none",
    ),
    Case(
        "one-frame",
        fit(lambda s: npy(s, "one.npy", X[:1])),
        r"a map needs at least 2 frames, got n=1",
    ),
    Case(
        "r-1",
        fit(ok, extra=["--r", "1"]),
        r"argument --r: must be an integer >= 2, got 1 \(see rhythmic-jax fit --help\)",
    ),
    Case(
        "r-negative",
        fit(ok, extra=["--r", "-3"]),
        r"argument --r: must be an integer >= 2, got -3",
    ),
    Case(
        "r-impossible",
        fit(lambda s: npy(s, "six.npy", X[:6]), extra=["--r", "5"]),
        r"no 5 pairwise co-prime periods among \(2, 3, 4, 5, 6, 7, 8\) have a "
        r"product >= n=6",
    ),
    Case(
        "level-0",
        fit(ok, extra=["--level", "0"]),
        r"argument --level: must be an integer >= 1, got 0",
    ),
    Case(
        "level-negative",
        fit(ok, extra=["--level", "-2"]),
        r"argument --level: must be an integer >= 1, got -2",
    ),
    Case(
        "count-below-r",
        fit(ok, extra=["--r", "3", "--count", "2"]),
        r"count must be an integer >= r=3, got count=2",
    ),
    Case(
        "count-1",
        fit(ok, extra=["--count", "1"]),
        r"argument --count: must be an integer in \[2, 64\], got 1",
    ),
    Case("c-zero", fit(ok, extra=["--c", "0"]), r"argument --c: must be > 0, got 0 "),
    Case(
        "duplicate-frame-names",
        fit(dup_frames),
        r"'img01\.png' and 'img1\.png' in .*dup name the same frame",
    ),
    Case(
        "unsortable-frame-names",
        fit(two_patterns),
        r"cannot order the frames of .*pat: 'frame0\.png' and 'img0\.png' follow "
        r"different naming patterns",
    ),
    Case(
        "condition-frame-count",
        fit(lambda s: frames(s / "summer", 6), lambda s: frames(s / "winter", 5)),
        r"winter: 5 frames of 2048-d, but .*summer has 6 of 2048-d; traversals of "
        r"one route must match frame for frame",
    ),
    Case(
        "truncated-image",
        fit(truncated),
        r"cannot read image .*img1\.png: image file is truncated",
    ),
    Case(
        "unreadable-image",
        fit(not_an_image),
        r"cannot read image .*img2\.png: no image reader recognises its contents$",
    ),
    Case(
        "mixed-image-sizes",
        fit(mixed_sizes),
        r"frame .*img3\.png is 30x20 but img0\.png is 16x12",
    ),
    Case(
        "features-exceed-memory",
        fit(header_only),
        r"a full-batch fit of 10000000 frames x 4096 features x \d+ templates needs "
        r"about [\d,]+ bytes .* are available; stream the frames instead: .*"
        r"memmap_batches",
    ),
    Case(
        "augment-unknown-name",
        fit(lambda s: frames(s / "aug", 4), extra=["--augment", "hflip,sepia"]),
        r"unknown augmentation 'sepia'; known: gaussian_blur, hflip, ",
    ),
    Case(
        "augment-batch-size-0",
        fit(
            lambda s: frames(s / "aug", 4),
            extra=["--augment", "all", "--batch-size", "0"],
        ),
        r"argument --batch-size: must be an integer >= 1, got 0",
    ),
    Case(
        "augment-checkpoint-is-a-file",
        fit(
            lambda s: frames(s / "aug", 4),
            extra=["--augment", "all", "--checkpoint", __file__],
        ),
        r"--checkpoint .*test_bad_inputs\.py: a file, not a folder",
    ),
    Case(
        "augment-descriptor-files",
        fit(ok, extra=["--augment", "all"]),
        r"--augment needs image sources \(folders or --tile\), not \.npy",
    ),
    Case(
        "unknown-descriptor",
        fit(lambda s: frames(s / "f", 3), extra=["--descriptor", "sift"]),
        r"unknown descriptor 'sift'; known: \['efficientnet_lite0', 'hog', "
        r"'patchnorm', 'vgg16_fc7'\]",
    ),
    Case(
        "vgg16-without-weights",
        fit(lambda s: frames(s / "f", 3), extra=["--descriptor", "vgg16_fc7"]),
        r"descriptor vgg16_fc7 needs weights \(a state-dict file: --weights PATH\)$",
    ),
    Case(
        "descriptor-option-on-npy",
        fit(ok, extra=["--descriptor", "hog"]),
        r"ok\.npy: \d+-d rows, but hog at 64x32 gives 756-d; --descriptor names "
        r"what described the file",
    ),
    Case(
        "text-named-npy",
        fit(text_file),
        r"text\.npy is not a valid \.npy file: .*magic string",
    ),
    Case(
        "pickled-object-array",
        fit(object_array),
        r"obj\.npy contains Python objects; refusing to unpickle",
    ),
    Case(
        "raw-pickle-npy",
        fit(raw_pickle),
        r"raw\.npy contains Python objects; refusing to unpickle",
    ),
    Case(
        "tile-on-text-file",
        fit(lambda s: text_file(s, "notes.txt"), extra=["--tile", "8"]),
        r"cannot read image .*notes\.txt: no image reader recognises its contents",
    ),
    Case(
        "tile-on-npy",
        fit(ok, extra=["--tile", "8"]),
        r"ok\.npy: --tile cuts one large image, but this is a descriptor file",
    ),
    Case(
        "tile-on-folder",
        fit(lambda s: frames(s / "f", 3), extra=["--tile", "8"]),
        r"f: --tile cuts one large image, but this is a folder of frames",
    ),
    Case(
        "tile-zero",
        fit(lambda s: text_file(s, "big.png"), extra=["--tile", "0"]),
        r"argument --tile: must be an integer >= 1, got 0",
    ),
    Case(
        "not-a-source",
        fit(lambda s: text_file(s, "notes.txt")),
        r"notes\.txt: not a \.npy descriptor file or an image folder \(to tile one "
        r"large image, give --tile SIZE\)",
    ),
    Case(
        "mixed-source-kinds",
        fit(ok, lambda s: frames(s / "f", 3)),
        r"mixed source kinds \['folder', 'npy'\]; give one kind at a time",
    ),
    Case(
        "missing-source",
        fit(lambda s: str(s / "absent.npy")),
        r"absent\.npy: no such file or folder",
    ),
    Case(
        "out-is-a-file",
        lambda src, maps, out: [
            "fit",
            ok(src),
            "--out",
            text_file(src, "taken.txt"),
            "--no-progress",
        ],
        r"taken\.txt: exists and is not a map folder; refusing to replace it",
    ),
    Case(
        "out-under-a-file",
        lambda src, maps, out: [
            "fit",
            ok(src),
            "--out",
            str(Path(ok(src)) / "route.map"),
            "--no-progress",
        ],
        r"route\.map: .*ok\.npy is a file, not a folder",
    ),
    Case(
        "query-wrong-dimension",
        query(npy_map, lambda s: npy(s, "q.npy", X[:5, :4])),
        r"q\.npy: 4-d features but the map was built for 18-d",
    ),
    Case(
        "query-nan",
        query(npy_map, with_nan),
        r"nan\.npy row 3 holds NaN or inf",
    ),
    Case(
        "query-images-on-npy-map",
        query(npy_map, lambda s: frames(s / "f", 3)),
        r"f: the map was fitted on descriptor files that name no descriptor; give "
        r"queries as \.npy",
    ),
    Case(
        "query-other-descriptor",
        query(
            hog_map, lambda s: frames(s / "f", 3), extra=["--descriptor", "patchnorm"]
        ),
        r"the map was built with descriptor 'hog', not 'patchnorm'",
    ),
    Case(
        "query-hog-map-with-8-d-npy",
        query(hog_map, lambda s: npy(s, "q8.npy", X[:, :8])),
        r"q8\.npy: 8-d features but the map was built for 18-d",
    ),
    Case(
        "query-out-folder-missing",
        lambda src, maps, out: [
            "query",
            npy_map(src, maps),
            ok(src),
            "--out",
            str(out / "sub" / "pred.npy"),
        ],
        r"--out .*pred\.npy: folder .*sub not found",
    ),
    Case(
        "map-missing",
        info(lambda src, maps: str(src / "absent.map")),
        r"absent\.map: no such map folder",
    ),
    Case(
        "map-is-a-file",
        info(lambda src, maps: ok(src)),
        r"ok\.npy: not a map folder \(it is a file\)",
    ),
    Case(
        "map-arrays-deleted",
        info(damaged(lambda p: shutil.rmtree(p / "arrays"))),
        r"copy\.map: arrays are missing or corrupt \(Checkpoint at .* not found",
    ),
    Case(
        "map-data-files-deleted",
        query(damaged(delete_data), ok),
        r"copy\.map: arrays are missing or corrupt \(NOT_FOUND: .*\)$",
    ),
    Case(
        "map-json-cut",
        info(damaged(cut_json)),
        r"copy\.map/map\.json: corrupt metadata \(",
    ),
    Case(
        "map-json-missing",
        info(damaged(lambda p: (p / "map.json").unlink())),
        r"copy\.map: not a map folder \(map\.json is missing\)",
    ),
    Case(
        "map-json-without-periods",
        info(damaged(lambda p: edit_meta(p, lambda m: m.pop("periods")))),
        r"copy\.map: corrupt map metadata \(KeyError\('periods'\)\)",
    ),
    Case(
        "map-newer-format",
        info(damaged(lambda p: edit_meta(p, lambda m: m.update(format_version=9)))),
        r"copy\.map: map format 9 is newer than this rhythmic_jax reads \(1\); "
        r"upgrade the package",
    ),
    Case(
        "map-weights-do-not-fit-periods",
        info(damaged(lambda p: edit_meta(p, lambda m: m.update(periods=[5, 6])))),
        r"copy\.map: weights of shape \(18, \d+\) do not fit periods \(5, 6\), "
        r"d=18",
    ),
]


CLI_CASES += [  # option values: each refused where it is parsed, 0 never "unset"
    Case(
        "r-not-an-integer",
        fit(ok, extra=["--r", "2.5"]),
        r"argument --r: expected an integer, got '2\.5'",
    ),
    Case("c-nan", fit(ok, extra=["--c", "nan"]), r"--c: must be a finite number"),
    Case("c-inf", fit(ok, extra=["--c", "inf"]), r"--c: must be a finite number"),
    Case("gap-1", fit(ok, extra=["--gap", "1"]), r"--gap: must be in \(0, 1\), got 1"),
    Case("gap-nan", fit(ok, extra=["--gap", "nan"]), r"--gap: must be a finite"),
    Case("pca-0", fit(ok, extra=["--pca", "0"]), r"--pca: must be an integer >= 1"),
    Case(
        "augment-epochs-0",
        fit(
            lambda s: frames(s / "aug", 4), extra=["--augment", "all", "--epochs", "0"]
        ),
        r"argument --epochs: must be an integer >= 1, got 0",
    ),
    Case(
        "augment-checkpoint-every-negative",
        fit(
            lambda s: frames(s / "aug", 4),
            extra=["--augment", "all", "--checkpoint-every", "-5"],
        ),
        r"argument --checkpoint-every: must be an integer >= 1, got -5",
    ),
    Case(
        "stride-0",
        fit(big_image, extra=["--tile", "16", "--stride", "0"]),
        r"argument --stride: must be an integer >= 1, got 0",
    ),
    Case(
        "stride-negative",
        fit(big_image, extra=["--tile", "16", "--stride", "-8"]),
        r"argument --stride: must be an integer >= 1, got -8",
    ),
    Case(
        "stride-without-tile",
        fit(lambda s: frames(s / "f", 3), extra=["--stride", "8"]),
        r"^--stride needs --tile",
    ),
    Case(
        "query-sequence-0",
        query(npy_map, ok, extra=["--sequence", "0"]),
        r"argument --sequence: must be an integer >= 1, got 0",
    ),
    Case(
        "query-sequence-negative",
        query(npy_map, ok, extra=["--sequence", "-3"]),
        r"argument --sequence: must be an integer >= 1, got -3",
    ),
    Case(
        "query-sequence-longer-than-queries",
        query(npy_map, ok, extra=["--sequence", "1000000"]),
        r"sequence length L=1000000 is longer than the 40 queries",
    ),
    Case(
        "query-sequence-41-of-40",
        query(npy_map, ok, extra=["--sequence", "41", "--decode", "soft"]),
        r"sequence length L=41 is longer than the 40 queries",
    ),
    Case(
        "query-threshold-nan",
        query(npy_map, ok, extra=["--threshold", "nan"]),
        r"argument --threshold: must be a finite number, got nan",
    ),
    Case(
        "query-threshold-inf",
        query(npy_map, ok, extra=["--threshold", "inf"]),
        r"argument --threshold: must be a finite number, got inf",
    ),
    Case(
        "query-threshold-minus-inf",
        query(npy_map, ok, extra=["--threshold=-inf"]),
        r"argument --threshold: must be a finite number, got -inf",
    ),
    Case(
        "query-threshold-text",
        query(npy_map, ok, extra=["--threshold", "high"]),
        r"argument --threshold: expected a number, got 'high'",
    ),
    Case(
        "query-stride-without-tile",
        query(npy_map, ok, extra=["--stride", "4"]),
        r"^--stride needs --tile",
    ),
    Case(
        "query-tiled-map-other-tile",
        query(tiled_map, big_image, extra=["--tile", "8"]),
        r"big\.png: the map was fitted on 16-pixel tiles every 8 pixels, not 8 every "
        r"4; give the same --tile and --stride, or neither to use the map's",
    ),
    Case(
        "query-tiled-map-other-stride",
        query(tiled_map, big_image, extra=["--tile", "16", "--stride", "4"]),
        r"big\.png: the map was fitted on 16-pixel tiles every 8 pixels, not 16 "
        r"every 4",
    ),
    Case(
        "query-tiled-map-stride-alone",
        query(tiled_map, big_image, extra=["--stride", "4"]),
        r"^--stride needs --tile",
    ),
    Case(
        "evaluate-sequence-0",
        evaluate(npy_map, ok, extra=["--sequence", "0"]),
        r"argument --sequence: must be an integer >= 1, got 0",
    ),
    Case(
        "evaluate-sequence-longer-than-queries",
        evaluate(npy_map, ok, extra=["--sequence", "64"]),
        r"sequence length L=64 is longer than the 40 queries",
    ),
    Case(
        "evaluate-tolerance-negative",
        evaluate(npy_map, ok, extra=["--tolerance", "-1"]),
        r"argument --tolerance: must be an integer >= 0, got -1",
    ),
]


def rows(k: int) -> Callable[[Path], str]:
    """A descriptor file of k rows (the map's 40, cut or repeated)."""
    return lambda src: npy(src, f"rows{k}.npy", np.resize(X, (k, X.shape[1])))


CLI_CASES += [  # numbers at their limits: refused where they are parsed
    Case(
        "evaluate-tolerance-past-int64",
        evaluate(npy_map, ok, extra=["--tolerance", "9223372036854775808"]),
        r"argument --tolerance: must be an integer in \[0, 2147483647\], got "
        r"9223372036854775808 \(see",
    ),
    Case(
        "evaluate-tolerance-int64-max",
        evaluate(npy_map, ok, extra=["--tolerance", "9223372036854775807"]),
        r"argument --tolerance: must be an integer in \[0, 2147483647\]",
    ),
    Case(
        "fit-count-huge",
        fit(ok, extra=["--count", "2147483648"]),
        r"argument --count: must be an integer in \[2, 64\], got 2147483648",
    ),
    Case(
        "fit-processes-huge",
        fit(ok, extra=["--processes", "100000"]),
        r"argument --processes: must be an integer in \[1, 256\], got 100000",
    ),
    Case(
        "fit-c-past-float32",
        fit(ok, extra=["--c", "1e39"]),
        r"argument --c: must be in \(0, 1e\+38\], got 1e\+39",
    ),
    Case(
        "query-threshold-past-float32",
        query(npy_map, ok, extra=["--threshold=-1e300"]),
        r"argument --threshold: must be a finite number in \[-1e\+38, 1e\+38\], got "
        r"-1e\+300",
    ),
    Case(
        "fit-memory-huge",
        fit(ok, extra=["--memory", "99999999T"]),
        r"argument --memory: must be a size \(1GiB, 800M\) in \[1, 1125899906842624\]",
    ),
    # a brute-force reference that is not the map's database (40 frames)
    Case(
        "evaluate-reference-longer",
        evaluate(npy_map, ok, extra=["--reference", "{rows50}"]),
        r"^--reference .*rows50\.npy: 50 frames, but the map was fitted on 40; give "
        r"the map's reference frames",
    ),
    Case(
        "evaluate-reference-shorter",
        evaluate(npy_map, ok, extra=["--reference", "{rows30}"]),
        r"^--reference .*rows30\.npy: 30 frames, but the map was fitted on 40",
    ),
]
CLI_CASES += [  # files that cannot be read are errors, never dropped frames
    Case(
        "dangling-link-frame",
        fit(dangling_link),
        r"cannot read image .*links/img2\.png: a dangling link \(to .*gone\.png\)",
    ),
    Case(
        "pipe-as-frame",
        fit(fifo_frame),
        r"cannot read image .*fifo/img1\.png: not a regular file",
    ),
    Case(
        "query-dangling-link-frame",
        query(hog_map, dangling_link),
        r"cannot read image .*links/img2\.png: a dangling link",
    ),
]


def learn(*sources: Callable[[Path], str], extra=()) -> Callable:
    def argv(src, maps, out):
        paths = [s(src) for s in sources]
        return ["learn", *paths, "--out", str(out / "e.emb"), "--no-progress", *extra]

    return argv


def linked(target: Callable) -> Callable:
    """A symlink ``link`` in the source folder to what ``target`` makes."""

    def make(src, maps=None):
        path = target(src, maps) if maps is not None else target(src)
        (src / "link").symlink_to(path)
        return str(src / "link")

    return make


def source_inside_map(src: Path) -> list[str]:
    """A map folder holding the descriptor file a fit reads: (file, map)."""
    shutil.copytree(ok_map(src), src / "held.map")
    return [npy(src / "held.map", "ok.npy", X), str(src / "held.map")]


def ok_map(src: Path) -> Path:
    """A map of ok.npy in the source folder (written once per case)."""
    if not (src / "own.map").exists():
        RhythmicMap().fit(X, progress=False).save(src / "own.map")
    return src / "own.map"


CLI_CASES += [  # an option that has no effect in the combination given
    Case(
        "fit-fusion-without-codes",
        fit(ok, extra=["--fusion", "0.3"]),
        r"^--fusion needs --codes",
    ),
    Case(
        "fit-epochs-without-augment",
        fit(ok, extra=["--epochs", "5"]),
        r"^--epochs needs --augment",
    ),
    Case(
        "fit-batch-size-without-augment",
        fit(ok, extra=["--batch-size", "8"]),
        r"^--batch-size needs --augment",
    ),
    Case(
        "fit-checkpoint-every-without-augment",
        fit(ok, extra=["--checkpoint-every", "9"]),
        r"^--checkpoint-every needs --augment",
    ),
    Case(
        "fit-checkpoint-in-memory",
        fit(ok, extra=["--checkpoint", "ckpt"]),
        r"^--checkpoint needs --augment or a fit from files at scale",
    ),
    Case(
        "fit-count-with-mixed-layout",
        fit(ok, extra=["--layout", "mixed:8,8", "--count", "5"]),
        r"^--count acts only with --layout periods",
    ),
    Case(
        "fit-level-with-given-periods",
        fit(ok, extra=["--layout", "periods:7,9", "--level", "2"]),
        r"^--level acts only with a --layout that leaves its sizes out",
    ),
    Case(
        "fit-r-with-given-radices",
        fit(ok, extra=["--layout", "mixed:8,8", "--r", "3"]),
        r"^--r acts only with a --layout that leaves its sizes out",
    ),
    Case(
        "fit-gap-with-lbfgs",
        fit(ok, extra=["--solver", "lbfgs", "--gap", "1e-3"]),
        r"^--gap acts only with --solver newton",
    ),
    Case(
        "fit-places-without-positions",
        fit(ok, extra=["--places", "5"]),
        r"^--places needs --positions",
    ),
    Case(
        "fit-process-id-without-coordinator",
        fit(ok, extra=["--process-id", "0"]),
        r"^--process-id needs --coordinator",
    ),
    Case(
        "fit-processes-with-coordinator",
        fit(
            ok,
            extra=[
                "--coordinator",
                "localhost:1",
                "--num-processes",
                "2",
                "--process-id",
                "0",
                "--processes",
                "2",
            ],
        ),
        r"^--processes acts only without --coordinator",
    ),
    Case(
        "fit-process-id-past-the-processes",
        fit(
            ok,
            extra=[
                "--coordinator",
                "localhost:1",
                "--num-processes",
                "2",
                "--process-id",
                "2",
            ],
        ),
        r"^--process-id must be below --num-processes",
    ),
    Case(
        "fit-codes-with-hierarchical-layout",
        fit(ok, extra=["--layout", "hierarchical", "--codes", "8"]),
        r"^--codes needs a periods layout",
    ),
    Case(
        "fit-weights-on-descriptor-files",
        fit(ok, extra=["--weights", __file__]),
        r"^--weights applies to images, or with --descriptor to \.npy files it "
        r"declares",
    ),
    Case(
        "fit-codes-at-scale",
        fit(ok, extra=["--memory", "1GiB", "--codes", "8"]),
        r"^--codes: not used by a fit from files at scale",
    ),
    Case(
        "fit-lbfgs-at-scale",
        fit(ok, extra=["--stream", "--solver", "lbfgs"]),
        r"^--solver: not used by a fit from files at scale",
    ),
    Case(
        "query-descriptor-on-descriptor-files",
        query(npy_map, ok, extra=["--descriptor", "hog"]),
        r"^the map was built with descriptor 'features', not 'hog'",
    ),
    Case(
        "evaluate-tolerance-with-ground-truth",
        evaluate(npy_map, ok, extra=["--ground-truth", "names", "--tolerance", "2"]),
        r"^--tolerance acts only without --ground-truth",
    ),
    Case(
        "evaluate-tolerance-m-without-ground-truth",
        evaluate(npy_map, ok, extra=["--tolerance-m", "10"]),
        r"^--tolerance-m needs --ground-truth",
    ),
    Case(
        "learn-steps-of-a-closed-form",
        learn(ok, ok, extra=["--steps", "5"]),
        r"^--steps acts only with --method map or infonce",
    ),
    Case(
        "learn-seed-of-pca",
        learn(ok, ok, extra=["--method", "pca", "--k", "4", "--seed", "3"]),
        r"^--seed acts only with --method map or infonce",
    ),
]
CLI_CASES += [  # a numeric option outside its domain (stated in --help)
    Case(
        "evaluate-tolerance-m-negative",
        evaluate(npy_map, ok, extra=["--ground-truth", "names", "--tolerance-m=-5"]),
        r"argument --tolerance-m: must be > 0, got -5",
    ),
    Case(
        "evaluate-tolerance-m-zero",
        evaluate(npy_map, ok, extra=["--ground-truth", "names", "--tolerance-m", "0"]),
        r"argument --tolerance-m: must be > 0, got 0",
    ),
    Case(
        "evaluate-tolerance-m-nan",
        evaluate(
            npy_map, ok, extra=["--ground-truth", "names", "--tolerance-m", "nan"]
        ),
        r"argument --tolerance-m: must be a finite number, got nan",
    ),
    Case(
        "fit-fusion-above-1",
        fit(ok, extra=["--codes", "8", "--fusion", "1.5"]),
        r"argument --fusion: must be in \[0, 1\], got 1\.5",
    ),
    Case(
        "fit-fusion-inf",
        fit(ok, extra=["--codes", "8", "--fusion", "inf"]),
        r"argument --fusion: must be a finite number, got inf",
    ),
    Case(
        "fit-codes-0",
        fit(ok, extra=["--codes", "0"]),
        r"argument --codes: must be an integer >= 1 or int8, got 0",
    ),
    Case(
        "fit-processes-0",
        fit(ok, extra=["--processes", "0"]),
        r"argument --processes: must be an integer in \[1, 256\], got 0",
    ),
    Case(
        "fit-num-processes-0",
        fit(
            ok,
            extra=["--coordinator", "h:1", "--num-processes", "0", "--process-id", "0"],
        ),
        r"argument --num-processes: must be an integer in \[1, 65536\], got 0",
    ),
    Case(
        "fit-process-id-negative",
        fit(
            ok,
            extra=["--coordinator", "h:1", "--num-processes", "2", "--process-id=-1"],
        ),
        r"argument --process-id: must be an integer in \[0, 65535\], got -1",
    ),
    Case(
        "fit-memory-not-a-size",
        fit(ok, extra=["--memory", "."]),
        r"argument --memory: expected a size \(1GiB, 800M\), got '\.'",
    ),
    Case(
        "fit-memory-0",
        fit(ok, extra=["--memory", "0"]),
        r"argument --memory: must be a size \(1GiB, 800M\) in \[1, \d+\], got 0",
    ),
    Case(
        "learn-k-0",
        learn(ok, ok, extra=["--k", "0"]),
        r"argument --k: must be an integer >= 1, got 0",
    ),
    Case(
        "learn-steps-0",
        learn(ok, ok, extra=["--method", "map", "--steps", "0"]),
        r"argument --steps: must be an integer >= 1, got 0",
    ),
    Case(
        "learn-seed-past-32-bits",
        learn(ok, ok, extra=["--method", "map", "--seed", str(2**64)]),
        r"argument --seed: must be an integer in \[0, 4294967295\], got",
    ),
]
CLI_CASES += [  # an output that is, holds or lies inside what the job reads
    Case(
        "query-out-is-the-map",
        lambda src, maps, out: [
            "query",
            str(ok_map(src)),
            ok(src),
            "--out",
            str(ok_map(src)),
        ],
        r"^--out .*own\.map: the same path as the map .*own\.map, which this "
        r"job reads; give another path",
    ),
    Case(
        "query-out-is-the-queries",
        lambda src, maps, out: ["query", npy_map(src, maps), ok(src), "--out", ok(src)],
        r"^--out .*ok\.npy: the same path as the queries .*ok\.npy",
    ),
    Case(
        "query-out-through-a-link-to-the-queries",
        lambda src, maps, out: [
            "query",
            npy_map(src, maps),
            ok(src),
            "--out",
            linked(ok)(src),
        ],
        r"^--out .*link: the same path as the queries .*ok\.npy",
    ),
    Case(
        "query-out-inside-the-map",
        lambda src, maps, out: [
            "query",
            str(ok_map(src)),
            ok(src),
            "--out",
            str(ok_map(src) / "pred.npy"),
        ],
        r"^--out .*own\.map/pred\.npy: inside the map .*own\.map",
    ),
    Case(
        "query-out-relative-to-the-queries",
        lambda src, maps, out: [
            "query",
            npy_map(src, maps),
            ok(src),
            "--out",
            str(src / "sub" / ".." / "ok.npy"),
        ],
        r"^--out .*sub/\.\./ok\.npy: the same path as the queries",
    ),
    Case(
        "fit-out-holds-the-source",
        lambda src, maps, out: [
            "fit",
            source_inside_map(src)[0],
            "--out",
            str(src / "held.map"),
            "--no-progress",
        ],
        r"^--out .*held\.map: holding the source .*held\.map/ok\.npy",
    ),
    Case(
        "fit-checkpoint-is-the-out",
        fit(ok, extra=["--stream", "--checkpoint", "{out}"]),
        r"^--out .*route\.map: the same path as --checkpoint",
    ),
    Case(
        "evaluate-plot-inside-the-map",
        lambda src, maps, out: [
            "evaluate",
            str(ok_map(src)),
            ok(src),
            "--plot",
            str(ok_map(src) / "pr.png"),
            "--no-progress",
        ],
        r"^--plot .*own\.map/pr\.png: inside the map .*own\.map",
    ),
]


def eight_bit(src: Path) -> str:
    """60 frames of 16 unscaled 8-bit features (0-253) as float32."""
    x = np.random.default_rng(0).integers(0, 254, (60, 16)).astype(np.float32)
    return npy(src, "u8.npy", x)


EIGHT_BIT_ADVICE = (
    r"^reference features: values up to 253 \(8-bit scale\?\), their mean frame "
    r"[\d.]+ from the origin; the solvers expect features of order one: divide "
    r"them by 255 or L2-normalise each row$"
)
CLI_CASES += [  # a scale no solver fits: every solver refuses it alike
    Case("fit-8-bit", fit(eight_bit), EIGHT_BIT_ADVICE),
    Case(
        "fit-8-bit-lbfgs", fit(eight_bit, extra=("--solver=lbfgs",)), EIGHT_BIT_ADVICE
    ),
    Case("fit-8-bit-stream", fit(eight_bit, extra=("--stream",)), EIGHT_BIT_ADVICE),
]


def _listing(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


@pytest.mark.parametrize("case", CLI_CASES, ids=[c.id for c in CLI_CASES])
def test_command_line_refuses(case, maps, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("RHYTHMIC_JAX_CACHE", str(tmp_path / "cache"))
    src, out = tmp_path / "in", tmp_path / "out"
    src.mkdir()
    out.mkdir()
    argv = case.argv(src, maps, out)
    before = _contents(src)
    capsys.readouterr()
    code = main(argv)
    captured = capsys.readouterr()
    lines = captured.err.splitlines()
    assert code == 2, captured
    assert len(lines) == 1, lines
    prefix = f"rhythmic-jax {argv[0]}: error: "
    assert lines[0].startswith(prefix)
    assert re.search(case.match, lines[0][len(prefix) :]), lines[0]
    assert captured.out == ""
    assert _listing(out) == []  # no map, no prediction, no hidden temporary
    assert not (src / "unpickled").exists()  # nothing was unpickled
    assert _contents(src) == before  # the inputs untouched


def _contents(folder: Path) -> dict[str, bytes | None]:
    """Every path under ``folder`` with the bytes of its regular files (links
    and pipes by name only: a pipe is never opened)."""
    return {
        str(p.relative_to(folder)): p.read_bytes()
        if p.is_file() and not p.is_symlink() and os.access(p, os.R_OK)
        else None
        for p in sorted(folder.rglob("*"))
    }


def test_the_catalogue_is_broad():
    assert len(CLI_CASES) >= 20
    assert len({c.id for c in CLI_CASES}) == len(CLI_CASES)


# --------------------------------------------------------- through a real process


SUBPROCESS_CASES = [
    "nan-features",
    "fit-8-bit",
    "query-wrong-dimension",
    "mixed-source-kinds",
    "query-sequence-0",
    "query-threshold-nan",
    "dangling-link-frame",
    "query-tiled-map-other-tile",
]


def test_real_processes_exit_2_with_one_line(maps, tmp_path):
    """The same lines from ``python -m rhythmic_jax.app.cli`` and from the installed
    ``rhythmic-jax``, run from another working directory."""
    script = shutil.which("rhythmic-jax")
    env = {**os.environ, "RHYTHMIC_JAX_CACHE": str(tmp_path / "cache")}
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    by_id = {c.id: c for c in CLI_CASES}
    runs = []
    for i, name in enumerate(SUBPROCESS_CASES):
        src, out = tmp_path / name / "in", tmp_path / name / "out"
        src.mkdir(parents=True)
        out.mkdir()
        argv = by_id[name].argv(src, maps, out)
        use_script = i > 0 and script is not None  # the installed entry point
        cmd = [script] if use_script else [sys.executable, "-m", "rhythmic_jax.app.cli"]
        proc = subprocess.Popen(
            [*cmd, *argv],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            env=env,
            cwd=elsewhere,
        )
        runs.append((name, argv, out, proc))
    for name, argv, out, proc in runs:  # started together: they share the wait
        stdout, stderr = proc.communicate(timeout=180)
        lines = stderr.decode().splitlines()
        assert proc.returncode == 2, (name, stderr)
        assert len(lines) == 1, lines
        prefix = f"rhythmic-jax {argv[0]}: error: "
        assert lines[0].startswith(prefix)
        assert re.search(by_id[name].match, lines[0][len(prefix) :]), lines[0]
        assert stdout == b"" and _listing(out) == []
    assert _listing(elsewhere) == []


def test_a_tiled_map_is_queried_with_its_own_tiling(maps, tmp_path, capsys):
    """Without --tile, or with the map's own, the same tiles as the library's."""
    big = big_image(tmp_path)
    expected = RhythmicMap.load(maps["tiled"]).predict(
        describe(tile_image(read_rgb(big), 16, 8).tiles, HOG, progress=False)
    )
    assert expected.shape == (12,)  # (32 - 16) / 8 + 1 rows x (40 - 16) / 8 + 1
    for extra in ([], ["--tile", "16"], ["--tile", "16", "--stride", "8"]):
        argv = ["query", str(maps["tiled"]), big, "--json", "--no-progress"]
        code = main([*argv, *extra])
        captured = capsys.readouterr()
        assert code == 0 and captured.err == "", captured
        assert json.loads(captured.out)["predictions"] == expected.tolist()


def test_a_frame_without_read_permission_is_named(tmp_path, capsys):
    folder = Path(frames(tmp_path / "f", 3))
    (folder / "img1.png").chmod(0)
    if os.access(folder / "img1.png", os.R_OK):
        pytest.skip("this user (root) reads files without read permission")
    code = main(["fit", str(folder), "--out", str(tmp_path / "m.map")])
    lines = capsys.readouterr().err.splitlines()
    assert code == 2 and len(lines) == 1, lines
    assert re.search(r"cannot read image .*img1\.png: permission denied$", lines[0])
    assert not (tmp_path / "m.map").exists()


# ------------------------------------------------------------------ a full disk


@pytest.fixture
def small_disk(tmp_path):
    """A 1 MiB tmpfs at ``tmp_path/disk``; skipped where mounting is not allowed."""
    disk = tmp_path / "disk"
    disk.mkdir()
    if shutil.which("mount") is None:
        pytest.skip("no mount command to make a small file system")
    cmd = ["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(disk)]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode:
        pytest.skip(f"cannot mount a small tmpfs: {proc.stderr.strip()}")
    yield disk
    subprocess.run(["umount", str(disk)], check=True)


def _fill(disk: Path, leave: int) -> None:
    """Write a filler file so that about ``leave`` bytes stay free on ``disk``."""
    free = shutil.disk_usage(disk).free
    (disk / "filler").write_bytes(b"\1" * max(0, free - leave))


def _fit(source: str, out: Path, capsys) -> tuple[int, list[str]]:
    code = main(["fit", source, "--out", str(out), "--no-progress"])
    captured = capsys.readouterr()
    return code, captured.err.splitlines()


def _same_map(path: Path, before: np.ndarray) -> None:
    """The map at ``path`` loads and predicts ``before`` on X."""
    np.testing.assert_array_equal(RhythmicMap.load(path).predict(X), before)


def test_a_map_too_large_for_the_disk_is_refused_before_the_solve(
    small_disk, maps, tmp_path, capsys, monkeypatch
):
    src = ok(tmp_path)
    code, _ = _fit(src, small_disk / "route.map", capsys)
    assert code == 0
    before = RhythmicMap.load(small_disk / "route.map").predict(X)
    _fill(small_disk, 32 * 1024)

    def solve(*args, **kwargs):
        raise AssertionError("the solve started on a disk that cannot hold the map")

    monkeypatch.setattr("rhythmic_jax.fitting.fit_map.fit", solve)  # the solve
    code, lines = _fit(src, small_disk / "route.map", capsys)
    assert code == 2 and len(lines) == 1, lines
    found = re.fullmatch(
        rf"rhythmic-jax fit: error: {re.escape(str(small_disk))}: the map needs "
        r"about ([\d,]+) bytes but only ([\d,]+) are free",
        lines[0],
    )
    assert found, lines[0]
    need, free = (int(g.replace(",", "")) for g in found.groups())
    assert need > free and abs(free - shutil.disk_usage(small_disk).free) < 8192
    assert _listing(small_disk) == ["filler", "route.map"]  # no hidden temporary
    monkeypatch.undo()
    _same_map(small_disk / "route.map", before)


@pytest.mark.filterwarnings("error::pytest.PytestUnraisableExceptionWarning")
def test_a_write_that_fills_the_disk_keeps_the_previous_map(
    small_disk, maps, tmp_path, capsys, caplog, monkeypatch
):
    """The space check passes (as if its estimate were wrong) and the real write
    runs out of space: one line, no orbax log or I/O-thread traceback, and the
    previous map loads as before."""
    src = ok(tmp_path)
    code, _ = _fit(src, small_disk / "route.map", capsys)
    assert code == 0
    before = RhythmicMap.load(small_disk / "route.map").predict(X)
    _fill(small_disk, 12 * 1024)
    monkeypatch.setattr(checkpoint, "check_space", lambda path, nbytes: None)
    code, lines = _fit(src, small_disk / "route.map", capsys)
    assert code == 2 and len(lines) == 1, lines
    assert re.fullmatch(
        rf"rhythmic-jax fit: error: {re.escape(str(small_disk))}: the disk filled up "
        r"while the map was written \([\d,]+ bytes free\); the previous map is "
        r"unchanged",
        lines[0],
    ), lines[0]
    assert not [r for r in caplog.records if r.name.startswith("absl")]
    assert _listing(small_disk) == ["filler", "route.map"]
    _same_map(small_disk / "route.map", before)


def test_a_full_disk_inside_the_writer_keeps_the_previous_map(
    maps, tmp_path, capsys, monkeypatch
):
    """Where no small file system can be mounted: the writer raises ENOSPC
    after writing the arrays, before the metadata."""
    src, out = ok(tmp_path), tmp_path / "out"
    out.mkdir()
    code, _ = _fit(src, out / "route.map", capsys)
    assert code == 0
    before = RhythmicMap.load(out / "route.map").predict(X)
    write = checkpoint._write

    def write_then_fill_up(tmp, arrays, body):
        write(tmp, arrays, body)
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(tmp / "map.json"))

    monkeypatch.setattr(checkpoint, "_write", write_then_fill_up)
    code, lines = _fit(src, out / "route.map", capsys)
    assert code == 2 and len(lines) == 1, lines
    assert re.search(
        r"out: the disk filled up while the map was written \([\d,]+ bytes free\); "
        r"the previous map is unchanged$",
        lines[0],
    ), lines[0]
    assert _listing(out) == ["route.map"]
    _same_map(out / "route.map", before)


# ---------------------------------------------------- library-only cases: weights


def _random_state(cls, drop: str | None = None, add: str | None = None, tiny=False):
    with torch.device("meta"):
        own = cls().state_dict()
    gen = torch.Generator().manual_seed(0)
    state = {
        k: torch.randn(2 if tiny else tuple(v.shape), generator=gen)
        if v.is_floating_point()
        else torch.zeros(v.shape, dtype=v.dtype)
        for k, v in own.items()
    }
    if drop:
        del state[drop]
    if add:
        state[add] = torch.randn(3, generator=gen)
    return state


def _describe_with(name: str, path: Path):
    images = RNG.integers(0, 256, (2, 32, 32, 3), dtype=np.uint8)
    return describe(images, get_descriptor(name, weights=str(path)), progress=False)


def vgg_missing_key(tmp: Path):
    path = tmp / "vgg16_missing.pth"
    torch.save(_random_state(VGG16, drop="classifier.3.weight", tiny=True), path)
    return lambda: _describe_with("vgg16_fc7", path), (
        r"vgg16_missing\.pth: keys do not fit VGG16: missing \[classifier\.3\.weight\],"
        r" unexpected none"
    )


def vgg_extra_key(tmp: Path):
    path = tmp / "vgg16_extra.pth"
    torch.save(_random_state(VGG16, add="classifier.9.weight", tiny=True), path)
    return lambda: _describe_with("vgg16_fc7", path), (
        r"vgg16_extra\.pth: keys do not fit VGG16: missing none, unexpected "
        r"\[classifier\.9\.weight\]"
    )


def lite0_missing_key(tmp: Path):
    path = tmp / "lite0.pth"
    torch.save(_random_state(EfficientNetLite0, drop="_fc.bias"), path)
    return lambda: _describe_with("efficientnet_lite0", path), (
        r"lite0\.pth: keys do not fit EfficientNet-Lite0: missing \[_fc\.bias\]"
    )


def lite0_wrong_shape(tmp: Path):
    path = tmp / "lite0_shape.pth"
    state = _random_state(EfficientNetLite0)
    state["_fc.weight"] = torch.zeros(10, 1280)
    torch.save(state, path)
    return lambda: _describe_with("efficientnet_lite0", path), (
        r"lite0_shape\.pth: 1 tensors have the wrong shape for EfficientNet-Lite0, "
        r"e\.g\. _fc\.weight \(10, 1280\) != \(1000, 1280\)"
    )


def weights_not_a_dict(tmp: Path):
    path = tmp / "list.pth"
    torch.save([torch.zeros(3)], path)
    return lambda: _describe_with("vgg16_fc7", path), (
        r"list\.pth: expected a state dict, found <class 'list'>"
    )


def weights_pickled_object(tmp: Path):
    path = tmp / "evil.pth"
    torch.save({"features.0.weight": Mkdir(tmp / "unpickled")}, path)
    return lambda: _describe_with("vgg16_fc7", path), (
        r"evil\.pth: holds Python objects beyond tensors, which are not loaded "
        r"\(weights_only\); save the plain state dict instead$"
    )


def weights_missing_file(tmp: Path):
    return lambda: get_descriptor("vgg16_fc7", weights=str(tmp / "none.pth")), (
        r"vgg16_fc7 weights file not found: .*none\.pth"
    )


# ------------------------------------------------- library-only cases: arrays, maps


def map_other_descriptor(tmp: Path, maps):
    return lambda: RhythmicMap.load(maps["hog"], descriptor="patchnorm"), (
        r"hog\.map: map built with descriptor 'hog', queries use 'patchnorm'"
    )


def map_other_settings(tmp: Path, maps):
    settings = {**HOG.settings(), "orientations": 12}
    return lambda: RhythmicMap.load(maps["hog"], descriptor_settings=settings), (
        r"hog\.map: map built with hog settings \{.*'orientations': 9.*\}, queries "
        r"use \{.*'orientations': 12.*\}"
    )


def fit_rank_3(tmp: Path, maps):
    return lambda: RhythmicMap().fit(X.reshape(5, 8, 18), progress=False), (
        r"reference features: expected a 2-D array \(frames x features\), got shape "
        r"\(5, 8, 18\)"
    )


def fit_nan(tmp: Path, maps):
    x = X.copy()
    x[[7, 9]] = np.nan
    return lambda: RhythmicMap().fit(x, progress=False), (
        r"reference features: 2 rows hold NaN or inf \(first: row 7\)"
    )


def fit_label_gap(tmp: Path, maps):
    """The pure fit numbers places itself (the estimator maps any labels)."""
    from rhythmic_jax import fit

    labels = np.r_[np.arange(20), np.arange(21, 41)]
    return lambda: fit(X, labels=labels), (
        r"labels: places must be numbered 0 \.\. 40 without gaps; 1 missing "
        r"\(first: 20\)"
    )


def predict_wrong_dimension(tmp: Path, maps):
    model = RhythmicMap.load(maps["npy"])
    return lambda: model.predict(X[:3, :5]), (
        r"queries: 5-d features but the map was built for 18-d"
    )


def memmap_object_array(tmp: Path, maps):
    path = object_array(tmp)
    return lambda: memmap_batches(path, np.arange(1), (2, 3), 4, 0), (
        r"obj\.npy: not a readable \.npy array \(.*Python objects"
    )


def run_config_zero_batch(tmp: Path, maps):
    return lambda: RunConfig(batch_size=0), (
        r"RunConfig\.batch_size must be an integer >= 1, got 0"
    )


WEIGHT_CASES = [
    vgg_missing_key,
    vgg_extra_key,
    lite0_missing_key,
    lite0_wrong_shape,
    weights_not_a_dict,
    weights_pickled_object,
    weights_missing_file,
]
LIBRARY_CASES = [
    map_other_descriptor,
    map_other_settings,
    fit_rank_3,
    fit_nan,
    fit_label_gap,
    predict_wrong_dimension,
    memmap_object_array,
    run_config_zero_batch,
]


def _assert_one_line(call, match: str) -> None:
    with pytest.raises(InputError) as err:
        call()
    message = str(err.value)
    assert "\n" not in message
    assert re.search(match, message), message


@pytest.mark.parametrize("case", WEIGHT_CASES, ids=[c.__name__ for c in WEIGHT_CASES])
def test_weights_files_are_refused(case, tmp_path):
    call, match = case(tmp_path)
    _assert_one_line(call, match)
    assert not (tmp_path / "unpickled").exists()


@pytest.mark.parametrize("case", LIBRARY_CASES, ids=[c.__name__ for c in LIBRARY_CASES])
def test_library_refuses(case, maps, tmp_path):
    call, match = case(tmp_path, maps)
    _assert_one_line(call, match)
    assert not (tmp_path / "unpickled").exists()


@pytest.mark.parametrize(
    "edit",
    [
        lambda m: m.pop("c"),
        lambda m: m.update(candidates=5),
        lambda m: m["config"].update(threshold="high"),
    ],
    ids=["without-c", "candidates-not-a-list", "threshold-not-a-number"],
)
def test_map_json_with_a_bad_field(edit, maps, tmp_path):
    path = copy_map(tmp_path, maps, lambda p: edit_meta(p, edit))
    _assert_one_line(
        lambda: RhythmicMap.load(path).predict(X[:2]), r"copy\.map: corrupt map"
    )


# ------------------------------------------------------- no pickle in load paths


def _load_calls(tree):
    """``(module alias, function, keywords, line)`` of every ``X.load(s)`` call."""
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Attribute)
            and node.func.attr in ("load", "loads", "Unpickler")
            and isinstance(node.func.value, ast.Name)
        ):
            keywords = {
                k.arg: k.value.value
                for k in node.keywords
                if isinstance(k.value, ast.Constant)
            }
            yield node.func.value.id, node.func.attr, keywords, node.lineno


def test_no_load_path_in_the_package_can_unpickle():
    """Every numpy load refuses pickles, every torch load takes weights only, and
    nothing calls pickle at all (the catalogue above feeds the payloads)."""
    package = Path(__file__).resolve().parents[1] / "rhythmic_jax"
    seen = {"np": 0, "torch": 0}
    for path in sorted(package.rglob("*.py")):
        for module, name, keywords, line in _load_calls(ast.parse(path.read_text())):
            where = f"{path.name}:{line} {module}.{name}"
            assert module not in ("pickle", "cPickle", "dill"), where
            if module in ("np", "numpy"):
                assert keywords.get("allow_pickle") is False, where
                seen["np"] += 1
            if module == "torch":
                assert keywords.get("weights_only") is True, where
                seen["torch"] += 1
    assert seen["np"] >= 3 and seen["torch"] >= 1  # the scan does find the loads


# ------------------------------------- drawn arrays: a result or one line, never both

PROPERTY = settings(
    max_examples=12,
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
DTYPES = ("float16", "float32", "float64", "int8", "uint16", "int64", "bool")
DTYPES += ("complex64",)


def drawn_arrays(shapes: list[tuple[int, ...]]):
    """Arrays of the given shapes and dtypes, any values: NaN, inf, huge, tiny."""
    return st.tuples(st.sampled_from(DTYPES), st.sampled_from(shapes)).flatmap(
        lambda ds: hnp.arrays(np.dtype(ds[0]), ds[1])
    )


def _valid(x: np.ndarray, d: int, least: int = 1) -> bool:
    """Whether ``x`` is an (n >= least, d) real array, finite as float32."""
    if x.dtype.kind not in "fiu" or x.ndim != 2 or x.shape[1] != d:
        return False
    with np.errstate(over="ignore", invalid="ignore"):
        return x.shape[0] >= least and bool(np.isfinite(x.astype(np.float32)).all())


def _main(argv: list[str]) -> tuple[int, str, list[str]]:
    """The command line in this process: (status, stdout, stderr lines)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(argv)
    return code, out.getvalue(), err.getvalue().splitlines()


def _refused(code: int, lines: list[str], command: str) -> None:
    assert code == 2, lines
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"rhythmic-jax {command}: error: "), lines


@PROPERTY
@given(
    q=drawn_arrays([(1, 18), (4, 18), (4, 18), (4, 5), (18,), (2, 2, 18), (0, 18)]),
    sequence=st.none() | st.integers(-2, 5),
    threshold=st.none() | st.floats(),
    decode=st.sampled_from([None, "soft"]),
)
def test_query_on_any_array(maps, q, sequence, threshold, decode):
    """Exit 0 with one index in [-1, n) per query exactly when every input is
    good; otherwise exit 2 with one line and no prediction file."""
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        np.save(tmp / "q.npy", q)
        argv = ["query", str(maps["npy"]), str(tmp / "q.npy"), "--no-progress"]
        argv += ["--out", str(tmp / "pred.npy")]
        argv += [] if decode is None else ["--decode", decode]
        argv += [] if sequence is None else [f"--sequence={sequence}"]
        argv += [] if threshold is None else [f"--threshold={threshold!r}"]
        code, _, lines = _main(argv)
        good = (
            _valid(q, 18)
            and (sequence is None or 1 <= sequence <= len(q))
            and (threshold is None or abs(threshold) <= FLOAT_LIMIT)
        )
        if not good:
            _refused(code, lines, "query")
            assert _listing(tmp) == ["q.npy"]
            return
        assert code == 0 and lines == [], lines
        pred = np.load(tmp / "pred.npy")
        assert pred.dtype == np.int64 and pred.shape == (len(q),)
        assert ((pred >= -1) & (pred < len(X))).all()


@PROPERTY
@given(x=drawn_arrays([(40, 18), (40, 18), (40, 18), (1, 18), (40, 0), (2, 20, 18)]))
def test_fit_on_any_array(maps, x):
    """A good array gives a map with finite templates that loads and answers;
    anything else (or a solve that cannot stay finite) exits 2 with one line."""
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        np.save(tmp / "x.npy", x)
        argv = ["fit", str(tmp / "x.npy"), "--out", str(tmp / "m.map"), "--json"]
        code, out, lines = _main([*argv, "--no-progress"])
        if code != 0 or not _valid(x, 18, least=2):
            _refused(code, lines, "fit")
            assert _listing(tmp) == ["x.npy"]
            if _valid(x, 18, least=2):  # only its scale or the solve may refuse
                scale = "the solvers expect features of order one"
                assert "non-finite templates" in lines[0] or scale in lines[0], lines
            return
        info = json.loads(out)
        assert info["n"] == 40 and np.isfinite(info["candidate_errors"]).all()
        model = RhythmicMap.load(tmp / "m.map")
        assert np.isfinite(np.asarray(model.params.w)).all()
        assert np.isfinite(np.asarray(model.params.b)).all()
        pred = model.predict(X)
        assert ((pred >= -1) & (pred < 40)).all()


# ----------------------------------------------------- names in figures, literally
MARKUP_NAMES = ["$x^2$", "$\\frac{a}{b}$", "a_b^c", "100%", "{braces}", "\\", "$",
                "$$", "$\\undefinedcommand$", "\\$5 and $6"]  # fmt: skip


@pytest.mark.parametrize("usetex", [False, True])
def test_figure_text_fed_names_is_drawn_literally(tmp_path, usetex):
    """Titles, captions and legends fed file names are drawn as written: no
    mathtext (a ``$\\frac{a}{b}$`` or an odd ``$`` would end in a parse error),
    no TeX even where the user's rcParams ask for it."""
    import matplotlib
    from matplotlib.text import Text

    from rhythmic_jax.eval.figures import new_figure, plot_evaluation, plot_matches

    image = np.zeros((6, 8, 3), np.uint8)
    rows = [{"query": image, "chosen": image, "right": None,
             "titles": (name, f"chosen: {name}", f"right: {name}")}
            for name in MARKUP_NAMES]  # fmt: skip
    curve = {"precision": [1.0, 0.5], "recall": [0.0, 1.0]}
    result = {"methods": {name: {"pr_curve": curve, "pr_auc": 0.5, "recall@100p": 0.0,
                                 "label": name, "recall@1": 0.5}
                          for name in MARKUP_NAMES[:3]},
              "ground_truth": {"source": MARKUP_NAMES[1]}}  # fmt: skip
    with matplotlib.rc_context({"text.usetex": usetex}):
        fig = plot_matches(rows, title=MARKUP_NAMES[8], path=tmp_path / "m.png")
        shown = {t.get_text() for t in fig.findobj(Text)}
        assert set(MARKUP_NAMES) <= shown and MARKUP_NAMES[8] in shown
        for text in fig.findobj(Text):
            if text.get_text() in MARKUP_NAMES:
                assert not text.get_parse_math() and not text.get_usetex()
        if not usetex:  # tick labels stay the formatters' (TeX would need LaTeX)
            plot_evaluation(result, path=tmp_path / "e.png")
            assert (tmp_path / "e.png").stat().st_size > 1000
    assert (tmp_path / "m.png").stat().st_size > 1000
    # without the literal drawing the same caption is markup, and fails to render
    bare, _ = new_figure()
    bare.text(0, 0, MARKUP_NAMES[8])
    with pytest.raises(ValueError):
        bare.savefig(io.BytesIO(), format="png")


def test_evaluate_reference_must_be_the_frames_the_map_was_fitted_on(tmp_path, capsys):
    """A map fitted on descriptor files records their digest: a --reference of
    the same count but other values is refused in one line, the same frames
    (another copy) are brute force's database."""
    ref, other, copy = (npy(tmp_path, name, v) for name, v in (
        ("ref.npy", X), ("other.npy", X[::-1]), ("copy.npy", X)))  # fmt: skip
    target = str(tmp_path / "m.map")
    assert main(["fit", ref, "--out", target, "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["evaluate", target, ref, "--reference", other, "--no-progress"]) == 2
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("rhythmic-jax evaluate: error: "
                                                   "--reference "), lines  # fmt: skip
    assert "not the frames the map was fitted on (the same count, 40" in lines[0]
    assert main(["evaluate", target, ref, "--reference", copy, "--json",
                 "--no-progress"]) == 0  # fmt: skip
    result = json.loads(capsys.readouterr().out)
    assert result["methods"]["brute force"]["recall@1"] == 1.0
