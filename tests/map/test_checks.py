"""A map is checked for meaning, not only bytes: each planted fault (its digests
recomputed, so only the meaning is wrong) ends in one line naming it, and a
valid map passes unchanged."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest

import rhythmic_jax as rj
from rhythmic_jax.app.cli import main
from rhythmic_jax.decoding import queries
from rhythmic_jax.errors import InputError
from rhythmic_jax.eval.ground_truth_files import load_ground_truth
from rhythmic_jax.io.checkpoint import load_map, save_map
from rhythmic_jax.map import checks, map_file
from rhythmic_jax.map.checks import MAX_PLACES, check_decode, check_map, decode_bytes
from rhythmic_jax.map.embedding import linear
from rhythmic_jax.map.groups import Groups
from rhythmic_jax.map.pytree import Map

N, D = 40, 8


def _frames(seed: int = 0) -> np.ndarray:
    x = np.random.default_rng(seed).normal(size=(N, D)).astype(np.float32)
    return x / np.linalg.norm(x, axis=1, keepdims=True)


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """(folder, map, frames): a small map fitted and saved once."""
    x = _frames()
    model = rj.RhythmicMap().fit(x)
    folder = tmp_path_factory.mktemp("checks") / "m.map"
    model.save(folder)
    return folder, model.value, x


def _planted(src, dst, arrays=None, meta=None):
    """A copy of the map folder ``src`` at ``dst`` with ``arrays(arrays)`` and
    ``meta(meta)`` applied and its digests recomputed by the save."""
    got, info = load_map(src)
    info.pop("format_version", None)
    if arrays:
        arrays(got)
    if meta:
        meta(info)
    save_map(dst, got, info)
    return dst


def _one_line(err: pytest.ExceptionInfo) -> str:
    text = str(err.value)
    assert "\n" not in text
    return text


def test_a_valid_map_passes_unchanged(fitted):
    folder, m, x = fitted
    assert check_map(m) is m
    loaded = map_file.load(folder)
    np.testing.assert_array_equal(queries.predict(loaded, x), queries.predict(m, x))


def _set(name, index, value):
    def plant(arrays):
        arrays[name] = arrays[name].copy()
        arrays[name][index] = value

    return plant


@pytest.mark.parametrize(
    ("plant", "named"),
    [
        (_set("w", (slice(None), slice(None, None, 2)), np.nan), "w holds"),
        (_set("b", slice(None), np.inf), "b holds"),
        (_set("b", 0, -np.inf), "b holds 1 NaN"),
    ],
)
def test_non_finite_templates_are_refused_on_load(fitted, tmp_path, plant, named):
    folder, _, _ = fitted
    bad = _planted(folder, tmp_path / "bad.map", arrays=plant)
    with pytest.raises(InputError, match=named) as err:
        map_file.load(bad)
    assert _one_line(err).startswith(str(bad))


def test_non_finite_record_is_refused(fitted, tmp_path):
    folder, _, _ = fitted

    def nan_c(meta):
        meta["c"] = float("nan")  # json writes NaN, and reads it back

    bad = _planted(folder, tmp_path / "c.map", meta=nan_c)
    with pytest.raises(InputError, match="c holds 1 NaN"):
        map_file.load(bad)


def test_non_finite_extra_and_embedding_are_refused(fitted):
    _, m, _ = fitted
    extra = {"pca_mean": np.array([0.0, np.nan])}
    with pytest.raises(InputError, match=r"extra\['pca_mean'\] holds 1"):
        check_map(dataclasses.replace(m, extra=extra))
    emb = linear(np.zeros(D, np.float32), np.eye(D, dtype=np.float32))
    emb = emb._replace(mean=jnp.full((D,), jnp.inf))
    with pytest.raises(InputError, match="embedding.*holds 8"):
        check_map(dataclasses.replace(m, embedding=emb))


def _with_periods(m: Map, periods, n) -> Map:
    p = sum(periods)
    w, b = np.zeros((m.k, p), np.float32), np.zeros(p, np.float32)
    return dataclasses.replace(
        m, w=w, b=b, stored={"w": w, "b": b}, periods=tuple(periods), n=n,
        groups=Groups("periods", tuple(periods)),
    )  # fmt: skip


def test_a_layout_beyond_int32_indices_is_refused(fitted):
    """The issue's map: periods (99991, 100003), n their product (about
    10**10): every digest right, a hard decode's int32 indices overflow."""
    _, m, _ = fitted
    huge = _with_periods(m, (99991, 100003), 99991 * 100003)
    with pytest.raises(InputError, match="a decode indexes fewer than") as err:
        check_map(huge, "big.map")
    assert _one_line(err).startswith("big.map: periods (99991, 100003)")
    # just below the bound passes
    ok = _with_periods(m, (32749, 32771), 32749 * 32771)
    assert 32749 * 32771 < MAX_PLACES
    assert check_map(ok) is ok


def test_the_issue_map_is_refused_from_its_folder(fitted, tmp_path, capsys):
    folder, _, x = fitted
    per = (99991, 100003)

    def arrays(a):
        a["w"] = np.ones((D, sum(per)), np.float32)
        a["b"] = np.ones(sum(per), np.float32)

    def meta(info):
        info.update(periods=list(per), n=per[0] * per[1])
        info["groups"] = {"kind": "periods", "sizes": list(per), "segment": 0}

    bad = _planted(folder, tmp_path / "huge.map", arrays, meta)
    np.save(tmp_path / "q.npy", x)
    code = main(["query", str(bad), str(tmp_path / "q.npy"), "--decode", "soft"])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and "a decode indexes fewer than" in err


def test_shapes_must_agree_with_the_layout(fitted):
    _, m, _ = fitted
    with pytest.raises(InputError, match="w of shape"):
        check_map(dataclasses.replace(m, w=np.zeros((D, 3), np.float32)))
    stored = dict(m.stored, scale=np.ones(2, np.float32))
    with pytest.raises(InputError, match="stored scale of shape"):
        check_map(dataclasses.replace(m, stored=stored))
    with pytest.raises(InputError, match="differ from the layout"):
        check_map(dataclasses.replace(m, periods=m.periods[::-1]))
    with pytest.raises(InputError, match="tells apart"):
        check_map(dataclasses.replace(m, n=m.groups.capacity + 1))


@pytest.mark.parametrize(
    ("labels", "match"),
    [
        (np.r_[np.arange(N - 1), 10**6], "name places 0..1000000, the map has 0..39"),
        (np.r_[-1, np.arange(N - 1)], "name places -1..38"),
        (np.arange(N, dtype=np.float32), "one integer place"),
        (np.zeros((N, 2), np.int64), "one integer place"),
    ],
)
def test_reference_labels_lie_inside_the_map(fitted, tmp_path, labels, match):
    folder, m, _ = fitted

    def plant(arrays):
        arrays["extra_reference_labels"] = labels

    bad = _planted(folder, tmp_path / "labels.map", arrays=plant)
    with pytest.raises(InputError, match=match):
        map_file.load(bad)


def test_labels_and_positions_agree(fitted):
    _, m, _ = fitted
    good = dict(
        reference_labels=np.arange(N) // 2, reference_positions=np.zeros((N, 2))
    )
    assert check_map(dataclasses.replace(m, extra=good))
    short = dict(good, reference_positions=np.zeros((N - 1, 2)))
    with pytest.raises(InputError, match="40 reference_labels but 39"):
        check_map(dataclasses.replace(m, extra=short))
    flat = dict(good, reference_positions=np.zeros(N))
    with pytest.raises(InputError, match=r"want \(rows, 2\)"):
        check_map(dataclasses.replace(m, extra=flat))


def test_decode_memory_is_bounded_before_the_decode(fitted, monkeypatch):
    """A decode that scores every place is refused in one line when its
    allocation exceeds the budget; the hard decode, whose memory follows p, is
    not checked, and answers."""
    _, m, x = fitted
    assert decode_bytes(m, "hard", 10**6) == 0
    soft = decode_bytes(m, "soft", len(x))
    assert soft == 64 * 2**20 + m.n * (128 + len(x) * 10)
    assert decode_bytes(m, "soft", 10**6) == soft + m.n * (256 - len(x)) * 10  # a batch
    with pytest.raises(InputError, match="a soft decode of 40 places needs"):
        check_decode(m, "soft", len(x), budget=soft - 1)
    assert check_decode(m, "soft", len(x), budget=soft) == soft
    monkeypatch.setattr(checks, "_SMALL", 0)  # small decodes are not checked
    monkeypatch.setattr(checks, "memory_budget", lambda: 1000)
    with pytest.raises(InputError, match="available; decode hard"):
        queries.decode(m, x, "soft")
    with pytest.raises(InputError, match="a soft decode"):
        queries.predict(m, x, "soft", sequence=3)
    hard = queries.predict(m, x, "hard")
    assert hard.shape == (N,)


def test_an_evaluation_ranking_every_place_is_bounded(fitted, monkeypatch):
    """evaluate ranks every place for every query at once (recall@K): its
    (b, n) scores are checked before they are made."""
    from rhythmic_jax.eval.report import evaluate_map

    _, m, x = fitted
    model = rj.RhythmicMap()
    model.map = m
    ranking = decode_bytes(m, "soft", len(x), at_once=True)
    assert ranking == 64 * 2**20 + m.n * (128 + len(x) * 12)  # 4 (r + 1) a place
    monkeypatch.setattr(checks, "_SMALL", 0)
    monkeypatch.setattr(checks, "memory_budget", lambda: ranking - 1)
    with pytest.raises(InputError, match="ranking 40 places for 40 queries"):
        evaluate_map(model, x, timing=False)
    monkeypatch.setattr(checks, "memory_budget", lambda: ranking)
    got = evaluate_map(model, x, timing=False)["methods"]["map"]["accuracy"]
    assert got == pytest.approx(np.mean(queries.predict(m, x) == np.arange(N)))


def test_memory_budget_follows_the_address_space_limit():
    import resource

    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    assert 0 < checks.memory_budget()
    assert checks.memory_budget() <= checks.memory_budget() * 2  # a number
    if hard == resource.RLIM_INFINITY or hard > 2**44:
        resource.setrlimit(resource.RLIMIT_AS, (2**44, hard))
        try:
            assert checks.memory_budget() <= 2**44
        finally:
            resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


@pytest.mark.slow
@pytest.mark.parametrize("rows", [16, 256])
def test_decode_bytes_bounds_the_measured_peak(rows):
    """The estimate is at least what a soft decode of 250,000 places adds to
    the process (its compiling, columns and scores; measured 103 MiB at 16
    queries, 522 MiB at 256, against estimates of 133 and 705 MiB)."""
    from rhythmic_jax.decoding.dispatch import decode_scores
    from rhythmic_jax.solvers.memory import peak_growth

    per, n = (499, 503), 250_000
    s = np.random.default_rng(rows).normal(size=(rows, sum(per))).astype(np.float32)
    m = _with_periods(rj.RhythmicMap().fit(_frames()).value, per, n)
    grown = peak_growth(
        lambda: decode_scores(jnp.asarray(s), per, n, "soft").index.block_until_ready()
    )
    want = decode_bytes(m, "soft", rows)
    assert grown <= want, (grown, want)


def test_an_infinite_ground_truth_radius_is_refused(tmp_path):
    rng = np.random.default_rng(0)
    db, q = rng.uniform(0, 100, (5, 2)), rng.uniform(0, 100, (3, 2))
    path = tmp_path / "pitts.npz"
    np.savez(path, utmQ=q, utmDb=db, posDistThr=np.inf)
    with pytest.raises(InputError, match="posDistThr must be a finite radius") as err:
        load_ground_truth([str(path)], n_queries=3, n_places=5, query_source="q")
    assert _one_line(err).startswith(str(path))
    np.savez(path, utmQ=q, utmDb=db, posDistThr=25.0)
    assert (
        load_ground_truth(
            [str(path)], n_queries=3, n_places=5, query_source="q"
        ).n_places
        == 5
    )


@pytest.mark.parametrize(
    ("field", "value", "match"),
    [
        ("descriptor_settings", "x", "descriptor_settings must be a mapping"),
        ("descriptor_settings", None, "descriptor_settings must be a mapping"),
        ("descriptor", 3, "descriptor must be a name"),
        ("top", 0, r"top \(phases top-m keeps\) must be an integer >= 1"),
        ("top", 2.5, "must be an integer"),
    ],
)
def test_the_configuration_a_query_reads_is_checked(
    fitted, tmp_path, field, value, match
):
    """map.json is not digested: its configuration is checked for what a
    query reads of it (these ended in a TypeError or ValueError before)."""
    folder, _, _ = fitted

    def meta(info):
        info["config"][field] = value

    bad = _planted(folder, tmp_path / "config.map", meta=meta)
    with pytest.raises(InputError, match=match):
        map_file.load(bad)


@pytest.mark.parametrize("field", ["n", "candidates"])
def test_an_infinite_count_in_map_json_is_corrupt_metadata(fitted, tmp_path, field):
    folder, _, _ = fitted

    def meta(info):
        info[field] = float("inf") if field == "n" else [float("inf")]

    bad = _planted(folder, tmp_path / "inf.map", meta=meta)
    with pytest.raises(InputError, match="corrupt map metadata"):
        map_file.load(bad)
