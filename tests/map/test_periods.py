"""Period arithmetic against the paper's tables and brute-force loops."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rhythmic_jax.errors import InputError
from rhythmic_jax.map.periods import (
    candidate_periods,
    choose_periods,
    compression_ratio,
    crt_tables,
    database_bytes,
    nominal_periods,
    pairwise_coprime,
    period_offsets,
    phases,
    place_columns,
    storage_bytes,
)

D = 4096

# Paper Table 1 (r = 2, T = sqrt N, d = 4096, float32): N, sum tau, original bytes,
# compressed bytes, and the ratio of those bytes to 4 decimals. The paper prints
# 0.0207 for spring (the bytes give 0.0197) and 0.0246 for summer (the bytes give
# 0.02446, i.e. 0.0245).
TABLE1 = {
    "spring": (10713, 211, 175_521_792, 3_457_868, 0.0197),
    "summer": (7403, 181, 121_290_752, 2_966_228, 0.0245),
    "fall": (9267, 201, 151_830_528, 3_293_988, 0.0217),
    "winter": (7276, 179, 119_209_984, 2_933_452, 0.0246),
    "aerial": (3705, 125, 60_702_720, 2_048_500, 0.0337),
}
PRINTED_RATIO = {
    "spring": 0.0207,
    "summer": 0.0246,
    "fall": 0.0217,
    "winter": 0.0246,
    "aerial": 0.0337,
}
# Paper Table 2: chosen periods at level 1 (T = sqrt N) and level 2 (T = 2 sqrt N).
TABLE2 = {
    "spring": ((105, 106), (211, 212)),
    "summer": ((88, 93), (179, 180)),
    "fall": ((98, 103), (197, 200)),
    "winter": ((87, 92), (174, 175)),
    "aerial": ((62, 63), (122, 123)),
}


def _ceil_root(n: int, r: int) -> int:
    """Smallest t with t**r >= n by integer bisection (no floats)."""
    lo, hi = 1, n
    while lo < hi:
        mid = (lo + hi) // 2
        if mid**r >= n:
            hi = mid
        else:
            lo = mid + 1
    return lo


@pytest.mark.parametrize("name", sorted(TABLE1))
def test_table1_bytes_exactly(name):
    n, sum_tau, original, compressed, ratio = TABLE1[name]
    chosen = TABLE2[name][0]
    assert sum(chosen) == sum_tau
    assert database_bytes(n, D) == original == n * D * 4
    assert storage_bytes(chosen, D) == compressed == sum_tau * 4097 * 4
    got = compression_ratio(chosen, n, D)
    assert got == pytest.approx(compressed / original, rel=1e-12)
    assert round(got, 4) == ratio
    # every printed ratio is within rounding of the bytes but spring's
    assert abs(got - PRINTED_RATIO[name]) < (5e-3 if name == "spring" else 1.5e-4)


def test_table1_spring_ratio_is_a_misprint():
    n, _, _, _, _ = TABLE1["spring"]
    got = compression_ratio(TABLE2["spring"][0], n, D)
    assert round(got, 4) == 0.0197
    assert round(got, 4) != 0.0207
    assert abs(got - 0.0207) > 9e-4


def test_storage_with_other_itemsizes():
    assert storage_bytes((3, 4), 10, itemsize=2) == 7 * 11 * 2
    assert storage_bytes([5], 0, itemsize=8) == 5 * 1 * 8
    assert database_bytes(12, 10, itemsize=1) == 120


@pytest.mark.parametrize("name", sorted(TABLE2))
@pytest.mark.parametrize("level", [1, 2])
def test_table2_pairs_are_valid_candidates(name, level):
    n = TABLE1[name][0]
    pair = TABLE2[name][level - 1]
    cands = candidate_periods(n, 2, level)
    assert len(cands) == 7
    assert cands[0] == level * math.ceil(math.sqrt(n))
    assert set(pair) <= set(cands)
    assert math.gcd(*pair) == 1 and pairwise_coprime(pair)
    assert math.prod(pair) >= n


def test_candidates_of_summer_match_the_notes():
    assert candidate_periods(7403) == tuple(range(87, 94))
    assert candidate_periods(7403, 2, 2) == tuple(range(174, 181))


@pytest.mark.parametrize("r", [2, 3, 5])
@pytest.mark.parametrize("level", [1, 2, 3, 4])
@pytest.mark.parametrize("n", [2, 31, 1000, 1001, 3705, 7403, 10713, 99_999])
def test_candidates_for_larger_r(n, r, level):
    cands = candidate_periods(n, r, level)
    root = _ceil_root(n, r)
    assert cands == tuple(level * root + j for j in range(7))
    assert math.prod(cands[-r:]) >= n
    assert math.prod(cands[:r]) >= n * level**r  # even the shortest r suffice
    assert (root - 1) ** r < n <= root**r


def test_candidates_exact_integer_roots():
    assert candidate_periods(1000, 3)[0] == 10
    assert candidate_periods(1001, 3)[0] == 11
    assert candidate_periods(999, 3)[0] == 10
    assert candidate_periods(100, 2)[0] == 10
    assert candidate_periods(101, 2)[0] == 11
    assert candidate_periods(32, 5)[0] == 2
    assert candidate_periods(33, 5)[0] == 3
    assert candidate_periods(10, 2, 1, count=2) == (4, 5)


@given(st.integers(2, 10**6), st.integers(2, 5), st.integers(-1, 1))
@settings(max_examples=300, deadline=None)
def test_candidates_exact_near_large_powers(t, r, delta):
    # float n ** (1/r) is inexact near perfect powers; the integer root must not be
    n = t**r + delta
    assert candidate_periods(n, r)[0] == _ceil_root(n, r)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"n": 1},
        {"n": 0},
        {"n": 10.0},
        {"n": "100"},
        {"n": True},
        {"n": 100, "r": 1},
        {"n": 100, "r": 2.0},
        {"n": 100, "r": True},
        {"n": 100, "level": 0},
        {"n": 100, "level": 1.5},
        {"n": 100, "count": 1},
        {"n": 100, "r": 3, "count": 2},
        {"n": 100, "count": False},
    ],
)
def test_candidates_reject_bad_arguments(kwargs):
    with pytest.raises(InputError):
        candidate_periods(**kwargs)


def test_pairwise_coprime_against_gcd_loop():
    rng = np.random.default_rng(0)
    for _ in range(300):
        ps = [int(v) for v in rng.integers(1, 40, rng.integers(1, 5))]
        want = all(
            math.gcd(ps[i], ps[j]) == 1
            for i in range(len(ps))
            for j in range(i + 1, len(ps))
        )
        assert pairwise_coprime(ps) == want


def _choose_brute(cands, errors, n, r):
    """Reference: every r-subset, valid ones ranked by (error, storage, periods)."""
    valid = []
    for idx in itertools.combinations(range(len(cands)), r):
        combo = tuple(cands[i] for i in idx)
        ok = math.prod(combo) >= n and all(
            math.gcd(a, b) == 1 for a, b in itertools.combinations(combo, 2)
        )
        if ok:
            err = round(sum(errors[i] for i in idx), 12)
            valid.append((err, sum(combo), tuple(sorted(combo))))
    return min(valid)[2] if valid else None


def test_choose_least_error_wins_over_storage():
    # (8, 9) is cheapest but (11, 13) has the least error
    cands = [8, 9, 10, 11, 13]
    errors = [0.5, 0.5, 0.1, 0.01, 0.02]
    assert choose_periods(cands, errors, 50) == (11, 13)


def test_choose_ties_go_to_least_storage():
    cands = [13, 11, 9, 8]
    errors = [0.1, 0.1, 0.1, 0.1]
    assert choose_periods(cands, errors, 50) == (8, 9)
    # float sums that differ only by rounding are a tie: 0.1 + 0.2 vs 0.3 + 0.0.
    # Every cross pair of 6, 35, 10, 21 shares a factor: the valid sets are
    # (6, 35) (sum 41) and (10, 21) (sum 31).
    assert 0.1 + 0.2 > 0.3 + 0.0
    assert choose_periods([6, 35, 10, 21], [0.3, 0.0, 0.1, 0.2], 200) == (10, 21)
    assert choose_periods([6, 35, 10, 21], [0.3, 0.0, 0.1, 0.25], 200) == (6, 35)


def test_choose_skips_shared_factors_and_short_products():
    # (6, 7) is cheapest but 42 < 50; (6, 10) is cheaper than (7, 10) but gcd 2
    cands = [6, 7, 10, 11, 12]
    errors = [0.0, 0.0, 0.0, 0.3, 0.0]
    assert choose_periods(cands, errors, 50) == (7, 10)
    assert choose_periods(cands, errors, 71) == (7, 12)  # 70 < 71


def test_choose_r3_and_paper_errors():
    # Table 2 errors (x 1e-3) of the chosen summer periods; others made worse
    cands = candidate_periods(7403)
    err = {88: 8.91e-3, 93: 8.65e-3}
    errors = [err.get(t, 9.5e-3) for t in cands]
    assert choose_periods(cands, errors, 7403) == (88, 93)
    cands3 = candidate_periods(1000, 3)  # 10 .. 16
    got = choose_periods(cands3, [0.0] * 7, 1000, 3)
    assert got == (10, 11, 13)  # cheapest co-prime triple; (10, 11, 12) shares 2


@given(
    st.lists(st.integers(2, 40), min_size=2, max_size=8, unique=True),
    st.data(),
    st.integers(2, 3),
    st.integers(2, 2000),
)
@settings(max_examples=200, deadline=None)
def test_choose_matches_brute_force(cands, data, r, n):
    errors = data.draw(
        st.lists(
            st.sampled_from([0.0, 0.01, 0.1, 0.2, 0.3, 0.05]),
            min_size=len(cands),
            max_size=len(cands),
        )
    )
    want = _choose_brute(cands, errors, n, r)
    if want is None:
        with pytest.raises(InputError, match="co-prime"):
            choose_periods(cands, errors, n, r)
    else:
        assert choose_periods(cands, errors, n, r) == want


@pytest.mark.parametrize(
    "cands,errors,n,r",
    [
        ([4, 6, 8, 10], [0.0] * 4, 10, 2),  # all even: no co-prime pair
        ([3, 4], [0.0, 0.0], 13, 2),  # 12 < 13
        ([3, 4, 5], [0.0] * 3, 61, 3),  # 60 < 61
        ([3, 4], [0.0], 10, 2),  # length mismatch
        ([3, 4], [0.0, 0.0], 10, -1),  # negative r
        ([3, 4], [0.0, 0.0], 10, 0),
        ([3, 4], [0.0, 0.0], 10, 2.0),
        ([3, 4], [0.0, 0.0], 0, 2),
        ([3, 4], [0.0, 0.0], 10.5, 2),
        ([-3, -4], [0.0, 0.0], 10, 2),  # product 12 >= 10 but not periods
        ([3, 3, 4], [0.0, 0.1, 0.0], 10, 2),  # repeated candidate
        ([3, 4, 5], [0.0, float("nan"), 0.0], 10, 2),
        ([3, 4.5], [0.0, 0.0], 10, 2),
    ],
)
def test_choose_rejects(cands, errors, n, r):
    with pytest.raises(InputError):
        choose_periods(cands, errors, n, r)


def test_phases_against_loop():
    periods = (5, 7, 9)
    idx = np.arange(400).reshape(20, 20)
    got = phases(idx, periods)
    assert got.shape == (20, 20, 3)
    for i in range(20):
        for j in range(20):
            assert list(got[i, j]) == [int(idx[i, j]) % t for t in periods]
    assert phases(17, (3, 4)).tolist() == [2, 1]


COPRIME_SETS = [
    (2, 3),
    (3, 4),
    (5, 7),
    (8, 9),
    (11, 13),
    (1, 7),
    (7, 1),
    (87, 92),
    (2, 3, 5),
    (3, 4, 5),
    (5, 7, 9),
    (1, 4, 9),
    (7, 9, 11),
    (2, 3, 5, 7),
    (3, 4, 5, 7),
    (5, 7, 8, 9),
    (4, 1, 9, 5),
    (7,),
    (1,),
]


@pytest.mark.parametrize("periods", COPRIME_SETS)
def test_crt_tables_exhaustive(periods):
    tables, m = crt_tables(periods)
    assert m == math.prod(periods)
    assert [len(t) for t in tables] == list(periods)
    assert all(t.dtype == np.int64 and (t >= 0).all() and (t < m).all() for t in tables)
    for i in range(m):  # every index below the product, one at a time
        total = 0
        for t, table in zip(periods, tables, strict=True):
            total = (total + int(table[i % t])) % m
        assert total == i


@pytest.mark.parametrize("periods", COPRIME_SETS)
def test_crt_tables_vectorised_in_int32(periods):
    # the running sum reduced after every addition fits int32 (as decode does)
    tables, m = crt_tables(periods)
    i = np.arange(m)
    total = np.zeros(m, np.int32)
    for t, table in zip(periods, tables, strict=True):
        total = (total + table.astype(np.int32)[i % t]) % m
    np.testing.assert_array_equal(total, i)


@pytest.mark.parametrize("periods", [(2, 4), (3, 6, 5), (9, 12), (5, 7, 15), (0, 3)])
def test_crt_tables_reject_non_coprime(periods):
    with pytest.raises(InputError):
        crt_tables(periods)


def test_crt_tables_reject_empty_and_negative():
    for periods in [(), (3, -4), (-1,)]:
        with pytest.raises(InputError):
            crt_tables(periods)


@st.composite
def coprime_periods(draw):
    out: list[int] = []
    for _ in range(draw(st.integers(1, 4))):
        t = draw(
            st.integers(1, 200).filter(lambda v: all(math.gcd(v, u) == 1 for u in out))
        )
        out.append(t)
    return tuple(out)


@given(coprime_periods(), st.data())
@settings(max_examples=300, deadline=None)
def test_crt_property_any_index(periods, data):
    tables, m = crt_tables(periods)
    i = data.draw(st.integers(0, m - 1))
    got = sum(int(tab[i % t]) for t, tab in zip(periods, tables, strict=True)) % m
    assert got == i


def test_nominal_periods_are_the_least_storage_choice():
    for n, r in [(3576, 2), (7403, 2), (1000, 3), (50, 2)]:
        cands = candidate_periods(n, r, 1, 7)
        assert nominal_periods(n, r) == choose_periods(cands, [0.0] * 7, n, r)
    assert nominal_periods(3576) == (60, 61)
    with pytest.raises(InputError, match="no 3 pairwise co-prime"):
        nominal_periods(1000, 3, 1, 3)  # 10, 11, 12: 10 and 12 share 2


def test_offsets_and_place_columns():
    assert period_offsets((3, 4, 5)) == (0, 3, 7)
    cols = place_columns((3, 4), 12)
    assert cols.shape == (2, 12) and cols.dtype == np.int32
    for i in range(12):
        assert tuple(cols[:, i]) == (i % 3, 3 + i % 4)
