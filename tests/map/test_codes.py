"""ITQ codes: faiss bit for bit, packing, similarity, storage arithmetic."""

import faiss
import numpy as np
import pytest

from rhythmic_jax.errors import InputError
from rhythmic_jax.eval.baselines import itq_storage_bytes
from rhythmic_jax.map.codes import (
    CodeBook,
    check_bits,
    code_bytes,
    code_similarity,
    fit_codes,
    pack_bits,
    unpack_bits,
)


def _data(n=400, d=48, seed=0):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, d)).astype(np.float32) @ rng.normal(size=(d, d)).astype(
        np.float32
    )
    return x / np.linalg.norm(x, axis=1, keepdims=True)


@pytest.mark.parametrize("bits", [8, 16, 24])
def test_codes_equal_faiss_itq_lsh_codes(bits):
    x = _data()
    q = _data(60, seed=1)
    itq = faiss.ITQTransform(x.shape[1], bits, True)
    lsh = faiss.IndexLSH(bits, bits, False, False)
    index = faiss.IndexPreTransform(itq, lsh)
    index.train(x)
    index.add(x)
    stored = faiss.vector_to_array(lsh.codes).reshape(len(x), -1)
    t = fit_codes(x, bits)
    assert np.array_equal(pack_bits(t.encode(x)), stored)
    # similarity = bits - Hamming distance of faiss's search
    dist, idx = index.search(q, len(x))
    sims = np.asarray(code_similarity(t.encode(q), t.encode(x)))
    mine = bits - np.take_along_axis(sims, idx, axis=1)
    assert np.array_equal(mine, dist)


def test_pack_roundtrip_and_similarity_by_hand():
    rng = np.random.default_rng(2)
    bits = rng.random((5, 13)) > 0.5
    assert np.array_equal(unpack_bits(pack_bits(bits), 13), bits)
    assert pack_bits(bits).shape == (5, 2)
    sims = np.asarray(code_similarity(bits[:2], bits))
    hand = np.array([[np.sum(a == b) for b in bits] for a in bits[:2]])
    assert np.array_equal(sims, hand)


def test_storage_by_hand():
    # 1000 places, d = 100, 64 bits: 8 B a place; mean 100 + matrix 64 x 100 floats
    got = code_bytes(1000, 100, 64)
    assert got == {"fixed": 26_000, "per_place": 8_000, "total": 34_000}
    assert code_bytes(10, 7, 9)["per_place"] == 20  # 9 bits take 2 bytes
    for n, d, b in [(2356, 10976, 64), (10**6, 256, 512)]:
        assert code_bytes(n, d, b)["total"] == itq_storage_bytes(n, d, b)


@pytest.mark.parametrize("bad", [0, -8, 49, 2.5, True, "64"])
def test_bad_bits_one_line(bad):
    with pytest.raises(InputError) as err:
        check_bits(bad, 48)
    assert "\n" not in str(err.value) and "[1, d=48]" in str(err.value)


def test_encode_traces_and_equals_the_eager_codes():
    """Under ``jax.jit`` the queries are encoded in JAX (projection and sign):
    the traced codes are the eager ones bit for bit."""
    import jax

    x = _data(200, 32)
    book = CodeBook.fit(x, 16)
    eager = book.transform.encode(x[:50])
    traced = jax.jit(lambda b, q: b.transform.encode(q))(book, x[:50])
    np.testing.assert_array_equal(np.asarray(traced), eager)
    sims = jax.jit(lambda b, q: b.similarity(q))(book, x[:50])
    np.testing.assert_array_equal(np.asarray(sims), np.asarray(book.similarity(x[:50])))


def test_book_similarity_is_faiss_hamming_and_survives_pickling():
    """The book's one-program similarity (its arrays kept on the device) is
    ``bits`` minus faiss's Hamming distance between the codes, and a pickled book
    answers the same."""
    import pickle

    x, q = _data(), _data(40, seed=3)
    book = CodeBook.fit(x, 24)
    index = faiss.IndexBinaryFlat(24)
    index.add(pack_bits(book.codes))
    dist, idx = index.search(pack_bits(book.transform.encode(q)), len(x))
    sims = np.asarray(book.similarity(q))
    assert np.array_equal(24 - np.take_along_axis(sims, idx, axis=1), dist)
    again = pickle.loads(pickle.dumps(book))
    assert np.array_equal(np.asarray(again.similarity(q.astype(np.float64))), sims)
