"""Training over frames augmented on the fly; multi-exemplar maps on Nordland."""

from __future__ import annotations

import jax
import numpy as np
import pytest
import torch
from skimage import data as skdata
from skimage.transform import resize

from rhythmic_jax import RhythmicMap
from rhythmic_jax.augment.kornia_ops import AugmentConfig, augmented_batch, epoch_order
from rhythmic_jax.augment.stream import AugmentedEpoch, AugmentedFit, fit_map_augmented
from rhythmic_jax.frames.features import describe, get_descriptor
from rhythmic_jax.solvers.objective import targets


def epoch_batches(images, config, batch_size, seed, epoch):
    """Every batch of one epoch, each made on its own by ``augmented_batch``."""
    order = epoch_order(len(images), seed, epoch, True)
    count = -(-len(images) // batch_size)
    return [
        augmented_batch(images, order, config, batch_size, seed, epoch, i)
        for i in range(count)
    ]


@pytest.fixture(scope="module")
def route():
    photo = resize(skdata.coffee(), (64, 1200), anti_aliasing=True)
    frames = np.stack(
        [(photo[:, 10 * i : 10 * i + 64] * 255).astype(np.uint8) for i in range(90)]
    )
    desc = get_descriptor("patchnorm", width=32, height=32)
    return frames, describe(frames, desc, progress=False), desc


def test_epochs_hand_jax_arrays_and_fresh_augmentations(route):
    frames, clean, desc = route
    cfg = AugmentedFit(names=("contrast", "hflip"), batch_size=32, p=1.0)
    periods = (9, 10)
    first = list(AugmentedEpoch(frames, clean, np.arange(90), periods, desc, cfg, 0))
    again = list(AugmentedEpoch(frames, clean, np.arange(90), periods, desc, cfg, 0))
    other = list(AugmentedEpoch(frames, clean, np.arange(90), periods, desc, cfg, 1))
    assert all(isinstance(x, jax.Array) for x, _ in first)
    assert sum(x.shape[0] for x, _ in first) == 180  # augmented + clean exemplars
    np.testing.assert_array_equal(np.asarray(first[0][0]), np.asarray(again[0][0]))
    assert not np.allclose(np.asarray(first[0][0]), np.asarray(other[0][0]))
    assert first[0][1].shape == (32, 19)


def test_any_batch_is_made_on_its_own_as_in_the_stream(route):
    """Batch i taken alone equals the i-th of the whole epoch's stream, so a
    resumed run can skip batches without making them."""
    frames, clean, desc = route
    cfg = AugmentedFit(names=("all",), batch_size=32, seed=3)
    epoch = AugmentedEpoch(frames, clean, np.arange(90), (9, 10), desc, cfg, 2)
    stream = epoch_batches(frames, AugmentConfig(("all",)), 32, 3, 2)
    assert len(epoch) == 2 * len(stream) == 6
    for i in (2, 1):  # out of order
        idx, batch = stream[i]
        x, y = epoch[i]
        with torch.inference_mode():
            np.testing.assert_allclose(np.asarray(x), desc(batch).numpy(), atol=1e-6)
        np.testing.assert_array_equal(np.asarray(y), targets(idx, (9, 10)))
    with pytest.raises(IndexError):
        epoch[6]


def test_augmented_map_still_localises_its_route(route):
    frames, clean, desc = route
    model = RhythmicMap(descriptor="patchnorm", descriptor_settings=desc.settings())
    cfg = AugmentedFit(names=("all",), epochs=1, batch_size=45)
    fit_map_augmented(model, frames, clean, desc, cfg, progress=False)
    assert model.timings["frames"] == 180
    assert model.timings["frames_per_s"] > 0
    assert (np.abs(model.predict(clean) - np.arange(90)) <= 1).mean() >= 0.9


@pytest.mark.slow
def test_multi_exemplar_map_covers_both_seasons(nordland_patchnorm):
    """One map of summer and winter (shared phase labels) localises both seasons
    as well as each season's own map does, within 1.5 points, at level 2.

    At level 1 the 2 x 37-41 templates of 2048-d patch-normalised pixels are too
    few for two appearances of 1200 places: measured 0.868 on summer against
    0.931 for the summer-only map. At level 2: 0.960 / 0.983 against 0.968 / 0.988.
    """
    summer, winter = nordland_patchnorm
    n = 1200
    s, w = summer[:n], winter[:n]
    truth = np.arange(n)

    def acc(model, q):
        return float(np.mean(np.abs(model.predict(q, "soft") - truth) <= 1))

    both = RhythmicMap(level=2).fit(
        np.concatenate([s, w]), np.tile(truth, 2), progress=False
    )
    only_s = RhythmicMap(level=2).fit(s, progress=False)
    only_w = RhythmicMap(level=2).fit(w, progress=False)
    assert both.n == n
    assert acc(both, s) >= acc(only_s, s) - 0.015
    assert acc(both, w) >= acc(only_w, w) - 0.015
    assert acc(both, w) > acc(only_s, w) + 0.5
    assert acc(both, s) > acc(only_w, s) + 0.5


def test_in_order_batches_are_augmented_ahead_and_equal_those_made_alone(route):
    """Taking batch i starts batch i + 1's augmentation in the background; the
    stream in order equals every batch made on its own (the same draws)."""
    frames, clean, desc = route
    cfg = AugmentedFit(names=("all",), batch_size=32, seed=5)
    epoch = AugmentedEpoch(frames, clean, np.arange(90), (9, 10), desc, cfg, 1)
    stream = epoch_batches(frames, AugmentConfig(("all",)), 32, 5, 1)
    x0, _ = epoch[0]
    assert list(epoch._ahead) == [1]  # batch 1 is being made already
    got = [x0] + [epoch[i][0] for i in (1, 2)]
    assert not epoch._ahead  # nothing is made past the augmented half
    for x, (_, batch) in zip(got, stream, strict=True):
        with torch.inference_mode():
            np.testing.assert_allclose(np.asarray(x), desc(batch).numpy(), atol=1e-6)
