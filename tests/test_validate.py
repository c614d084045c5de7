"""check_features, check_labels and the number checks behind every command-line
option: what they return and each one-line refusal."""

from __future__ import annotations

import argparse
import re

import numpy as np
import pytest

from rhythmic_jax.errors import InputError
from rhythmic_jax.validate import (
    check_features,
    check_int,
    check_labels,
    check_number,
    int_option,
    is_int,
    is_number,
    number_option,
)


# --------------------------------------------------------------- check_features
@pytest.mark.parametrize("dtype", [np.float64, np.float16, np.int64, np.uint8])
def test_features_become_float32_with_same_values(dtype):
    x = (np.arange(12).reshape(3, 4) * 3).astype(dtype)
    out = check_features(x)
    assert out.dtype == np.float32 and out.shape == (3, 4)
    np.testing.assert_array_equal(out, x.astype(np.float64))


def test_features_from_nested_lists():
    out = check_features([[1, 2.5], [3, -4]])
    assert out.dtype == np.float32
    np.testing.assert_array_equal(out, [[1.0, 2.5], [3.0, -4.0]])


def test_float32_features_are_not_copied():
    x = np.random.default_rng(0).standard_normal((5, 3)).astype(np.float32)
    out = check_features(x, d=3)
    assert out is x


def test_features_not_an_array():
    with pytest.raises(InputError, match=r"^features: not an array \(.+\)$") as err:
        check_features([[1.0, 2.0], [3.0]])
    assert "\n" not in str(err.value)


@pytest.mark.parametrize(
    ("x", "dtype"),
    [
        (np.array([["a", "b"], ["c", "d"]]), "<U1"),
        (np.array([[1, None]], dtype=object), "object"),
        (np.ones((2, 2), bool), "bool"),
    ],
)
def test_features_must_be_numbers(x, dtype):
    msg = f"^frames: expected numbers, got dtype {re.escape(dtype)}$"
    with pytest.raises(InputError, match=msg):
        check_features(x, "frames")


@pytest.mark.parametrize("shape", [(4,), (2, 3, 4), ()])
def test_features_must_be_2d(shape):
    msg = re.escape(
        f"queries: expected a 2-D array (frames x features), got shape {shape}"
    )
    with pytest.raises(InputError, match=f"^{msg}$"):
        check_features(np.zeros(shape), "queries")


@pytest.mark.parametrize("shape", [(0, 4), (3, 0)])
def test_features_must_not_be_empty(shape):
    msg = re.escape(f"ref.npy: empty array of shape {shape}")
    with pytest.raises(InputError, match=f"^{msg}$"):
        check_features(np.zeros(shape, np.float32), "ref.npy")


def test_features_dimension_check():
    x = np.zeros((2, 5), np.float32)
    assert check_features(x, d=5) is x
    msg = r"^queries: 5-d features but the map was built for 4-d$"
    with pytest.raises(InputError, match=msg):
        check_features(x, "queries", d=4)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_features_nan_or_inf_rows(bad):
    x = np.ones((7, 3))
    x[2, 1] = bad
    x[5, 0] = bad
    x[5, 2] = bad  # two bad entries, one row
    msg = r"^features: 2 rows hold NaN or inf \(first: row 2\)$"
    with pytest.raises(InputError, match=msg):
        check_features(x)


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")
def test_float64_overflow_to_float32_inf_is_refused():
    x = np.ones((3, 2))
    x[1, 1] = 1e300  # finite in float64, inf in float32
    with pytest.raises(InputError, match=r"1 rows hold NaN or inf \(first: row 1\)"):
        check_features(x)


def test_dimension_checked_before_values():
    x = np.full((2, 3), np.nan)
    with pytest.raises(InputError, match="3-d features but the map was built for 2-d"):
        check_features(x, d=2)


# ----------------------------------------------------------------- check_labels
def test_labels_valid_become_int64():
    lab = np.array([2, 0, 1, 1, 0, 2], np.int32)
    out = check_labels(lab, 6)
    assert out.dtype == np.int64
    np.testing.assert_array_equal(out, lab)
    np.testing.assert_array_equal(check_labels(range(4), 4), np.arange(4))
    np.testing.assert_array_equal(check_labels([0, 0, 0], 3), [0, 0, 0])


@pytest.mark.parametrize(
    ("labels", "n", "shape"),
    [
        ([0, 1, 2], 4, "(3,)"),
        ([[0, 1], [1, 0]], 4, "(2, 2)"),
        (np.arange(5), 4, "(5,)"),
    ],
)
def test_labels_wrong_shape(labels, n, shape):
    msg = re.escape(f"labels: expected shape ({n},), got {shape}")
    with pytest.raises(InputError, match=f"^{msg}$"):
        check_labels(labels, n)


@pytest.mark.parametrize(
    ("labels", "dtype"),
    [(np.array([0.0, 1.0]), "float64"), (np.array([True, False]), "bool")],
)
def test_labels_must_be_integers(labels, dtype):
    with pytest.raises(
        InputError, match=f"^labels: expected integers, got dtype {dtype}$"
    ):
        check_labels(labels, 2)


def test_labels_must_be_non_negative():
    with pytest.raises(InputError, match=r"^labels: place labels must be >= 0$"):
        check_labels([0, 1, -1, 2], 4)


@pytest.mark.parametrize(
    ("labels", "top", "count", "first"),
    [
        ([0, 0, 2, 5], 5, 3, 1),
        ([1, 2, 3], 3, 1, 0),
        ([0, 1, 3, 3, 1], 3, 1, 2),
    ],
)
def test_labels_without_gaps(labels, top, count, first):
    msg = re.escape(
        f"labels: places must be numbered 0 .. {top} without gaps; "
        f"{count} missing (first: {first})"
    )
    with pytest.raises(InputError, match=f"^{msg}$"):
        check_labels(labels, len(labels))


def test_empty_labels_are_refused_in_one_line():
    with pytest.raises(InputError, match=r"^labels: empty; a map needs at least one"):
        check_labels(np.array([], np.int64), 0)


@pytest.mark.parametrize("value", [3, np.int64(3), np.uint8(3)])
def test_check_int_accepts_python_and_numpy_integers(value):
    got = check_int(value, "k", 1, 5)
    assert got == 3 and type(got) is int


@pytest.mark.parametrize(
    "value,integer,number",
    [
        (3, True, True),
        (np.int64(3), True, True),
        (np.uint8(3), True, True),
        (2.5, False, True),
        (np.float32(2.5), False, True),
        (True, False, False),
        (np.bool_(True), False, False),
        ("3", False, False),
        (None, False, False),
    ],
)
def test_python_and_numpy_numbers_count_and_bools_do_not(value, integer, number):
    assert is_int(value) is integer and is_number(value) is number


@pytest.mark.parametrize(
    "value,low,high,line",
    [
        (True, 0, None, "k must be an integer >= 0, got k=True"),
        (2.0, 0, None, "k must be an integer >= 0, got k=2.0"),
        ("2", None, None, "k must be an integer, got k='2'"),
        (0, 1, None, "k must be an integer >= 1, got k=0"),
        (6, 1, 5, r"k must be an integer in \[1, 5\], got k=6"),
    ],
)
def test_check_int_refuses_in_one_line(value, low, high, line):
    with pytest.raises(InputError, match=f"^{line}$"):
        check_int(value, "k", low, high)
    with pytest.raises(InputError, match="^custom$"):
        check_int(value, "k", low, high, msg="custom")


def test_check_number():
    assert check_number(np.float32(0.5), "gap", 0, 1) == 0.5
    assert check_number(-3, "threshold") == -3.0
    for bad, match in [
        (float("nan"), r"^threshold must be a finite number, got nan$"),
        (float("-inf"), r"^threshold must be a finite number, got -inf$"),
        (True, r"^threshold must be a finite number, got True$"),
        ("1", r"^threshold must be a finite number, got '1'$"),
    ]:
        with pytest.raises(InputError, match=match):
            check_number(bad, "threshold")
    with pytest.raises(InputError, match=r"^gap must be in \(0, 1\), got 1$"):
        check_number(1, "gap", 0, 1)
    with pytest.raises(InputError, match=r"^c must be > 0, got 0$"):
        check_number(0.0, "c", low=0)
    with pytest.raises(InputError, match=r"^x must be < 2, got 5$"):
        check_number(5, "x", high=2)


def test_options_parse_text_or_say_why():
    parser = argparse.ArgumentParser(exit_on_error=False)
    parser.add_argument("--n", type=int_option(1))
    parser.add_argument("--t", type=number_option())
    args = parser.parse_args(["--n", "4", "--t", "-0.5"])
    assert (args.n, args.t) == (4, -0.5)
    for argv, match in [
        (["--n", "0"], r"argument --n: must be an integer >= 1, got 0$"),
        (["--n", "-2"], r"argument --n: must be an integer >= 1, got -2$"),
        (["--n", "1.5"], r"argument --n: expected an integer, got '1\.5'$"),
        (["--t", "nan"], r"argument --t: must be a finite number, got nan$"),
        (["--t=-inf"], r"argument --t: must be a finite number, got -inf$"),
        (["--t", "x"], r"argument --t: expected a number, got 'x'$"),
    ]:
        with pytest.raises(argparse.ArgumentError, match=match):
            parser.parse_args(argv)


# -------------------------------------------------------------- check_fit_scale
def _check_scale(x, name="reference features"):
    from rhythmic_jax.validate import check_fit_scale, scale_sums

    check_fit_scale(scale_sums(x), float(np.abs(x).max()), name)


def test_scale_sums_add_over_blocks_of_rows():
    from rhythmic_jax.validate import scale_sums

    x = np.random.default_rng(0).normal(size=(9, 4))
    np.testing.assert_allclose(
        scale_sums(x[:4]) + scale_sums(x[4:]),
        np.r_[x.sum(0), (x * x).sum(), 9.0],
    )


def test_8_bit_features_are_refused_with_advice():
    x = np.random.default_rng(0).integers(0, 254, (60, 16)).astype(np.float32)
    mean = np.linalg.norm(x.astype(np.float64).mean(0))
    msg = (
        f"^ref.npy: values up to 253 \\(8-bit scale\\?\\), their mean frame "
        f"{mean:.4g} from the origin; the solvers expect features of order one: "
        "divide them by 255 or L2-normalise each row$"
    )
    with pytest.raises(InputError, match=msg):
        _check_scale(x, "ref.npy")
    _check_scale(x / 255)  # the same values scaled fit


def test_a_mean_frame_just_past_the_limit_is_refused():
    with pytest.raises(InputError, match="mean frame 4.004 from the origin"):
        _check_scale(np.full((6, 16), 1.001))


def test_a_large_offset_off_the_8_bit_range_is_told_to_scale_down():
    x = np.full((5, 4), 1000.0) + np.arange(4)
    with pytest.raises(InputError, match="up to 1003, .* scale them down or L2-"):
        _check_scale(x)


@pytest.mark.parametrize(
    ("x", "why"),
    [
        (np.full((6, 16), 0.999), "mean frame 3.996 from the origin, at the limit"),
        (np.eye(50), "L2-normalised rows"),
        (np.random.default_rng(0).normal(size=(20, 2048)), "noise: no shared offset"),
    ],
)
def test_features_a_solver_fits_pass(x, why):
    _check_scale(x)


# ------------------------------------------------------ every domain a whole range
def test_a_domain_without_a_bound_has_the_whole_range_of_its_kind():
    from rhythmic_jax.validate import FLOAT_LIMIT, INT_LIMIT, Domain

    count, number, any_number = int_option(0), number_option(0), number_option()
    assert count.limits() == (0, INT_LIMIT) and count.check(INT_LIMIT) == INT_LIMIT
    assert count.text() == "an integer in [0, 2147483647]"
    assert any_number.limits() == (-FLOAT_LIMIT, FLOAT_LIMIT)
    for domain, value, match in [
        (count, 2**63, r"^must be an integer in \[0, 2147483647\], got 92233720"),
        (count, INT_LIMIT + 1, r"in \[0, 2147483647\], got 2147483648$"),
        (count, -1, r"^must be an integer >= 0, got -1$"),  # the bound it names
        (number, 1e39, r"^must be in \(0, 1e\+38\], got 1e\+39$"),
        (number, 0.0, r"^must be > 0, got 0$"),
        (any_number, -1e300, r"^must be a finite number in \[-1e\+38, 1e\+38\]"),
        (any_number, float("inf"), r"^must be a finite number, got inf$"),
        (Domain(True, 1, words=("int8",)), 2**40, r"2147483647\] or int8, got"),
    ]:  # fmt: skip
        with pytest.raises(InputError, match=match):
            domain.check(value)
    assert number.check(1e38) == 1e38 and any_number.check(-1e38) == -1e38


@pytest.mark.parametrize("text", ["9223372036854775808", "9223372036854775807",
                                  "2147483648", "-9223372036854775809"])  # fmt: skip
def test_integers_past_the_range_are_refused_where_parsed(text):
    parser = argparse.ArgumentParser(exit_on_error=False)
    parser.add_argument("--n", type=int_option(0))
    with pytest.raises(argparse.ArgumentError, match=r"argument --n: must be an "):
        parser.parse_args(["--n", text])


def test_a_reference_of_another_length_than_the_map_is_refused():
    from rhythmic_jax.validate import check_reference

    check_reference(300, 300, "ref.npy")
    for found in (250, 350):
        with pytest.raises(InputError, match=rf"^reference ref.npy: {found} frames, "
                           r"but the map was fitted on 300; "):  # fmt: skip
            check_reference(found, 300, "ref.npy")
