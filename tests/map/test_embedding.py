"""The closed-form invariant embedding, its storage count, and maps that carry it."""

from __future__ import annotations

import numpy as np
import pytest

from rhythmic_jax import MapConfig, RhythmicMap
from rhythmic_jax.errors import InputError
from rhythmic_jax.map.embedding import (
    apply,
    embedding_bytes,
    fit_invariant,
    load_embedding,
    save_embedding,
)


def two_conditions(n=400, d=48, nuisance=8, strength=3.0, seed=0):
    """Places p_i in R^d seen under two conditions that add large noise in a
    fixed subspace: (cond A (n, d), cond B (n, d))."""
    rng = np.random.default_rng(seed)
    places = rng.normal(size=(n, d))
    basis = np.linalg.qr(rng.normal(size=(d, nuisance)))[0]
    out = []
    for _ in range(2):
        noise = strength * rng.normal(size=(n, nuisance)) @ basis.T
        out.append((places + noise + 0.3 * rng.normal(size=(n, d))).astype("float32"))
    return out


def brute(ref, qry):
    ref = ref / np.linalg.norm(ref, axis=1, keepdims=True)
    qry = qry / np.linalg.norm(qry, axis=1, keepdims=True)
    return float(np.mean((qry @ ref.T).argmax(1) == np.arange(len(ref))))


def test_invariant_embedding_removes_the_condition_change():
    a, b = two_conditions()
    emb = fit_invariant([a[:200], b[:200]], k=24, p=40)
    raw = brute(a[200:], b[200:])
    embedded = brute(apply(emb, a[200:]), apply(emb, b[200:]))
    assert embedded > raw + 0.2, (raw, embedded)
    assert embedding_bytes(emb) == 4 * (48 + 48 * 24)


def test_map_with_embedding_saves_applies_and_counts_it(tmp_path):
    a, b = two_conditions()
    emb = fit_invariant([a[:200], b[:200]], k=24, p=40)
    m = RhythmicMap(r=2, level=1, embedding=emb).fit(a[200:], progress=False)
    assert m.d == 48 and m.params.w.shape == (24, sum(m.periods))
    assert m.storage_bytes == sum(m.periods) * 25 * 4
    assert m.embedding_bytes == embedding_bytes(emb)
    info = m.info()
    assert info["embedding"] == {"kind": "linear", "k": 24}
    want = (m.storage_bytes + m.embedding_bytes) / (200 * 48 * 4)
    assert info["compression_ratio"] == pytest.approx(want)
    m.save(tmp_path / "m")
    back = RhythmicMap.load(tmp_path / "m")
    np.testing.assert_array_equal(back.predict(b[200:]), m.predict(b[200:]))
    with pytest.raises(InputError, match="48"):
        back.predict(b[200:, :10])


def test_embedding_folder_round_trip_and_refusal(tmp_path):
    a, b = two_conditions(n=120)
    emb = fit_invariant([a, b], k=8, p=16)
    save_embedding(tmp_path / "e", emb, {"descriptor": "features"})
    back, meta = load_embedding(tmp_path / "e")
    np.testing.assert_allclose(apply(back, a), apply(emb, a), rtol=1e-6)
    assert meta["k"] == 8 and meta["descriptor"] == "features"
    m = RhythmicMap(r=2, level=1).fit(a, progress=False)
    m.save(tmp_path / "m")
    with pytest.raises(InputError, match="not an embedding"):
        load_embedding(tmp_path / "m")
    with pytest.raises(InputError, match="two or more"):
        fit_invariant([a])


@pytest.mark.slow  # two fits, a save and a load: about 30 s on 2 cores
def test_hybrid_map_on_an_embedding_counts_saves_and_describes_it(tmp_path):
    from rhythmic_jax.app import jobs, render, specs

    a, b = two_conditions(n=300)
    emb = fit_invariant([a[:150], b[:150]], k=24, p=40)
    save_embedding(tmp_path / "e", emb, {"descriptor": "features"})
    np.save(tmp_path / "ref.npy", a[150:])
    job = specs.FitJob(
        (str(tmp_path / "ref.npy"),), str(tmp_path / "m"),
        config=MapConfig(codes=16), embedding=str(tmp_path / "e"),
    )  # fmt: skip
    m = jobs.fit(job)
    # ITQ fitted on the embedded frames: a (16, k) projection, not (16, d)
    assert m.codebook.transform.projection.shape == (16, 24)
    n, k, tau = 150, 24, sum(m.periods)
    by_hand = tau * (k + 1) * 4 + n * 2 + (16 * k + k) * 4
    assert m.storage_bytes == by_hand
    assert m.embedding_bytes == 4 * (48 + 48 * 24)
    assert m.compression_ratio == pytest.approx(
        (by_hand + m.embedding_bytes) / (n * 48 * 4)
    )
    back = RhythmicMap.load(tmp_path / "m")
    for kw in ({}, {"sequence": 5}):
        np.testing.assert_array_equal(
            back.predict(b[150:], "soft", **kw), m.predict(b[150:], "soft", **kw)
        )
    on_disk = jobs.info(str(tmp_path / "m"))
    assert on_disk["storage_bytes"] == by_hand and on_disk["codes_bits"] == 16
    assert on_disk["embedding"] == {"kind": "linear", "k": 24}
    text = render.info_lines(on_disk)
    assert f"2 B (codes; {n * 2:,} B for {n} places)" in text  # per place, then all
    assert "embedding_bytes" in text
    with pytest.raises(InputError, match="at most d=24"):
        jobs.fit(specs.FitJob(job.sources, str(tmp_path / "m2"),
                             config=MapConfig(codes=32),
                             embedding=job.embedding))  # fmt: skip


def test_invariant_embedding_is_finite_with_few_training_frames():
    """p capped at (frames - 1) keeps an axis of no variance: it is dropped, not
    whitened to inf; a k above the axes left is refused in one line."""
    from rhythmic_jax.map.embedding import apply, fit_invariant

    rng = np.random.default_rng(0)
    a = rng.normal(size=(150, 40)) @ rng.normal(size=(40, 2048))
    b = a.copy()
    b[:, :100] += 0.3 * rng.normal(size=(150, 100))  # rank <= 140 in 300 frames
    a, b = a.astype(np.float32), b.astype(np.float32)
    emb = fit_invariant([a, b], k=64, p=512)
    assert np.isfinite(np.asarray(emb.proj)).all()
    assert np.isfinite(apply(emb, a)).all()
    with pytest.raises(InputError, match="principal axes"):
        fit_invariant([a, b], k=250, p=512)


def test_fusion_weight_of_an_option_an_embedding_or_the_default():
    """--fusion wins; else the weight the embedding learned for these codes; an
    embedding saved before (no weight) or for other codes: 0.5, said why."""
    from rhythmic_jax.map.embedding import fusion_of

    learned = {"descriptor": "features", "fusion": {
        "weight": 0.15, "codes": "int8", "recall": 0.9, "places": 120}}  # fmt: skip
    got = fusion_of(None, "int8", learned)
    assert got["weight"] == 0.15 and got["from"] == "embedding"
    assert "120 training places" in got["note"]
    assert fusion_of(0.7, "int8", learned) == {
        "weight": 0.7, "from": "option", "note": "given with --fusion"}  # fmt: skip
    other = fusion_of(None, 64, learned)
    assert other["weight"] == 0.5 and "learned for int8 codes" in other["note"]
    old = fusion_of(None, "int8", {"descriptor": "features"})
    assert old["weight"] == 0.5 and "no learned weight" in old["note"]
    assert fusion_of(None, None, None)["from"] == "default"


def test_an_embedding_saved_without_a_weight_loads_and_gives_its_descriptor(
    tmp_path,
):
    from rhythmic_jax.app.jobs import _before_reading, info
    from rhythmic_jax.app.render import info_lines
    from rhythmic_jax.app.specs import FitJob, Reading
    from rhythmic_jax.map.embedding import fusion_of

    a, b = two_conditions(n=120)
    emb = fit_invariant([a, b], k=8, p=16)
    settings = {"weights": "/w/vgg.pth"}
    meta = {"descriptor": "vgg16_fc7", "descriptor_settings": settings}
    save_embedding(tmp_path / "e", emb, meta)  # as learn wrote them before
    back, meta = load_embedding(tmp_path / "e")
    assert "fusion" not in meta and fusion_of(None, "int8", meta)["weight"] == 0.5
    folder, out = str(tmp_path), str(tmp_path / "m.map")

    def reading(sources, embedding=str(tmp_path / "e"), **kw):
        """The reading a fit of ``sources`` settles before reading them."""
        return _before_reading(FitJob(sources, out, embedding=embedding, **kw)).reading

    taken = reading((folder,))
    assert taken.descriptor == "vgg16_fc7" and taken.weights == "/w/vgg.pth"
    given = Reading(descriptor="hog")
    assert reading((folder,), reading=given) is given
    assert reading((str(tmp_path / "x.npy"),)) == Reading()
    assert reading((folder,), embedding=None) == Reading()
    described = info(str(tmp_path / "e"))  # info says it, without loading JAX arrays
    assert described["kind"] == "embedding" and described["fusion"] is None
    text = info_lines(described)
    assert "8 dims" in text and "vgg16_fc7 (fit --embedding describes" in text
    assert "none learned (saved before learn kept one): maps fuse at 0.5" in text
    fusion = {"weight": 0.1, "codes": "int8", "recall": 0.75, "places": 120}
    save_embedding(tmp_path / "new", emb, {**meta, "fusion": fusion})
    text = info_lines(info(str(tmp_path / "new")))
    assert "fusion: 0.1 for int8 codes (R@1 0.750 on the training places" in text


@pytest.mark.slow  # learning the weight (two map fits) and three fits: about 2 min
def test_learn_stores_the_fusion_weight_and_fit_uses_it(tmp_path):
    from test_learn import noisy_conditions

    from rhythmic_jax.app import jobs, render, specs

    a, b = noisy_conditions(n=300)
    for name, x in (("a", a[:150]), ("b", b[:150]), ("test", a[150:])):
        np.save(tmp_path / f"{name}.npy", x)
    src = lambda *names: tuple(str(tmp_path / f"{s}.npy") for s in names)  # noqa: E731
    config = specs.learn_config(method="invariant", k=24)
    emb, info = jobs.learn(specs.LearnJob(src("a", "b"), str(tmp_path / "e"), config))
    _, meta = load_embedding(tmp_path / "e")
    stored, learned = meta["fusion"], info["fusion"]
    w = stored["weight"]
    # approx takes flat mappings only (pytest 9 refuses nested values): the
    # scalars through approx, the [[w, recall@1], ...] table element by element
    assert stored.keys() == learned.keys() and w < 0.5
    flat = [k for k in learned if k != "table"]
    assert {k: stored[k] for k in flat} == pytest.approx({k: learned[k] for k in flat})
    np.testing.assert_allclose(stored["table"], learned["table"], rtol=1e-12)
    assert meta["descriptor"] == "features" and meta["fusion"]["codes"] == "int8"
    assert f"fusion {w:g} for int8 codes" in render.learn_summary("e", emb, info)

    def fitted(name, **kw):
        job = specs.FitJob(
            src("test"), str(tmp_path / name), config=MapConfig(codes="int8"), **kw
        )
        return jobs.fit(job), render.info_lines(jobs.info(str(tmp_path / name)))

    m, text = fitted("m", embedding=str(tmp_path / "e"))
    assert m.config.fusion == w and f"fusion: {w:g} (embedding: learned" in text
    assert f"embedding from: {tmp_path / 'e'}" in text
    m, text = fitted("given", embedding=str(tmp_path / "e"), fusion=0.7)
    assert m.config.fusion == 0.7 and "fusion: 0.7 (option" in text
    m, text = fitted("plain")
    assert m.config.fusion == 0.5 and "(default: no embedding)" in text
