"""A map's bytes by part, against the counts written out by hand."""

from __future__ import annotations

import pytest

from rhythmic_jax.map.storage import map_storage


def test_periods_templates_codes_and_embedding_by_hand():
    got = map_storage("periods", (23, 24), 1000, "float32", 500, 1000)
    assert got["per_period"] == {"23": 23 * 1001 * 4, "24": 24 * 1001 * 4}
    assert got["total"] == 188_188 and got["fixed"] == got["per_place"] == 0
    assert got["share"] == pytest.approx(188_188 / (500 * 1000 * 4))
    codes = {"fixed": 100, "per_place": 500 * 8}
    got = map_storage("periods", (23, 24), 24, "int8", 500, 48, codes, 4_000)
    templates = 47 * 25 + 4 * 47  # a byte a number, a float32 scale a template
    assert got["total"] == templates + 100 + 4_000 and got["embedding"] == 4_000
    assert got["share"] == pytest.approx((got["total"] + 4_000) / (500 * 48 * 4))


def test_groups_of_other_layouts_are_named_by_position():
    got = map_storage("mixed", (10, 9), 8, "float16", 90, 8)
    assert got["per_period"] == {"0:10": 10 * 9 * 2, "1:9": 9 * 9 * 2}
