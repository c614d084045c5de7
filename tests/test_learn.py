"""Embeddings learned through the map and by InfoNCE, on a synthetic route."""

from __future__ import annotations

import numpy as np
import pytest
from test_embedding import two_conditions

from rhythmic_jax import RhythmicMap
from rhythmic_jax.errors import InputError
from rhythmic_jax.learn import LearnConfig, learn_embedding


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
    cfg = LearnConfig(method=method, k=40, p=46, window=60, steps=40, eval_every=10)
    emb, info = learn_embedding([a[train], b[train]], cfg)
    before = map_accuracy(a[test], b[test])
    after = map_accuracy(a[test], b[test], emb)
    assert after > before + 0.1, (before, after)
    assert info["steps"] == 40 and 0 <= info["kept_step"] <= 40
    assert len(info["val_loss"]) == 5


def test_bad_settings_and_inputs():
    with pytest.raises(InputError, match="method"):
        LearnConfig(method="triplet")
    a, b = two_conditions(n=100)
    with pytest.raises(InputError, match="two or more"):
        learn_embedding([a])
    with pytest.raises(InputError, match="shape"):
        learn_embedding([a, b[:50]])
