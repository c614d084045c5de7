"""The streamed Newton-CG solver against the in-memory one."""

import numpy as np

from rhythmic_jax.io.frame_files import ShardWriter, open_frames
from rhythmic_jax.objective import period_errors, scores, targets
from rhythmic_jax.solvers.newton import newton_fit
from rhythmic_jax.solvers.streamed import (
    StreamConfig,
    stream_errors,
    streamed_newton_fit,
)


def test_streamed_fit_reaches_the_in_memory_optimum(tmp_path):
    rng = np.random.default_rng(0)
    n, d = 300, 16
    x = np.cumsum(rng.normal(size=(n, d)), axis=0).astype(np.float32)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    with ShardWriter(tmp_path / "s", rows=110) as w:
        w.write(x)
    frames = open_frames(tmp_path / "s")
    periods, c = (18, 19, 20), float(np.log(n))
    ref, ref_info = newton_fit(x, targets(np.arange(n), periods), c, progress=False)
    got, info = streamed_newton_fit(
        frames, np.arange(n), periods, c, StreamConfig(block_rows=96), progress=False
    )
    assert len(info.pass_seconds) > info.steps  # gradient, CG and line passes
    rel = np.abs(info.objective - ref_info.objective) / ref_info.objective
    assert rel.max() < 1e-6
    w_ref = np.asarray(ref.w)
    assert np.linalg.norm(got.w - w_ref) / np.linalg.norm(w_ref) < 3e-3
    want = np.asarray(period_errors(scores(ref, x), np.arange(n), periods))
    errors = stream_errors(frames, np.arange(n), periods, got, block_rows=96)
    np.testing.assert_allclose(errors, want, atol=1.5 / n)
