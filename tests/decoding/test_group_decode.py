"""Place-domain decoding of any layout, against brute-force loops over every place."""

from __future__ import annotations

import numpy as np
import pytest

from rhythmic_jax import InputError
from rhythmic_jax.decoding.dispatch import decode_scores
from rhythmic_jax.decoding.group_decode import (
    group_hard_decode,
    group_sequence_decode,
    group_soft_decode,
    group_topm_decode,
    place_scores,
)
from rhythmic_jax.decoding.sequence import frame_offsets, sequence_decode
from rhythmic_jax.decoding.soft import calibrate, soft_decode
from rhythmic_jax.eval.report import ranked_places
from rhythmic_jax.map.groups import Groups

LAYOUTS = [
    (Groups("mixed", (5, 4, 5)), 83),
    (Groups("mixed", (7, 6)), 42),
    (Groups("hierarchical", (7, 2, 3), 6), 40),
    (Groups("hierarchical", (4, 3, 4, 5), 25), 100),
]


def random_scores(groups, b=23, seed=0):
    rng = np.random.default_rng(seed)
    return rng.normal(size=(b, groups.p)).astype(np.float32)


def loop_place_scores(s, groups, n):
    """S(i) = sum_g s[off_g + label_g(i)], one place at a time."""
    out = np.zeros((len(s), n), np.float64)
    for i in range(n):
        for off, lab in zip(groups.offsets, groups.labels(i), strict=True):
            out[:, i] += s[:, off + lab]
    return out


@pytest.mark.parametrize(("groups", "n"), LAYOUTS)
def test_place_scores_and_soft_decode_match_the_loop(groups, n):
    s = random_scores(groups)
    total = loop_place_scores(s, groups, n)
    np.testing.assert_allclose(np.asarray(place_scores(s, groups, n)), total, atol=1e-5)
    for exclude in (0, 2):
        out = group_soft_decode(s, groups, n, exclude=exclude)
        for q in range(len(s)):
            best = int(np.argmax(total[q]))
            assert int(out.index[q]) == best
            rival = np.abs(np.arange(n) - best) > exclude
            assert float(out.runner_up[q]) == pytest.approx(total[q][rival].max(), 1e-5)
    ranked = ranked_places(s, groups, n, 5)
    np.testing.assert_array_equal(ranked[:, 0], np.argmax(total, axis=1))


@pytest.mark.parametrize(("groups", "n"), LAYOUTS)
def test_topm_keeps_places_whose_labels_are_all_among_the_top_best(groups, n):
    s = random_scores(groups, seed=1)
    total = loop_place_scores(s, groups, n)
    for top in (1, 2, 3):
        out = group_topm_decode(s, groups, n, top)
        for q in range(len(s)):
            tops = [
                set(np.argsort(-s[q, o : o + t], kind="stable")[:top].tolist())
                for o, t in zip(groups.offsets, groups.sizes, strict=True)
            ]
            keep = [
                all(
                    lab in best
                    for lab, best in zip(groups.labels(i), tops, strict=True)
                )
                for i in range(n)
            ]
            keep = np.asarray(keep)
            want = (
                int(np.argmax(np.where(keep, total[q], -np.inf))) if keep.any() else -1
            )
            assert int(out.index[q]) == want
    big = group_topm_decode(s, groups, n, max(groups.sizes))
    np.testing.assert_array_equal(
        np.asarray(big.index), np.asarray(group_soft_decode(s, groups, n).index)
    )


@pytest.mark.parametrize(("groups", "n"), LAYOUTS)
def test_hard_decode_matches_the_loop(groups, n):
    s = random_scores(groups, seed=2)
    out = group_hard_decode(s, groups, n)
    for q in range(len(s)):
        blocks = [
            s[q, o : o + t] for o, t in zip(groups.offsets, groups.sizes, strict=True)
        ]
        margins = [np.sort(b)[-1] - np.sort(b)[-2] for b in blocks]
        if groups.kind == "mixed":  # the argmax digits are the index
            index = 0
            for b, t in zip(blocks, groups.sizes, strict=True):
                index = index * t + int(np.argmax(b))
            want = index if index < n else -1
            gap = min(margins)
        else:  # the argmax segment, then its best place by the fine scores
            seg = int(np.argmax(blocks[0]))
            places = [
                i
                for i in range(seg * groups.segment, (seg + 1) * groups.segment)
                if i < n
            ]
            fine = [
                sum(b[i % t] for b, t in zip(blocks[1:], groups.sizes[1:], strict=True))
                for i in places
            ]
            want = places[int(np.argmax(fine))]
            top2 = np.sort(fine)[-2:] if len(fine) > 1 else [-np.inf, fine[0]]
            gap = min(margins[0], top2[1] - top2[0])
        assert int(out.index[q]) == want
        if want >= 0:
            assert float(out.confidence[q]) == pytest.approx(gap, 1e-4)
    if groups.kind == "mixed":  # m = 1 keeps exactly the argmax digits
        np.testing.assert_array_equal(
            np.asarray(out.index), np.asarray(group_topm_decode(s, groups, n, 1).index)
        )


@pytest.mark.parametrize(("groups", "n"), LAYOUTS[::2])
def test_sequences_sum_place_scores_along_the_route(groups, n):
    frames, length = 17, 4
    s = random_scores(groups, b=frames, seed=3)
    total = loop_place_scores(s, groups, n)
    speeds = (1.0, 0.5, -1.0)
    best_score = np.full(frames, -np.inf)
    want = np.zeros(frames, int)
    for v in speeds:
        offs = frame_offsets(length, v)
        acc = np.zeros((frames, n))
        for t in range(frames):
            for step, o in enumerate(offs):
                if t - step < 0:
                    continue
                row = total[t - step]
                for i in range(n):
                    j = i - o
                    acc[t, i] += row[j] if 0 <= j < n else row.mean()
        for t in range(frames):
            if acc[t].max() > best_score[t] + 1e-9:
                best_score[t], want[t] = acc[t].max(), int(np.argmax(acc[t]))
    offsets = [frame_offsets(length, v) for v in speeds]
    idx, conf = group_sequence_decode(s, groups, n, offsets, chunk=5)
    np.testing.assert_array_equal(np.asarray(idx), want)
    assert (np.asarray(conf) >= 0).all()
    idx2, _ = sequence_decode(s, groups, n, length, speeds, "soft")
    np.testing.assert_array_equal(np.asarray(idx2), want)


def test_dispatch_and_calibration_with_groups():
    g, n = LAYOUTS[0]
    s = random_scores(g)
    for method, fn in (("soft", group_soft_decode), ("hard", group_hard_decode)):
        np.testing.assert_array_equal(
            np.asarray(decode_scores(s, g, n, method).index),
            np.asarray(fn(s, g, n).index),
        )
    cal = np.asarray(calibrate(s, g))
    for o, t in zip(g.offsets, g.sizes, strict=True):
        np.testing.assert_allclose(
            np.exp(cal[:, o : o + t]).sum(axis=1), 1.0, rtol=1e-5
        )
    per = Groups("periods", (4, 5, 7))
    sp = random_scores(per)
    np.testing.assert_array_equal(
        np.asarray(decode_scores(sp, per, 140, "soft").index),
        np.asarray(soft_decode(sp, (4, 5, 7), 140).index),
    )


def test_bad_scores_are_refused():
    g, n = LAYOUTS[0]
    with pytest.raises(InputError, match=r"shape \(\.\.\., 14\)"):
        group_soft_decode(np.zeros((3, 13), np.float32), g, n)
    with pytest.raises(InputError, match="tells apart 100 places"):
        group_soft_decode(np.zeros((3, 14), np.float32), g, 101)
    with pytest.raises(InputError, match="floating"):
        group_hard_decode(np.zeros((3, 14), np.int32), g, n)
    assert group_soft_decode(np.zeros((0, 14), np.float32), g, n).index.shape == (0,)
