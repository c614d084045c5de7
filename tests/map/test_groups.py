"""Layouts of groups: labels against brute-force loops, storage, choices, specs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rhythmic_jax import InputError
from rhythmic_jax.map.groups import (
    Groups,
    choose_radices,
    choose_segment,
    fine_periods,
    parse_layout,
    resolve_layout,
)
from rhythmic_jax.map.periods import _iroot_ceil, pairwise_coprime, storage_bytes

LAYOUTS = [
    (Groups("periods", (4, 5, 7)), 140),
    (Groups("mixed", (3, 4, 5)), 60),
    (Groups("mixed", (5, 4, 5)), 83),  # product 100 > n: top digit < 5
    (Groups("mixed", (9,)), 9),
    (Groups("hierarchical", (7, 2, 3), 6), 40),
    (Groups("hierarchical", (4, 3, 4, 5), 25), 100),
]


def loop_labels(groups: Groups, i: int) -> list[int]:
    """One place's labels by the definition, digit by digit."""
    if groups.kind == "periods":
        return [i % t for t in groups.sizes]
    if groups.kind == "mixed":
        digits, rest = [], i
        for b in reversed(groups.sizes):  # least significant first
            rest, d = divmod(rest, b)
            digits.append(d)
        assert rest == 0
        return digits[::-1]
    return [i // groups.segment] + [i % t for t in groups.sizes[1:]]


@pytest.mark.parametrize(("groups", "n"), LAYOUTS)
def test_labels_match_the_definition_and_tell_every_place_apart(groups, n):
    lab = groups.labels(np.arange(n))
    assert lab.shape == (n, len(groups.sizes))
    for i in range(n):
        assert lab[i].tolist() == loop_labels(groups, i)
    assert (lab >= 0).all() and (lab < np.asarray(groups.sizes)).all()
    assert len({tuple(row) for row in lab.tolist()}) == n
    cols = groups.columns(n)
    assert cols.shape == (len(groups.sizes), n)
    np.testing.assert_array_equal(cols, (lab + np.asarray(groups.offsets)).T)
    assert groups.check(n) == n and n <= groups.capacity


def test_mixed_top_digit_is_a_contiguous_segment():
    g = Groups("mixed", (48, 50))
    top = g.labels(np.arange(2356))[:, 0]
    np.testing.assert_array_equal(top, np.arange(2356) // 50)
    assert g.capacity == 2400 and g.weights() == (50, 1)


def test_storage_is_the_hand_count():
    # (48 + 50) templates of 10,976 weights and a bias, float32
    assert storage_bytes(Groups("mixed", (48, 50)).sizes, 10976) == 98 * 10977 * 4
    g = Groups("hierarchical", (85, 6, 7), 28)
    assert g.p == 98 and storage_bytes(g.sizes, 10976) == 4_302_984


def test_choose_radices_fills_the_budget_with_the_segment_digit():
    assert choose_radices(2356, 2, 1) == (55, 43)
    assert choose_radices(2356, 2, 4) == (337, 7)
    for n, r, level in [(2356, 2, 1), (2356, 2, 2), (1000, 3, 1), (77, 2, 3)]:
        budget = r * level * _iroot_ceil(n, r)
        radices = choose_radices(n, r, level)
        assert math.prod(radices) >= n and sum(radices) <= budget
        t = radices[-1]
        # every smaller t breaks the budget (brute force)
        for s in range(2, t):
            assert -(-n // s ** (r - 1)) + (r - 1) * s > budget
        resolve_layout(parse_layout("mixed"), n, r, level)  # passes check(n)


def test_choose_segment_fills_the_budget_with_segments():
    assert choose_segment(2356, 2, 1) == 28
    for n, level in [(2356, 1), (2356, 4), (500, 2)]:
        budget = 2 * level * _iroot_ceil(n, 2)
        s = choose_segment(n, 2, level)
        assert -(-n // s) + sum(fine_periods(s, 2)) <= budget
        for t in range(2, s):
            assert -(-n // t) + sum(fine_periods(t, 2)) > budget
        g = resolve_layout(parse_layout("hierarchical"), n, 2, level)
        assert g.segment == s and g.sizes[0] == -(-n // s)


def test_fine_periods_are_coprime_and_cover_the_segment():
    for s in range(2, 200):
        fine = fine_periods(s, 2)
        assert pairwise_coprime(fine) and math.prod(fine) >= s
    assert fine_periods(50) == (8, 9)


def test_specs_parse_and_resolve():
    assert parse_layout("periods").sizes == ()
    assert resolve_layout(parse_layout("mixed:48,50"), 2356) == Groups(
        "mixed", (48, 50)
    )
    assert resolve_layout(parse_layout("hierarchical:50"), 2356) == Groups(
        "hierarchical", (48, 8, 9), 50
    )
    assert resolve_layout(parse_layout("hierarchical:50:7,9"), 2356).sizes == (48, 7, 9)
    assert resolve_layout(parse_layout("periods:49,50"), 2356).sizes == (49, 50)
    g = Groups("hierarchical", (48, 8, 9), 50)
    assert Groups.from_dict(g.to_dict()) == g


@pytest.mark.parametrize(
    ("layout", "match"),
    [
        ("fourier", "expected periods"),
        ("mixed:1,5", "radices must be >= 2"),
        ("mixed:", "not a comma-separated list"),
        ("mixed:4,x", "not a comma-separated list"),
        ("periods:4,6", "not pairwise co-prime"),
        ("hierarchical:a", "not a comma-separated list"),
        ("hierarchical:50,3", "one segment length"),
        ("hierarchical:50:2,4", "co-prime with a product"),
        ("hierarchical:50:3,4", "co-prime with a product"),
        (3, "must be a string"),
    ],
)
def test_bad_specs_say_what_in_one_line(layout, match):
    with pytest.raises(InputError, match=match) as err:
        parse_layout(layout)
    assert "\n" not in str(err.value)


def test_groups_that_cannot_label_n_places_are_refused():
    with pytest.raises(InputError, match="tells apart 2400 places"):
        Groups("mixed", (48, 50)).check(2401)
    with pytest.raises(InputError, match="use 48 of its digits"):
        Groups("mixed", (50, 50)).check(2356)
    with pytest.raises(InputError, match="segments of 50, not 50"):
        Groups("hierarchical", (50, 8, 9), 50).check(2356)
    with pytest.raises(InputError, match="layout 'periods' chooses"):
        resolve_layout(parse_layout("periods"), 100)
    with pytest.raises(InputError, match="no segment length"):
        Groups("mixed", (4, 5), 3)
    with pytest.raises(InputError, match="kind"):
        Groups("digits", (4, 5))
