"""Where the reference frames were taken, and the places they group into.

* **Positions** (:func:`read_positions`): a CSV with a header naming
  ``easting``/``northing`` (or ``x``/``y``) in metres, or ``latitude``/
  ``longitude`` (``lat``/``lon``) in degrees, converted to metres; a CSV of two
  unnamed columns or an ``(n, 2)`` ``.npy`` holds easting, northing in metres.
* **File names** ``@easting@northing@...`` as the Pittsburgh and GSV downloaders
  write them (:func:`positions_from_names`).
* **Places** (:func:`gps_places`): the paper's RobotCar protocol groups GPS
  positions into places with k-means on normalised coordinates;
  :func:`frame_places` gives a fit its frames' positions and places.

A fit keeps the positions in the map (``reference_positions``), so that
:func:`rhythmic_jax.eval.ground_truth_files.load_ground_truth` finds the right
places of queries with positions of their own.
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from rhythmic_jax.errors import InputError
from rhythmic_jax.io.reader import load_npy, memory_budget, npy_header, read_text
from rhythmic_jax.validate import check_int

__all__ = [
    "checked_positions",
    "frame_places",
    "gps_places",
    "in_metres",
    "latlon_to_metres",
    "positions_from_names",
    "positions_of_sources",
    "read_positions",
]

EARTH_RADIUS_M = 6_371_008.8  # mean radius (IUGG)


def latlon_to_metres(latlon, origin=None) -> np.ndarray:
    """(n, 2) latitude, longitude in degrees -> (n, 2) easting, northing in metres.

    A local equirectangular projection about ``origin`` (default: the mean):
    ``east = R cos(lat0) dlon``, ``north = R dlat`` (R = 6,371,008.8 m); within
    a city it agrees with great-circle distances to well under 0.1 %.
    """
    ll = np.radians(np.asarray(latlon, np.float64))
    lat0, lon0 = ll.mean(0) if origin is None else np.radians(origin)
    east = EARTH_RADIUS_M * np.cos(lat0) * (ll[:, 1] - lon0)
    north = EARTH_RADIUS_M * (ll[:, 0] - lat0)
    return np.stack([east, north], axis=1)


_METRES = (("easting", "northing"), ("x", "y"), ("east", "north"))
_DEGREES = (("latitude", "longitude"), ("lat", "lon"), ("lat", "lng"))


def _plain_npy(path: Path) -> np.ndarray:
    """A numeric ``.npy``; one holding pickled objects is refused unread (nothing
    is unpickled), as is a file that is not a ``.npy``."""
    if npy_header(path).dtype.hasobject:
        raise InputError(
            f"{path}: holds pickled objects, not numbers; refusing to unpickle "
            "it (save the positions as a numeric (n, 2) array or a CSV)"
        )
    return load_npy(path)


def read_positions(path: str | Path) -> tuple[np.ndarray, str]:
    """Per-frame positions of a file: ``(n, 2)`` and their unit.

    ``"metres"``: (easting, northing); ``"degrees"``: (latitude, longitude), to
    be projected with :func:`in_metres` together with the files they meet.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: positions file not found")
    if path.suffix.lower() == ".npy":
        return checked_positions(_plain_npy(path), path), "metres"
    # as a spreadsheet saves it too: a byte-order mark, CRLF ends, blank lines
    text = read_text(path, limit=memory_budget() // 8, encoding="utf-8-sig")
    rows = list(csv.reader(text.splitlines()))
    rows = [r for r in rows if r and any(c.strip() for c in r)]
    if not rows:
        raise InputError(f"{path}: no positions")
    head = [c.strip().lower() for c in rows[0]]
    try:
        [float(c) for c in head]
    except ValueError:
        pass
    else:
        if len(head) != 2:
            raise InputError(f"{path}: {len(head)} unnamed columns; name them")
        return checked_positions(_floats(rows, (0, 1), path), path), "metres"
    named = [(m, "metres") for m in _METRES] + [(d, "degrees") for d in _DEGREES]
    for (a, b), unit in named:
        if a in head and b in head:
            xy = _floats(rows[1:], (head.index(a), head.index(b)), path)
            return checked_positions(xy, path), unit
    raise InputError(
        f"{path}: no easting,northing / x,y / latitude,longitude columns in {head}"
    )


def in_metres(*positions: tuple[np.ndarray, str]) -> list[np.ndarray]:
    """Positions ``(array, unit)`` of one area in metres, degrees projected
    about the mean of them all (:func:`latlon_to_metres`); units must agree."""
    units = {unit for _, unit in positions}
    if len(units) > 1:
        raise InputError("positions mix metres and latitude/longitude; use one")
    if units != {"degrees"}:
        return [np.asarray(a, np.float64) for a, _ in positions]
    origin = np.concatenate([a for a, _ in positions]).mean(0)
    return [latlon_to_metres(a, origin) for a, _ in positions]


def _floats(rows, cols: tuple[int, int], path: Path) -> np.ndarray:
    try:
        return np.array([[float(r[c]) for c in cols] for r in rows], np.float64)
    except (ValueError, IndexError):
        raise InputError(f"{path}: a row without two numbers in its columns") from None


def checked_positions(xy, where) -> np.ndarray:
    """Positions ``xy`` as (n, 2) float64, n >= 1, all finite, else one line
    naming ``where`` they came from."""
    xy = np.asarray(xy, np.float64)
    if xy.ndim != 2 or xy.shape[1] != 2 or not len(xy):
        raise InputError(f"{where}: positions must be (n, 2), got {xy.shape}")
    if not np.isfinite(xy).all():
        raise InputError(f"{where}: positions hold NaN or infinite values")
    return xy


def positions_from_names(paths: Sequence[str | Path]) -> np.ndarray:
    """``@easting@northing@...`` file names (Pittsburgh, GSV) -> (n, 2) metres."""
    out = []
    for p in paths:
        parts = Path(p).name.split("@")
        try:
            out.append((float(parts[1]), float(parts[2])))
        except (IndexError, ValueError):
            raise InputError(f"{p}: no @easting@northing@ in the file name") from None
    return checked_positions(np.array(out), paths[0] if paths else "file names")


def positions_of_sources(specs: Sequence[str], sources: Sequence[str]):
    """Reference positions ``(array, unit)`` for the map's sources: one file per
    source, or ``["names"]`` to read ``@easting@northing@`` from its frames' names
    (an image folder's, or those a described ``.npy`` file's record names)."""
    from rhythmic_jax.io.descriptor_files import frame_names

    if list(specs) != ["names"]:
        if len(specs) != len(sources):
            raise InputError(
                f"{{opt:positions}}: {len(specs)} files for {len(sources)} sources; "
                "give one per source, or 'names'"
            )
        read = [read_positions(s) for s in specs]
        if len({unit for _, unit in read}) > 1:
            raise InputError(
                "{opt:positions} mix metres and latitude/longitude; use one"
            )
        return np.concatenate([a for a, _ in read]), read[0][1]
    names = [f for s in sources for f in frame_names(s, "reference")]
    return positions_from_names(names), "metres"


def gps_places(coords: np.ndarray, k: int, seed: int = 0) -> np.ndarray:
    """Group GPS positions into ``k`` places (the paper's RobotCar protocol).

    k-means (scikit-learn, ``n_init=10``) on coordinates normalised to zero mean
    and unit variance per axis; labels are renumbered in route order, so place 0
    holds the first frame and a new place number appears the first time the
    sequence enters that place.

    Args:
      coords: float (n, 2) positions along the sequence (e.g. northing, easting).
      k: number of places, ``1 <= k <= n``.
      seed: k-means random state.

    Returns:
      int64 (n,) place label per frame.
    """
    coords = np.asarray(coords, dtype=np.float64)
    if coords.ndim != 2 or coords.shape[1] != 2 or len(coords) == 0:
        raise InputError(f"coords must have shape (n, 2), got {coords.shape}")
    bad = np.flatnonzero(~np.isfinite(coords).all(axis=1))
    if bad.size:
        raise InputError(f"coords row {bad[0]} is not finite: {coords[bad[0]]}")
    check_int(
        k,
        "k",
        1,
        len(coords),
        msg=f"k must be an integer in [1, {len(coords)}], got {k}",
    )
    std = coords.std(axis=0)
    z = (coords - coords.mean(axis=0)) / np.where(std > 0, std, 1.0)
    from sklearn.cluster import KMeans  # here: importing it costs a query 0.6 s

    kmeans = KMeans(n_clusters=int(k), n_init=10, random_state=seed)
    with threadpool_limits(limits=1):  # small 2-D problem: threads only add waiting
        labels = kmeans.fit_predict(z)
    _, first = np.unique(labels, return_index=True)
    rank = np.empty(int(labels.max()) + 1, np.int64)
    rank[labels[np.sort(first)]] = np.arange(len(first))
    return rank[labels]


def frame_places(
    located: tuple[np.ndarray, str], places: int | None
) -> tuple[np.ndarray | None, dict[str, np.ndarray]]:
    """The positions a fit's map keeps for its reference frames, and their places.

    Args:
      located: the frames' positions ``(array (frames, 2), unit)``, as
        :func:`positions_of_sources` reads them (before the frames are read;
        the fit checks that there is one a frame).
      places: group the frames into this many places by k-means over their
        positions in metres (:func:`gps_places`); None keeps the sources' own.

    Returns:
      ``(labels, extra)``: the (frames,) int64 place of each frame, or None
      without ``places``; and the arrays the map keeps, ``reference_positions``
      (frames, 2) float64 and ``reference_positions_degrees`` (1 where they are
      latitude, longitude), plus ``reference_labels`` with ``places``.
    """
    xy, unit = located
    extra = {
        "reference_positions": xy,
        "reference_positions_degrees": np.asarray(int(unit == "degrees")),
    }
    if places is None:
        return None, extra
    metres = in_metres(located)[0]
    labels = gps_places(metres, places)
    return labels, {**extra, "reference_labels": labels}
