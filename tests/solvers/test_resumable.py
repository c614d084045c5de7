"""Resumable training runs and streamed batches."""

from __future__ import annotations

import dataclasses
import json
import logging
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from rhythmic_jax.decoding.hard import hard_decode
from rhythmic_jax.errors import InputError
from rhythmic_jax.solvers.objective import Templates, scores, targets
from rhythmic_jax.solvers.optax_loops import init_state, minibatch_step, ridge_start
from rhythmic_jax.solvers.resumable import RunConfig, memmap_batches, train_run

N, D, PERIODS, C = 30, 5, (5, 7), 2.0
CONFIG = RunConfig(epochs=2, batch_size=8, learning_rate=0.05, checkpoint_every=3)
STEPS = 2 * 4  # 2 epochs of 30 rows in batches of 8, 8, 8, 6


@pytest.fixture(scope="module")
def problem(tmp_path_factory):
    """Frames (N, D), labels, their .npy file and a ridge start on a few frames."""
    rng = np.random.default_rng(0)
    x = rng.normal(size=(N, D)).astype(np.float32)
    path = tmp_path_factory.mktemp("run") / "x.npy"
    np.save(path, x)
    labels = np.arange(N)
    init = ridge_start(x[:6], targets(labels[:6], PERIODS), C)
    return x, labels, path, init


def in_memory(x, labels, fail_at: int | None = None, exc=RuntimeError, seen=None):
    """``epoch -> generator`` of the same batches as memmap_batches (rows matched
    below), optionally raising ``exc`` before the global step ``fail_at``."""

    def batches_for_epoch(epoch: int):
        order = np.random.default_rng([CONFIG.seed, epoch]).permutation(len(x))
        for i in range(0, len(x), CONFIG.batch_size):
            step = epoch * 4 + i // CONFIG.batch_size
            if seen is not None:
                seen.append(step)
            if step == fail_at:
                raise exc("stopped on purpose")
            rows = np.sort(order[i : i + CONFIG.batch_size])
            yield x[rows], targets(labels[rows], PERIODS)

    return batches_for_epoch


def predictions(params: Templates, x) -> np.ndarray:
    s = scores(params, jnp.asarray(x))
    return np.asarray(hard_decode(s, PERIODS, N).index)


def assert_same_map(a: Templates, b: Templates, x) -> None:
    np.testing.assert_allclose(np.asarray(a.w), np.asarray(b.w), rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(np.asarray(a.b), np.asarray(b.b), rtol=1e-6, atol=1e-7)
    np.testing.assert_array_equal(predictions(a, x), predictions(b, x))


def steps_saved(folder: Path) -> list[int]:
    return sorted(int(p.name) for p in folder.iterdir() if p.name.isdigit())


@pytest.fixture(scope="module")
def uninterrupted(problem):
    x, labels, _, init = problem
    return train_run(in_memory(x, labels), init, C, N, CONFIG, None, progress=False)


def test_run_equals_the_plain_optax_loop(problem, uninterrupted):
    """Reference: plain optax minibatch steps over both epochs' batches in a row."""
    x, labels, _, init = problem
    batches = [b for e in range(2) for b in in_memory(x, labels)(e)]
    optimizer = optax.adam(CONFIG.learning_rate)
    state = init_state(init, optimizer)
    for xb, yb in batches:
        xb = jnp.asarray(xb, jnp.float32)
        state, _ = minibatch_step(state, xb, jnp.asarray(yb), C, N / xb.shape[0])
    assert int(state.step) == STEPS
    assert_same_map(state.params, uninterrupted, x)
    assert not np.allclose(np.asarray(init.w), np.asarray(uninterrupted.w))


def test_two_runs_with_one_learning_rate_compile_the_step_once(problem):
    """The optimiser lives in the state and compares by its settings: a second
    run (a new optimiser object) reuses the first one's compiled step."""
    x, labels, _, init = problem
    train_run(in_memory(x, labels), init, C, N, CONFIG, None, progress=False)
    compiled = minibatch_step._cache_size()
    train_run(in_memory(x, labels), init, C, N, CONFIG, None, progress=False)
    assert minibatch_step._cache_size() == compiled


def test_batches_placed_or_not_compile_the_step_as_often(problem):
    """A batch already on the device (committed, as one handed over from torch by
    DLPack) and one from numpy run the same compiled step: each placement of the
    arguments would otherwise be a program of its own."""
    import jax

    x, labels, _, init = problem
    device = jax.devices()[0]

    def mixed(epoch):
        for i, (xb, yb) in enumerate(in_memory(x, labels)(epoch)):
            yield (jax.device_put(xb, device) if i % 2 else xb), yb

    minibatch_step.clear_cache()
    train_run(in_memory(x, labels), init, C, N, CONFIG, None, progress=False)
    from_numpy = minibatch_step._cache_size()
    minibatch_step.clear_cache()
    train_run(mixed, init, C, N, CONFIG, None, progress=False)
    assert minibatch_step._cache_size() == from_numpy == 2  # batches of 8 and of 6


@pytest.mark.parametrize("stop", [2, 4, 5, 7])  # mid-epoch, at the boundary, ...
def test_resume_after_a_stop_equals_an_uninterrupted_run(
    problem, uninterrupted, tmp_path, stop
):
    x, labels, _, init = problem
    ckpt = tmp_path / "ckpt"
    with pytest.raises(RuntimeError, match="on purpose"):
        train_run(in_memory(x, labels, stop), init, C, N, CONFIG, ckpt, False)
    assert steps_saved(ckpt)[-1] == stop  # the step reached was kept
    seen: list[int] = []
    resumed = train_run(
        in_memory(x, labels, seen=seen), init, C, N, CONFIG, ckpt, progress=False
    )
    assert_same_map(resumed, uninterrupted, x)
    assert steps_saved(ckpt)[-1] == STEPS
    assert seen == list(range(STEPS))  # skipped batches are drawn, not trained on


def test_resume_from_memmap_skips_without_reading(problem, uninterrupted, tmp_path):
    x, labels, path, init = problem
    ckpt = tmp_path / "ckpt"
    with pytest.raises(RuntimeError):
        train_run(in_memory(x, labels, 6), init, C, N, CONFIG, ckpt, False)
    batches = memmap_batches(path, labels, PERIODS, CONFIG.batch_size, CONFIG.seed)
    resumed = train_run(batches, init, C, N, CONFIG, ckpt, progress=False)
    assert_same_map(resumed, uninterrupted, x)


def test_ctrl_c_keeps_the_last_step_and_reraises(problem, uninterrupted, tmp_path):
    x, labels, _, init = problem
    ckpt = tmp_path / "ckpt"
    batches = in_memory(x, labels, 5, exc=KeyboardInterrupt)
    with pytest.raises(KeyboardInterrupt):
        train_run(batches, init, C, N, CONFIG, ckpt, progress=False)
    assert steps_saved(ckpt) == [3, 5]
    resumed = train_run(in_memory(x, labels), init, C, N, CONFIG, ckpt, False)
    assert_same_map(resumed, uninterrupted, x)


def test_a_finished_run_returns_its_checkpoint(problem, uninterrupted, tmp_path):
    x, labels, _, init = problem
    ckpt = tmp_path / "ckpt"
    train_run(in_memory(x, labels), init, C, N, CONFIG, ckpt, False)
    again = train_run(in_memory(x, labels), init, C, N, CONFIG, ckpt, False)
    assert_same_map(again, uninterrupted, x)
    assert steps_saved(ckpt) == [6, 8]


def test_checkpoint_cadence(problem, tmp_path):
    """Before step s runs, the folder holds the last two multiples of 3 below s."""
    x, labels, _, init = problem
    ckpt = tmp_path / "ckpt"
    listings: dict[int, list[int]] = {}
    plain = in_memory(x, labels)

    def batches_for_epoch(epoch):
        for i, batch in enumerate(plain(epoch)):
            listings[epoch * 4 + i] = steps_saved(ckpt) if ckpt.exists() else []
            yield batch

    train_run(batches_for_epoch, init, C, N, CONFIG, ckpt, progress=False)
    for s, saved in listings.items():
        assert saved == [k for k in (3, 6) if k <= s][-2:], (s, saved)
    assert steps_saved(ckpt) == [6, 8]  # max_to_keep=2; the end is always saved


def test_resume_refuses_other_settings_or_shapes(problem, tmp_path):
    x, labels, _, init = problem
    ckpt = tmp_path / "ckpt"
    with pytest.raises(RuntimeError):
        train_run(in_memory(x, labels, 3), init, C, N, CONFIG, ckpt, False)
    other = RunConfig(epochs=2, batch_size=8, learning_rate=0.01, checkpoint_every=3)
    with pytest.raises(InputError, match=r"written with learning_rate=0\.05, this run"):
        train_run(in_memory(x, labels), init, C, N, other, ckpt, False)
    wider = Templates(jnp.zeros((D + 1, 12)), jnp.zeros(12))
    with pytest.raises(InputError, match=r"holds templates w, b of shapes \(\(5, 12\)"):
        train_run(in_memory(x, labels), wider, C, N, CONFIG, ckpt, False)
    assert steps_saved(ckpt) == [3]  # refusals wrote nothing


def test_resume_reads_settings_saved_before_a_field_existed(
    problem, uninterrupted, tmp_path
):
    """A checkpoint whose settings lack a later field (``source``) still resumes,
    and one of another source is refused."""
    x, labels, _, init = problem
    ckpt = tmp_path / "ckpt"
    with pytest.raises(RuntimeError):
        train_run(in_memory(x, labels, 3), init, C, N, CONFIG, ckpt, False)
    meta = ckpt / "3" / "config" / "metadata"
    saved = json.loads(meta.read_text())
    assert saved.pop("source") == ""
    meta.write_text(json.dumps(saved))
    other = dataclasses.replace(CONFIG, source="augmented frames")
    with pytest.raises(InputError, match=r"written with source='', this run has "):
        train_run(in_memory(x, labels), init, C, N, other, ckpt, False)
    resumed = train_run(in_memory(x, labels), init, C, N, CONFIG, ckpt, False)
    assert_same_map(resumed, uninterrupted, x)


def test_config_and_devices_are_logged(problem, caplog):
    x, labels, _, init = problem
    with caplog.at_level(logging.INFO, logger="rhythmic_jax.solvers.resumable"):
        train_run(in_memory(x, labels), init, C, N, CONFIG, None, progress=False)
    text = caplog.text
    device = repr(jax.devices()[0])  # CpuDevice(id=0), CudaDevice(id=0), ...
    assert "RunConfig(epochs=2, batch_size=8" in text and device in text


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"epochs": 0}, r"RunConfig\.epochs must be an integer >= 1, got 0"),
        ({"checkpoint_every": 1.5}, r"checkpoint_every must be an integer"),
        ({"learning_rate": -1.0}, r"learning_rate must be positive, got -1\.0"),
        ({"seed": "a"}, r"seed must be an integer >= 0, got 'a'"),
        ({"seed": -1}, r"seed must be an integer >= 0, got -1"),
    ],
)
def test_bad_run_config(kwargs, match):
    with pytest.raises(InputError, match=match):
        RunConfig(**kwargs)


# --------------------------------------------------------------------- memmap


def test_memmap_batches_equal_in_memory_batches(problem):
    x, labels, path, _ = problem
    multi = np.concatenate([labels, labels])  # two traversals of one route
    x2 = np.concatenate([x, x[::-1] + 1.0])
    path2 = path.with_name("x2.npy")
    np.save(path2, x2.astype(np.float64))  # float64 on disk, float32 batches
    batches = memmap_batches(path2, multi, PERIODS, 7, seed=3)
    row_of = {r.tobytes(): i for i, r in enumerate(x2.astype(np.float32))}
    orders = []
    for epoch in range(3):
        epoch_batches = batches(epoch)
        assert len(epoch_batches) == 9  # ceil(60 / 7)
        rows = []
        for xb, yb in epoch_batches:
            idx = np.array([row_of[r.tobytes()] for r in xb])
            np.testing.assert_array_equal(xb, x2[idx].astype(np.float32))
            np.testing.assert_array_equal(
                np.asarray(yb), np.asarray(targets(multi[idx], PERIODS))
            )
            rows.append(idx)
        assert [len(r) for r in rows] == [7] * 8 + [4]
        assert sorted(np.concatenate(rows)) == list(range(60))  # each row once
        again = [xb for xb, _ in batches(epoch)]  # the same epoch: the same batches
        assert all(np.array_equal(a, x2[r]) for a, r in zip(again, rows, strict=True))
        orders.append(np.concatenate(rows))
    assert not np.array_equal(orders[0], orders[1])  # a new order every epoch


def test_memmap_training_equals_in_memory_training(problem, uninterrupted):
    x, labels, path, init = problem
    batches = memmap_batches(path, labels, PERIODS, CONFIG.batch_size, CONFIG.seed)
    params = train_run(batches, init, C, N, CONFIG, None, progress=False)
    assert_same_map(params, uninterrupted, x)


def test_memmap_refuses_bad_files(problem, tmp_path):
    x, labels, _, _ = problem
    bad = x.copy()
    bad[17, 2] = np.inf
    np.save(tmp_path / "inf.npy", bad)
    batches = memmap_batches(tmp_path / "inf.npy", labels, PERIODS, 8, 0)
    with pytest.raises(InputError, match=r"inf\.npy: row 17 holds NaN or inf"):
        list(batches(0))
    with pytest.raises(InputError, match=r"labels: expected shape \(30,\)"):
        memmap_batches(tmp_path / "inf.npy", labels[:-1], PERIODS, 8, 0)
    np.save(tmp_path / "cube.npy", x.reshape(3, 10, 5))
    with pytest.raises(InputError, match=r"expected a non-empty \(n, d\) real array"):
        memmap_batches(tmp_path / "cube.npy", labels, PERIODS, 8, 0)
    with pytest.raises(InputError, match="descriptor file not found"):
        memmap_batches(tmp_path / "none.npy", labels, PERIODS, 8, 0)
    with pytest.raises(InputError, match="batch_size must be an integer >= 1"):
        memmap_batches(tmp_path / "inf.npy", labels, PERIODS, 0, 0)
