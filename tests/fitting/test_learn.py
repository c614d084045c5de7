"""Embeddings learned through the map and by InfoNCE, on a synthetic route."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from map.test_embedding import two_conditions

from rhythmic_jax import RhythmicMap
from rhythmic_jax.errors import InputError
from rhythmic_jax.fitting.learn import LearnConfig, learn_embedding


def map_accuracy(ref, qry, embedding=None):
    m = RhythmicMap(r=2, level=1, embedding=embedding).fit(ref, progress=False)
    pred = m.predict(qry, "soft")
    return float(np.mean(pred == np.arange(len(ref))))


@pytest.mark.parametrize(
    "method", [pytest.param("map", marks=pytest.mark.slow), "infonce"]
)
def test_learned_embedding_raises_the_maps_cross_condition_accuracy(method):
    a, b = two_conditions(n=560, strength=4.0, seed=3)
    train, test = slice(0, 280), slice(300, 560)
    cfg = LearnConfig(method=method, k=40, p=46, window=60, steps=40, eval_every=10,
                      holdout=0)  # its own test places below  # fmt: skip
    emb, info = learn_embedding([a[train], b[train]], cfg)
    before = map_accuracy(a[test], b[test])
    after = map_accuracy(a[test], b[test], emb)
    assert after > before + 0.1, (before, after)
    assert info["steps"] == 40 and 0 <= info["kept_step"] <= 40
    assert len(info["val_loss"]) == 5


@pytest.mark.parametrize("head", ["linear", "mlp"])
def test_training_compiles_its_step_once(caplog, head):
    """The head's parameters keep their types from the first step on: one
    program for the step and one for the validation loss, whatever the steps."""
    import logging

    import jax

    a, b = two_conditions(n=200, seed=5)
    cfg = LearnConfig(method="infonce", head=head, k=8, p=10, window=30, steps=6)
    with caplog.at_level(logging.WARNING, logger="jax"), jax.log_compiles():
        learn_embedding([a, b], dataclasses.replace(cfg, eval_every=3))
    names = [r.getMessage().split(" with ")[0] for r in caplog.records]
    assert names.count("Compiling jit(step)") == 1, names
    assert names.count("Compiling jit(val_loss)") == 1, names


def test_bad_settings_and_inputs():
    with pytest.raises(InputError, match="method"):
        LearnConfig(method="triplet")
    a, b = two_conditions(n=100)
    with pytest.raises(InputError, match="two or more"):
        learn_embedding([a])
    with pytest.raises(InputError, match="shape"):
        learn_embedding([a, b[:50]])


def test_pca_method_is_the_principal_axes_of_every_traversal():
    """method="pca": scikit-learn's PCA of the stacked traversals (up to sign),
    then unit rows; no steps."""
    from sklearn.decomposition import PCA

    from rhythmic_jax.map.embedding import apply

    a, b = two_conditions(n=120, seed=4)
    emb, info = learn_embedding([a, b], LearnConfig(method="pca", k=8, holdout=0))
    assert info["steps"] == 0 and emb.k == 8 and emb.kind == "linear"
    ref = PCA(8).fit(np.concatenate([a, b]))
    z = ref.transform(a)
    z /= np.linalg.norm(z, axis=1, keepdims=True)
    got = apply(emb, a)
    sign = np.sign(np.sum(got * z, axis=0))
    np.testing.assert_allclose(got * sign, z, atol=2e-4)


def noisy_conditions(n=180, noise=1.0):
    """Two conditions where the codes of the embedded frames beat the map alone."""
    a, b = two_conditions(n=n, strength=4.0, seed=5)
    rng = np.random.default_rng(1)
    a = a + noise * rng.normal(size=a.shape).astype(np.float32)
    b = b + noise * rng.normal(size=b.shape).astype(np.float32)
    return a, b


@pytest.mark.slow  # three map fits with codes: about 60 s on 2 cores
def test_fusion_weight_is_the_best_recall_of_the_fused_map_on_the_traversals():
    """learn_fusion's table is the recall@1 (within one place) of a map with codes
    fitted on one traversal and queried with the other, averaged both ways; its
    weight is the best of that table, below 0.5 where the codes are stronger."""
    from rhythmic_jax.app.jobs import learn_fusion
    from rhythmic_jax.map.embedding import fit_invariant

    a, b = noisy_conditions()
    emb = fit_invariant([a, b], k=40, p=80)
    got = learn_fusion([a, b], emb, "int8")
    table = dict(got["table"])
    assert got["codes"] == "int8" and got["places"] == 180 and len(table) == 21
    assert table[got["weight"]] == got["recall"] == max(table.values())
    assert got["weight"] < 0.5 and table[got["weight"]] > table[1.0] + 0.3
    gt = np.arange(180)
    for w in (got["weight"], 0.5):
        both = []
        for ref, qry in ((a, b), (b, a)):
            m = RhythmicMap(embedding=emb, codes="int8", fusion=w)
            pred = m.fit(ref, progress=False).predict(qry, "soft")
            both.append(np.mean(np.abs(pred - gt) <= 1))
        assert table[w] == pytest.approx(np.mean(both)), w


def _int8_recall(refs, tolerance=1):
    """Recall@1 of int8 codes recomputed in numpy from their documented formula
    (per-dimension min-max, floor(255 t), decoded at the bin's centre, cosine),
    every traversal as the reference and every other as the queries."""
    hits = []
    for a, ref in enumerate(refs):
        ref = np.asarray(ref, np.float64)
        vmin, vdiff = ref.min(axis=0), ref.max(axis=0) - ref.min(axis=0)
        vdiff = np.where(vdiff > 0, vdiff, 1.0)
        code = np.floor(255 * np.clip((ref - vmin) / vdiff, 0, 1))
        dec = vmin + (code + 0.5) / 255 * vdiff
        dec /= np.linalg.norm(dec, axis=1, keepdims=True)
        for b, qry in enumerate(refs):
            if a != b:
                q = np.asarray(qry, np.float64)
                best = np.argmax(q @ dec.T, axis=1)
                hits.append(np.abs(best - np.arange(len(q))) <= tolerance)
    return float(np.mean(np.concatenate(hits)))


def test_held_out_places_are_never_learned_from_and_their_recall_is_numpys():
    """The embedding is the one learned from the learning places alone (the
    held-out ones could change nothing), the two sets are disjoint, and the
    recall reported on the held-out places is numpy's."""
    from rhythmic_jax.fitting.holdout import split_places
    from rhythmic_jax.map.embedding import apply

    a, b = two_conditions(n=300, strength=4.0, seed=7)
    cfg = LearnConfig(method="invariant", k=16, p=40)
    emb, info = learn_embedding([a, b], cfg)
    learn, start = split_places(300, cfg.holdout)
    assert info["learn_places"] == learn and info["held_out"]["places"] == 300 - start
    assert learn < start and set(range(learn)).isdisjoint(range(start, 300))
    alone, _ = learn_embedding(
        [a[:learn], b[:learn]], dataclasses.replace(cfg, holdout=0)
    )
    np.testing.assert_array_equal(np.asarray(emb.proj), np.asarray(alone.proj))
    changed = [a.copy(), b.copy()]
    for x in changed:
        x[start:] = np.random.default_rng(0).normal(size=x[start:].shape)
    moved, _ = learn_embedding(changed, cfg)
    np.testing.assert_array_equal(np.asarray(emb.proj), np.asarray(moved.proj))
    held = [x[start:] for x in (a, b)]
    # float64 here, float32 there: a near tie may flip one of 2 x 60 queries
    assert info["held_out"]["raw"] == pytest.approx(_int8_recall(held), abs=0.01)
    embedded = [apply(emb, x) for x in held]
    assert info["held_out"]["embedded"] == pytest.approx(
        _int8_recall(embedded), abs=0.01
    )


@pytest.mark.slow  # the closed form on 2 x 1,500 real frames: about 2 min
def test_learning_from_few_real_places_warns_and_from_many_does_not(
    nordland_patchnorm,
):
    import warnings

    from rhythmic_jax.solvers.newton import FitWarning

    summer, winter = (np.asarray(x)[::2] for x in nordland_patchnorm)
    with pytest.warns(FitWarning) as record:
        _, info = learn_embedding([summer[:350], winter[:350]])
    lines = [str(w.message) for w in record if w.category is FitWarning]
    assert any("worse on 70 held-out places" in line for line in lines), lines
    assert any("a dimension, fewer than 4" in line for line in lines), lines
    assert info["held_out"]["embedded"] < info["held_out"]["raw"]
    with warnings.catch_warnings():
        warnings.simplefilter("error", FitWarning)
        _, info = learn_embedding([summer[:1500], winter[:1500]])
    assert info["held_out"]["embedded"] > info["held_out"]["raw"]
