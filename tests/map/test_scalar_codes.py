"""8-bit scalar codes: faiss's QT_8bit codec, cosine search, storage, disk form."""

import numpy as np
import pytest

from rhythmic_jax.errors import InputError
from rhythmic_jax.map.codes import check_codes, codebook_from_arrays, fit_codebook
from rhythmic_jax.map.scalar_codes import ScalarCodeBook, scalar_code_bytes


def _frames(n=300, d=24, seed=0):
    rng = np.random.default_rng(seed)
    return (rng.normal(size=(n, d)) * rng.uniform(0.1, 3.0, d)).astype(np.float32)


def test_codes_and_decode_equal_faiss_qt_8bit():
    faiss = pytest.importorskip("faiss")
    x = _frames()
    book = ScalarCodeBook.fit(x)
    sq = faiss.ScalarQuantizer(x.shape[1], faiss.ScalarQuantizer.QT_8bit)
    sq.train(x)
    codes = sq.compute_codes(x)
    assert np.array_equal(codes, book.codes)
    np.testing.assert_allclose(book.decode(), sq.decode(codes), rtol=0, atol=1e-5)


def test_range_from_other_frames_clips_outside_values():
    x, other = _frames(seed=1), _frames(seed=2) * 0.5
    book = ScalarCodeBook.fit(x, fit_on=other)
    np.testing.assert_array_equal(book.vmin, other.min(0))
    lo, hi = x < other.min(0), x > other.max(0)
    assert lo.any() and hi.any()
    assert (book.codes[lo] == 0).all() and (book.codes[hi] == 255).all()


def test_similarity_is_the_cosine_of_the_decoded_frames():
    x = _frames()
    q = x[:40] + 0.3 * _frames(n=40, seed=5)
    book = ScalarCodeBook.fit(x)
    ref = book.decode()
    want = (q / np.linalg.norm(q, axis=1, keepdims=True)) @ (
        ref / np.linalg.norm(ref, axis=1, keepdims=True)
    ).T
    np.testing.assert_allclose(np.asarray(book.similarity(q)), want, atol=1e-5)
    # a byte per dimension keeps the ranking of the float frames here
    exact = (q @ (x / np.linalg.norm(x, axis=1, keepdims=True)).T).argmax(1)
    assert np.mean(np.asarray(book.similarity(q)).argmax(1) == exact) > 0.95


def test_constant_dimension_and_storage():
    x = _frames(n=50, d=6)
    x[:, 2] = 1.5
    book = ScalarCodeBook.fit(x)
    assert book.vdiff[2] == 1.0 and np.all(book.codes[:, 2] == 0)
    assert book.storage() == scalar_code_bytes(50, 6)
    assert book.storage() == {"fixed": 48, "per_place": 300, "total": 348}
    assert book.bits == 48


def test_arrays_round_trip_and_shape_errors():
    x = _frames(n=30, d=8)
    book = fit_codebook(x, "int8")
    assert isinstance(book, ScalarCodeBook)
    back = codebook_from_arrays(book.arrays(), 30, 8, "int8")
    assert np.array_equal(back.codes, book.codes)
    with pytest.raises(InputError, match="do not fit"):
        codebook_from_arrays(book.arrays(), 31, 8, "int8")
    bad = dict(book.arrays(), codes_uint8=book.codes.astype(np.int16))
    with pytest.raises(InputError, match="uint8"):
        codebook_from_arrays(bad, 30, 8, "int8")


@pytest.mark.parametrize("codes", ["int4", True, 0, -2, 2.5, None])
def test_check_codes_refuses_in_one_line(codes):
    with pytest.raises(InputError) as err:
        check_codes(codes)
    assert "\n" not in str(err.value) and "int8" in str(err.value)


def test_check_codes_accepts_bits_and_int8():
    assert check_codes("int8") == "int8" and check_codes(np.int64(12), 24) == 12
    with pytest.raises(InputError, match="at most|\\[1, d=24\\]"):
        check_codes(25, 24)
