"""What the command line prints of a map: its bytes with the embedding's, its
descriptor, and a fusion weight in words."""

from __future__ import annotations

import numpy as np

from rhythmic_jax import RhythmicMap
from rhythmic_jax.app import render
from rhythmic_jax.fitting.learn import LearnConfig, learn_embedding


def test_a_maps_lines_count_its_embedding_and_name_its_fusion():
    rng = np.random.default_rng(0)
    x = np.cumsum(rng.normal(size=(80, 24)), axis=0).astype(np.float32)
    x -= x.mean(axis=0)
    emb, _ = learn_embedding([x, x + rng.normal(size=x.shape).astype(np.float32)],
                             LearnConfig(method="pca", k=8))  # fmt: skip
    model = RhythmicMap(codes=8, fusion=0.0, embedding=emb).fit(x)
    info = model.info()
    line = render.fit_summary("m.map", info)
    total = model.storage_bytes + model.embedding_bytes
    parts = f"{model.storage_bytes:,} B + embedding {model.embedding_bytes:,} B"
    assert f"storage={parts}" in line
    assert f"{total / (80 * 24 * 4):.4f}" in line and "the embedding counted" in line
    text = render.info_lines(info)
    assert "descriptor: features" in text
    assert "fusion: 0 (the codes alone)" in text
    assert render.fusion_words(1.0) == "1 (the map's templates alone)"
    assert render.fusion_words(0.35) == "0.35"
