"""A hybrid on an embedding (a map + codes of the embedded frames) judged along
sequences: its codes score the queries embedded, as its own decode does."""

from __future__ import annotations

import numpy as np
import pytest
from map.test_embedding import two_conditions

import rhythmic_jax as rj
from rhythmic_jax.eval.report import evaluate_map


@pytest.mark.parametrize("codes", ["int8", 16])
def test_evaluate_a_hybrid_on_an_embedding_along_sequences(codes):
    """evaluate_map with a sequence on an embedding + codes map gives its table
    (it once fed the raw d-dim queries to the k-dim codes), and the sequence
    accuracy is that of the map's own sequence decode."""
    a, b = two_conditions(n=200, strength=4.0, seed=5)
    emb = rj.fit_invariant([a[:100], b[:100]], k=24)
    model = rj.RhythmicMap(r=2, level=1, codes=codes, embedding=emb)
    model.fit(a[100:])
    queries = b[100:]
    result = evaluate_map(model, queries, sequence=5, timing=False)
    pred = np.asarray(model.predict(queries, sequence=5))
    assert result["methods"]["map"]["accuracy"] == pytest.approx(
        np.mean(pred == np.arange(len(pred)))
    )
