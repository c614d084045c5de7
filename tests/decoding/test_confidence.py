"""A decode's confidence is finite for every decode and every kind of map, and
orders answers sensibly: where correct answers win with a margin, the surest
answers are right (recall at 100 % precision above 0, computed here in numpy
from the raw places and confidences, not by the package's metric code).

Maps: a plain periods map, its int8 and float16 copies, a level-2 map,
mixed-radix and hierarchical layouts, hybrids with int8 and ITQ codes, an
embedded map, and a map of real Nordland frames. Decodes: hard, soft, top-m
(top 1 and 3) of single frames; hard, soft and top-m of sequences (the hard
sequence decode of a map with codes once put 1.8e308 on most queries).
"""

from __future__ import annotations

import numpy as np
import pytest

import rhythmic_jax as rj
from rhythmic_jax.decoding.hard import Decoded, confidence
from rhythmic_jax.map.embedding import fit_invariant
from rhythmic_jax.map.pytree import with_dtype

N, D, NOISE, STRANGERS = 120, 64, 0.1, 20


def r_at_100p(pred, conf, gt) -> float:
    """Recall at precision 1 over queries with a true place: answers taken in
    order of confidence (ties together); the largest share of queries answered
    right while every answer taken is right."""
    pred, conf, gt = (np.asarray(a) for a in (pred, conf, gt))
    best = 0.0
    for c in np.unique(conf)[::-1]:
        taken = (conf >= c) & (pred >= 0)
        right = taken & (pred == gt)
        if right.sum() < taken.sum():
            break
        best = right.sum() / len(gt)
    return float(best)


def test_the_oracle_counts_until_the_first_confident_mistake():
    pred = np.array([0, 1, 7, 3, -1])
    conf = np.array([5.0, 4.0, 3.0, 6.0, 0.0])
    assert r_at_100p(pred, conf, np.arange(5)) == pytest.approx(3 / 5)
    assert r_at_100p(pred, np.array([1.0, 1, 9, 1, 0]), np.arange(5)) == 0.0


@pytest.fixture(scope="module")
def route():
    """Reference frames (N, D), their noisy revisits (N, D) in order (a
    traversal: the right place wins with a margin), and blends: frame i mixed
    half and half with frame i + N/2 (true place i; two places tie, so about
    half are answered wrong, by a small margin)."""
    rng = np.random.default_rng(7)
    x = rng.normal(size=(N, D)).astype(np.float32)
    q = (x + NOISE * rng.normal(size=x.shape)).astype(np.float32)
    i = np.arange(STRANGERS)
    blends = (0.5 * (x[i] + x[i + N // 2])).astype(np.float32)
    return x, q, blends


def _kinds(x):
    rng = np.random.default_rng(8)
    plain = rj.fit(x)
    emb = fit_invariant(
        [x, (x + NOISE * rng.normal(size=x.shape)).astype(np.float32)], k=32, p=64
    )
    return {
        "plain": plain,
        "int8": with_dtype(plain, "int8"),
        "float16": with_dtype(plain, "float16"),
        "level2": rj.fit(x, rj.MapConfig(level=2)),
        "mixed": rj.fit(x, rj.MapConfig(layout="mixed")),
        "hierarchical": rj.fit(x, rj.MapConfig(layout="hierarchical")),
        "codes-int8": rj.fit(x, rj.MapConfig(codes="int8")),
        "codes-itq": rj.fit(x, rj.MapConfig(codes=32)),
        "embedded": rj.fit(x, embedding=emb),
    }


@pytest.fixture(scope="module")
def maps(route):
    return _kinds(route[0])


KINDS = ("plain", "int8", "float16", "level2", "mixed", "hierarchical",
         "codes-int8", "codes-itq", "embedded")  # fmt: skip
SINGLE = (("hard", None), ("soft", None), ("topm", 1), ("topm", 3))
SEQUENCE = ("hard", "soft", "topm")


def _check(pred, conf, gt, fused=False):
    pred, conf = np.asarray(pred), np.asarray(conf)
    assert np.isfinite(conf).all(), conf[~np.isfinite(conf)][:5]
    # below 0 only where a top-m decode fused with codes kept an answer that a
    # rival one phase away outscores
    assert (conf >= 0).all() or fused
    assert (conf[pred < 0] == 0).all()  # no match: confidence 0
    assert r_at_100p(pred, conf, gt) > 0.05
    assert len(np.unique(conf[pred >= 0])) > len(pred) // 4  # not a constant


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("method,top", SINGLE)
def test_single_frame_confidence_is_finite_and_ranks_right_answers_first(
    route, maps, kind, method, top
):
    x, q, blends = route
    m = maps[kind]
    queries = np.concatenate([q, blends])
    gt = np.concatenate([np.arange(N), np.arange(STRANGERS)])
    out = rj.decode(m, queries, method, top)
    np.testing.assert_allclose(  # the one definition, whatever the decode
        np.asarray(out.confidence),
        np.asarray(confidence(*(np.asarray(f) for f in out), xp=np)),
    )
    _check(out.index, out.confidence, gt, fused=kind.startswith("codes"))
    wrong = np.asarray(out.index) != gt
    assert wrong[N:].any()  # the blends put a mistake among the answers


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("method", SEQUENCE)
def test_sequence_confidence_is_finite_and_ranks_right_answers_first(
    route, maps, kind, method
):
    _, q, blends = route
    # a traversal, then the blends: places of no speed-1 sequence
    frames = np.concatenate([q, blends])
    gt = np.concatenate([np.arange(N), np.full(STRANGERS, -5)])
    idx, conf = rj.decode_sequence(maps[kind], frames, 5, method=method, top=2)
    _check(idx, conf, gt, fused=kind.startswith("codes"))


def test_hard_sequence_with_codes_has_rivals(route, maps):
    """The hybrid's default decode (hard, fused with its codes): every answer
    measured against a rival place, so no confidence is the dtype's largest
    number, and the predict threshold keeps the surest answers."""
    _, q, _ = route
    m = maps["codes-int8"]
    idx, conf = (np.asarray(a) for a in rj.decode_sequence(m, q, 10, method="hard"))
    assert np.isfinite(conf).all() and conf.max() < 1e3
    cut = float(np.quantile(conf, 0.5))
    kept = rj.predict(m, q, "hard", sequence=10, threshold=cut)
    np.testing.assert_array_equal(kept, np.where(conf >= cut, idx, -1))
    assert (kept[kept >= 0] == np.arange(N)[kept >= 0]).all()


def test_confidence_is_finite_at_the_limits():
    """No rival (-inf) and no match give 0; a margin past float32 is its largest
    number; a NaN margin is 0: the same on the host and in a program."""
    out = Decoded(
        np.array([3, -1, 0, 2, 1], np.int32),
        np.array([2.0, -np.inf, 1.0, 3e38, np.nan], np.float32),
        np.array([1.5, -np.inf, -np.inf, -3e38, 0.0], np.float32),
    )
    want = [0.5, 0.0, 0.0, np.finfo(np.float32).max, 0.0]
    np.testing.assert_array_equal(np.asarray(out.confidence), want)
    import jax

    traced = jax.jit(lambda d: d.confidence)(out)
    np.testing.assert_array_equal(np.asarray(traced), want)


def _nordland(root, season: str, rows) -> np.ndarray:
    from PIL import Image

    files = sorted((root / season).glob("*.png"))
    frames = []
    for i in rows:
        a = np.asarray(Image.open(files[i]).convert("L"), np.float32).ravel()
        frames.append((a - a.mean()) / (a.std() + 1e-6) / np.sqrt(a.size))
    return np.stack(frames).astype(np.float32)


def test_real_nordland_frames_rank_right_answers_first(nordland_root):
    """Summer frames, every 20th of the route, as the map; the same frames with
    their brightness changed and noise added as queries, and winter frames as
    harder ones: every decode's confidence finite, the surest answers right."""
    rows = list(range(0, 3576, 20))[:150]
    x = _nordland(nordland_root, "summer", rows)
    rng = np.random.default_rng(3)
    noise = rng.normal(size=x.shape) / np.sqrt(x.shape[1])
    q = (0.8 * x + 0.4 * noise).astype(np.float32)
    winter = _nordland(nordland_root, "winter", rows)
    for codes in (None, "int8"):
        m = rj.fit(x, rj.MapConfig(codes=codes))
        both = np.concatenate([q, winter])
        gt = np.concatenate([np.arange(len(x)), np.arange(len(x))])
        for method, top in SINGLE:
            out = rj.decode(m, both, method, top)
            pred, conf = np.asarray(out.index), np.asarray(out.confidence)
            assert np.isfinite(conf).all()
            assert r_at_100p(pred, conf, gt) > 0.03, (codes, method, top)
        idx, conf = rj.decode_sequence(m, q, 5, method="hard")
        assert np.isfinite(np.asarray(conf)).all()
        assert r_at_100p(idx, conf, np.arange(len(x))) > 0.03
