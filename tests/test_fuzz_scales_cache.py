"""Drawn frame scales and drawn damage to ``frontier``'s cache.

Frame scales: a route multiplied by 10**e (e drawn in [-40, 40], or 0.0) is
either fitted into a map that places its own frames about as well as the
unscaled route's does, or refused in one line (exit 2, nothing written) (all
frames zero: a map that says it cannot place them, or one line); the
estimator with ``scale="auto"`` likewise works or raises one line.

Cache entries: one file of a filled ``frontier --cache`` folder drawn and
damaged (cut short, bytes overwritten, an array set to NaN, deleted, JSON
replaced by garbage, a map entry saved again whole with an array all NaN);
the rerun either gives the undamaged run's recall (the entry fitted again) or
one line with exit 2; never a traceback, never recall figures from damaged
data.
"""

from __future__ import annotations

import json
import shutil
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_fuzz_files import _main  # the command line run in this process

N, D = 50, 24
FUZZ = settings(
    max_examples=12,
    deadline=None,
    database=None,
    derandomize=True,  # the same examples on every run: a failure replays
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
# None: scale 0.0; exponents near 0 drawn often too (most of [-40, 40] is refused)
EXPONENTS = st.one_of(st.integers(-40, 40), st.integers(-4, 3), st.just(None))


def _errors(lines: list[str]) -> list[str]:
    """stderr lines that are not notes or warnings (a fit may note its size)."""
    return [ln for ln in lines if ": note: " not in ln and "warning" not in ln.lower()]


@pytest.fixture(scope="module")
def frames() -> np.ndarray:
    """(N, D) float64 unit rows."""
    x = np.random.default_rng(0).normal(size=(N, D))
    return x / np.linalg.norm(x, axis=1, keepdims=True)


def _scaled(x: np.ndarray, e: int | None) -> np.ndarray:
    """x * 10**e in float64 (0.0 for ``None``): past float32's range the reader
    meets infinities or zeros, which it must refuse in one line."""
    return x * (0.0 if e is None else 10.0**e)


def _self_recall(root: Path, x_path: Path, codes: list[str]) -> tuple[int, list, float]:
    """(fit's status, fit's stderr lines, the map's self-recall or NaN)."""
    out = root / "m.map"
    code, _, lines = _main(["fit", str(x_path), "--out", str(out), "--no-progress",
                            *codes])  # fmt: skip
    if code != 0:
        return code, lines, float("nan")
    q, _, qlines = _main(["query", str(out), str(x_path), "--out", str(root / "p.npy"),
                          "--no-progress"])  # fmt: skip
    assert q == 0, qlines
    pred = np.load(root / "p.npy")
    return code, lines, float((pred == np.arange(N)).mean())


@pytest.fixture(scope="module")
def baseline(frames, tmp_path_factory) -> dict[str, float]:
    """The unscaled route's self-recall, with and without int8 codes."""
    root = tmp_path_factory.mktemp("scale1")
    np.save(root / "x.npy", frames.astype(np.float32))
    found = {}
    for name, codes in (("plain", []), ("int8", ["--codes", "int8"])):
        code, lines, recall = _self_recall(root, root / "x.npy", codes)
        assert code == 0, lines
        shutil.rmtree(root / "m.map")
        found[name] = recall
    assert min(found.values()) > 0.5  # the route is one a map can learn
    return found


@settings(FUZZ, max_examples=30)
@given(e=EXPONENTS, int8=st.booleans())
def test_scaled_frames_fit_a_usable_map_or_end_in_one_line(frames, baseline, e, int8):
    codes = ["--codes", "int8"] if int8 else []
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        np.save(root / "x.npy", _scaled(frames, e))
        with np.errstate(all="ignore"):
            code, lines, recall = _self_recall(root, root / "x.npy", codes)
        if code == 0 and e is None:  # every frame the same: none can be placed
            assert any("warning: the map places at most" in ln for ln in lines), lines
        elif code == 0:
            expected = baseline["int8" if int8 else "plain"]
            # frames accepted as they are but short (RMS 1e-3 to 1e-1) fit a
            # weaker map; the fit must then say its periods miss their frames
            said = any("its periods miss" in ln for ln in lines)
            assert recall >= expected - 0.1 or said, (e, int8, recall, expected, lines)
        else:
            assert code == 2, (e, lines)
            errors = _errors(lines)
            assert len(errors) == 1 and ": error: " in errors[0], (e, lines)
            assert "Traceback" not in "\n".join(lines)
            assert not (root / "m.map").exists(), (e, "a refused fit left a map")


@settings(FUZZ, max_examples=30)
@given(e=EXPONENTS)
def test_estimator_auto_scale_works_or_raises_one_line(frames, e):
    from rhythmic_jax import RhythmicMap
    from rhythmic_jax.errors import InputError

    x0 = frames.astype(np.float32)
    plain = RhythmicMap(scale="auto").fit(x0)
    expected = float((np.asarray(plain.predict(x0)) == np.arange(N)).mean())
    with np.errstate(all="ignore"):
        x = _scaled(frames, e).astype(np.float32)
    try:
        with warnings.catch_warnings(record=True) as said:
            warnings.simplefilter("always")
            m = RhythmicMap(scale="auto").fit(x)
    except InputError as err:
        assert "\n" not in str(err) and str(err), (e, str(err))
        return
    if e is None:  # every frame the same: none can be placed, and the fit says so
        assert any("places at most" in str(w.message) for w in said), said
        return
    recall = float((np.asarray(m.predict(x)) == np.arange(N)).mean())
    assert recall >= expected - 0.1, (e, recall, expected)


def test_auto_scale_of_short_frames_keeps_recall(frames):
    """Frames of RMS 1e-2, which a fit takes as they are but places badly, are
    standardised by scale='auto' and placed as the unscaled ones are."""
    from rhythmic_jax import RhythmicMap

    x0 = frames.astype(np.float32)
    plain = RhythmicMap(scale="auto").fit(x0)
    expected = float((np.asarray(plain.predict(x0)) == np.arange(N)).mean())
    x = (frames * 1e-2).astype(np.float32)
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        m = RhythmicMap(scale="auto").fit(x)
    recall = float((np.asarray(m.predict(x)) == np.arange(N)).mean())
    assert recall >= expected - 0.1, (recall, expected, [str(w.message) for w in said])


# ------------------------------------------------------------------ cache entries
def _frontier(ref: Path, qry: Path, cache: Path) -> tuple[int, dict | None, list[str]]:
    code, out, lines = _main(["frontier", str(ref), str(qry), "--maps", "2:1",
                              "--bits", "8", "--pq", "", "--lengths", "1",
                              "--cache", str(cache), "--json",
                              "--no-progress"])  # fmt: skip
    return code, json.loads(out) if code == 0 else None, lines


def _recalls(result: dict) -> dict[str, float]:
    return {r["name"]: r["recall@1 L=1"] for r in result["rows"]}


@pytest.fixture(scope="module")
def filled(tmp_path_factory) -> dict:
    """A route (ref, qry .npy), a filled cache folder and the undamaged recall."""
    root = tmp_path_factory.mktemp("frontier_cache")
    rng = np.random.default_rng(0)
    walk = np.cumsum(rng.standard_normal((90, 16)), axis=0).astype(np.float32)
    walk -= walk.mean(axis=0)
    for name, noise in (("ref.npy", 0.3), ("qry.npy", 0.8)):
        jitter = noise * rng.standard_normal((90, 16)).astype(np.float32)
        np.save(root / name, walk + jitter)
    cache = root / "cache"
    code, result, lines = _frontier(root / "ref.npy", root / "qry.npy", cache)
    assert code == 0, lines
    files = sorted(str(p.relative_to(cache)) for p in cache.rglob("*") if p.is_file())
    assert files, "the cache kept nothing"
    code, again, lines = _frontier(root / "ref.npy", root / "qry.npy", cache)
    assert code == 0 and _recalls(again) == _recalls(result), lines  # read back
    return {"root": root, "cache": cache, "files": files, "recalls": _recalls(result)}


DAMAGES = ("truncate", "overwrite", "nan", "delete", "garbage", "nan map")


def _nan_map(entry: Path, data: st.DataObject) -> None:
    """The map folder ``entry`` saved again, whole and with fresh digests, with
    one drawn float array of its stored ones all NaN."""
    import dataclasses

    from rhythmic_jax.map import map_file

    m = map_file.load(entry)
    floats = sorted(k for k, v in m.stored.items() if np.asarray(v).dtype.kind == "f")
    key = data.draw(st.sampled_from(floats))
    stored = {**m.stored, key: np.full_like(np.asarray(m.stored[key]), np.nan)}
    map_file.save(entry, dataclasses.replace(m, stored=stored))


def _damage(path: Path, how: str, data: st.DataObject) -> None:
    """Damage one cached file in place (``nan map``: a map entry's arrays)."""
    raw = path.read_bytes()
    entry = next((p for p in path.parents if p.name.startswith("map-")), None)
    if how == "nan map" and entry is not None:
        _nan_map(entry, data)
        return
    if how == "truncate":
        path.write_bytes(raw[: data.draw(st.integers(0, max(len(raw) - 1, 0)))])
    elif how == "overwrite":
        start = data.draw(st.integers(0, max(len(raw) - 1, 0)))
        length = data.draw(st.integers(1, 64))
        noise = data.draw(st.binary(min_size=length, max_size=length))
        path.write_bytes(raw[:start] + noise + raw[start + length:])
    elif how == "delete":
        path.unlink()
    elif how == "garbage" or path.suffix not in (".npy", ".npz"):
        path.write_bytes(data.draw(st.binary(min_size=0, max_size=64)) + b"{not json")
    elif path.suffix == ".npy":
        try:
            a = np.load(path, allow_pickle=False)
        except Exception:  # noqa: BLE001 - not an array we can rewrite: cut it
            path.write_bytes(raw[: len(raw) // 2])
            return
        if a.dtype.kind == "f" and a.size:
            np.save(path, np.full_like(a, np.nan))
        else:
            path.write_bytes(raw[: len(raw) // 2])
    else:  # .npz: every float array NaN
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        arrays = {k: np.full_like(v, np.nan) if v.dtype.kind == "f" and v.size else v
                  for k, v in arrays.items()}  # fmt: skip
        with open(path, "wb") as f:
            np.savez(f, **arrays)


@settings(FUZZ, max_examples=14)
@given(data=st.data())
def test_a_damaged_cache_entry_is_refitted_or_refused(filled, data):
    index = data.draw(st.integers(0, len(filled["files"]) - 1))
    how = data.draw(st.sampled_from(DAMAGES))
    with tempfile.TemporaryDirectory() as tmp:
        cache = Path(tmp) / "cache"
        shutil.copytree(filled["cache"], cache)
        name = filled["files"][index]
        _damage(cache / name, how, data)
        root = filled["root"]
        code, result, lines = _frontier(root / "ref.npy", root / "qry.npy", cache)
        assert "Traceback" not in "\n".join(lines), (name, how, lines)
        if code == 0:
            assert _recalls(result) == filled["recalls"], (name, how)
        else:
            errors = _errors(lines)
            assert code == 2 and len(errors) == 1, (name, how, lines)
            assert ": error: " in errors[0], (name, how, lines)
