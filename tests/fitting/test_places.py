"""Frames' positions read from the files users have (metres, degrees, file
names) and grouped into places by k-means (the RobotCar protocol), checked
against scikit-learn's own k-means and great-circle distances."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.cluster import KMeans
from sklearn.metrics import adjusted_rand_score
from sklearn.preprocessing import StandardScaler
from threadpoolctl import threadpool_limits

from rhythmic_jax.errors import InputError
from rhythmic_jax.fitting.places import (
    frame_places,
    gps_places,
    latlon_to_metres,
    positions_from_names,
    positions_of_sources,
    read_positions,
)

RNG = np.random.default_rng(0)


def test_positions_in_metres_and_degrees(tmp_path):
    ref = np.c_[np.arange(40) * 10.0, np.zeros(40)] + 500_000
    (tmp_path / "ref.csv").write_text(
        "timestamp,northing,easting\n"
        + "".join(f"{i},{n},{e}\n" for i, (e, n) in enumerate(ref))
    )
    xy, unit = read_positions(tmp_path / "ref.csv")
    np.testing.assert_array_equal(xy, ref) and unit == "metres"
    np.save(tmp_path / "q.npy", ref[:5] + [3.0, 4.0])
    assert read_positions(tmp_path / "q.npy")[1] == "metres"
    # degrees: the local projection keeps great-circle distances within 0.1 %
    ll = np.array([[40.44, -79.99]]) + RNG.uniform(-0.03, 0.03, (50, 2))
    m = latlon_to_metres(ll)
    lat, lon = np.radians(ll).T
    i, j = np.triu_indices(50, 1)
    hav = 2 * 6_371_008.8 * np.arcsin(np.sqrt(
        np.sin((lat[j] - lat[i]) / 2) ** 2
        + np.cos(lat[i]) * np.cos(lat[j]) * np.sin((lon[j] - lon[i]) / 2) ** 2
    ))  # fmt: skip
    np.testing.assert_allclose(np.linalg.norm(m[i] - m[j], axis=1), hav, rtol=1e-3)
    (tmp_path / "ll.csv").write_text("lat,lon\n" + "".join(f"{a},{b}\n" for a, b in ll))
    assert read_positions(tmp_path / "ll.csv")[1] == "degrees"
    names = [f"@{e:.2f}@{n:.2f}@17@T@040.4@-079.9@pano{k}@@@@@201411@.jpg"
             for k, (e, n) in enumerate(ref[:3])]  # fmt: skip
    np.testing.assert_allclose(positions_from_names(names), ref[:3])
    with pytest.raises(InputError, match="no @easting@northing@"):
        positions_from_names(["image0.jpg"])


def _loop(n_per_lap: int, laps: int, noise: float) -> np.ndarray:
    """A 2 km x 200 m oval driven ``laps`` times (metres, UTM-like offsets)."""
    t = np.tile(np.linspace(0, 2 * np.pi, n_per_lap, endpoint=False), laps)
    xy = np.stack([5e5 + 1000 * np.cos(t), 5.7e6 + 100 * np.sin(t)], axis=1)
    return xy + noise * RNG.standard_normal(xy.shape)


def test_gps_places_route_order_and_laps():
    coords = _loop(200, 2, noise=2.0)
    labels = gps_places(coords, k=16, seed=0)
    assert labels.shape == (400,) and set(labels) == set(range(16))
    _, first = np.unique(labels, return_index=True)
    np.testing.assert_array_equal(labels[np.sort(first)], np.arange(16))
    lap1, lap2 = labels[:200], labels[200:]
    assert lap1[0] == 0 and np.mean(lap1 == lap2) > 0.95  # same place, same label
    changes = np.count_nonzero(np.diff(lap1))
    assert changes <= 16 + 4  # contiguous arcs along the oval, few boundary flips
    z = StandardScaler().fit_transform(coords)
    with threadpool_limits(limits=1):
        ref = KMeans(n_clusters=16, n_init=10, random_state=0).fit_predict(z)
    assert adjusted_rand_score(labels, ref) == 1.0


def test_gps_places_errors():
    with pytest.raises(InputError, match=r"\(n, 2\)"):
        gps_places(np.zeros((5, 3)), 2)
    bad = _loop(10, 1, 0.0)
    bad[4, 1] = np.nan
    with pytest.raises(InputError, match="row 4"):
        gps_places(bad, 2)
    with pytest.raises(InputError, match="k must be"):
        gps_places(_loop(10, 1, 0.0), 11)


def test_frame_places_keep_positions_and_group_them(tmp_path):
    coords = _loop(100, 2, noise=1.0)
    np.save(tmp_path / "a.npy", coords[:100])
    np.save(tmp_path / "b.npy", coords[100:])
    specs, sources = [str(tmp_path / "a.npy"), str(tmp_path / "b.npy")], ["a", "b"]
    located = positions_of_sources(specs, sources)
    labels, extra = frame_places(located, None)
    assert labels is None and set(extra) == {
        "reference_positions", "reference_positions_degrees"
    }  # fmt: skip
    np.testing.assert_array_equal(extra["reference_positions"], coords)
    labels, extra = frame_places(located, 8)
    np.testing.assert_array_equal(labels, gps_places(coords, 8))
    np.testing.assert_array_equal(extra["reference_labels"], labels)
    with pytest.raises(InputError, match="2 files for 1 sources"):
        positions_of_sources(specs, ["a"])
