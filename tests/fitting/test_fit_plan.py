"""A fit's plan: what it trains, keeps and needs, from a config and a shape."""

from __future__ import annotations

import math
from dataclasses import FrozenInstanceError

import numpy as np
import pytest

from rhythmic_jax import InputError
from rhythmic_jax.fitting.fit_plan import plan
from rhythmic_jax.map.config import MapConfig
from rhythmic_jax.map.groups import Groups, parse_layout, resolve_layout
from rhythmic_jax.map.periods import (
    candidate_periods,
    choose_periods,
    nominal_periods,
    storage_bytes,
)
from rhythmic_jax.map.quantize import quantize
from rhythmic_jax.solvers.memory import check_memory
from rhythmic_jax.solvers.objective import Templates


def _planned_before(config: MapConfig, n: int) -> tuple[tuple[int, ...], float]:
    """What a map planned before its plan had a module: the candidates, the
    periods it could take (refusing an impossible r) and C."""
    cands = candidate_periods(n, config.r, config.level, config.count)
    nominal_periods(n, config.r, config.level, config.count)
    return cands, (config.c if config.c is not None else math.log(n))


@pytest.mark.parametrize(
    "n, settings",
    [(90, {}), (3576, {}), (7403, dict(level=2)), (500, dict(r=3, count=9)),
     (10_000, dict(r=3, level=2, c=0.5)), (2, {}), (37, dict(count=4))],
)  # fmt: skip
def test_plan_matches_what_a_map_planned_before(n, settings):
    config = MapConfig(**settings)
    got = plan(config, n, 64)
    cands, c = _planned_before(config, n)
    assert (got.candidates, got.c, got.groups) == (cands, c, None)
    assert got.trained == got.periods == cands and got.p == sum(cands)
    assert got.largest_bytes == storage_bytes(sorted(cands)[-config.r :], 64)
    with pytest.raises(FrozenInstanceError):
        got.c = 1.0


@pytest.mark.parametrize(
    "layout", ["periods:11,13", "mixed", "mixed:10,12", "hierarchical:20"]
)
def test_a_layout_of_fixed_groups_plans_them(layout):
    got = plan(MapConfig(layout=layout), 120, 16)
    want = resolve_layout(parse_layout(layout), 120, 2, 1)
    assert got.groups == want and got.trained is got.groups
    assert got.candidates == () and got.periods == want.sizes
    assert got.largest_bytes == storage_bytes(want.sizes, 16)


def test_plan_refuses_what_the_fit_refused_before():
    with pytest.raises(InputError) as before:
        _planned_before(MapConfig(r=1), 100)
    with pytest.raises(InputError) as now:
        plan(MapConfig(r=1), 100, 8)
    assert str(now.value) == str(before.value)
    with pytest.raises(InputError, match=r"codes 9: at most d=8 bits \(a number"):
        plan(MapConfig(codes=9), 100, 8)
    with pytest.raises(InputError, match="codes fuse with the place scores"):
        plan(MapConfig(codes="int8", layout="mixed"), 100, 8)
    assert plan(MapConfig(codes="int8"), 100, 8).candidates  # int8: any d


def test_the_memory_check_is_the_solvers_for_the_plan():
    got = plan(MapConfig(), 100, 32)
    assert got.check_memory(100) == check_memory(100, 32, got.p)
    with pytest.raises(InputError, match="stream the frames instead"):
        plan(MapConfig(), 10**7, 4096).check_memory(10**7)


def test_keep_takes_the_periods_of_least_error_and_their_columns():
    got = plan(MapConfig(dtype="int8"), 90, 5)
    rng = np.random.default_rng(0)
    w = rng.standard_normal((5, got.p)).astype(np.float32)
    params = Templates(w, rng.standard_normal(got.p).astype(np.float32))
    errors = np.linspace(0.5, 0.1, len(got.candidates))
    kept = got.keep(params, errors, "int8")
    chosen = choose_periods(got.candidates, errors, 90, 2)
    assert kept.periods == chosen and kept.groups == Groups("periods", chosen)
    starts = np.cumsum((0,) + got.candidates[:-1])
    offset = dict(zip(got.candidates, starts, strict=True))
    cols = np.concatenate([np.arange(offset[t], offset[t] + t) for t in chosen])
    want = quantize(w[:, cols], params.b[cols], "int8")
    for name in want:
        np.testing.assert_array_equal(kept.stored[name], want[name])
    assert kept.candidate_errors == tuple(errors)
    assert kept.group_errors == tuple(errors[got.candidates.index(t)] for t in chosen)
    fixed = plan(MapConfig(layout="mixed:10,9"), 90, 5)
    params = Templates(np.ones((5, fixed.p), np.float32), np.zeros(fixed.p, np.float32))
    kept = fixed.keep(params, [0.2, 0.3], "float32")
    assert kept.groups is fixed.groups and kept.periods == ()
    assert kept.candidates == kept.candidate_errors == ()
    assert kept.group_errors == (0.2, 0.3) and kept.stored["w"].shape == (5, 19)
