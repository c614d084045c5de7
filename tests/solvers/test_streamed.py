"""The streamed Newton-CG solver against the in-memory one."""

import json
import os
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optax

from rhythmic_jax.io.frame_files import ShardWriter, open_frames
from rhythmic_jax.solvers import newton_cg as newton_cg_module
from rhythmic_jax.solvers import passes, streamed
from rhythmic_jax.solvers.newton import newton_fit
from rhythmic_jax.solvers.newton_cg import (
    Iterate,
    newton_cg,
    newton_solver,
    scale_by_exact_linesearch,
)
from rhythmic_jax.solvers.objective import (
    margin_objectives,
    period_errors,
    scores,
    targets,
)
from rhythmic_jax.solvers.passes import Passes
from rhythmic_jax.solvers.precondition import spectral_setup
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
    # the basis, every step's gradient, CG and line passes, the final gradient
    steps = zip(info.cg_iterations, info.line_passes, strict=True)
    assert len(info.pass_seconds) == 2 + sum(1 + cg + line for cg, line in steps)
    assert all(line >= 1 for line in info.line_passes)
    rel = np.abs(info.objective - ref_info.objective) / ref_info.objective
    assert rel.max() < 1e-6
    w_ref = np.asarray(ref.w)
    assert np.linalg.norm(got.w - w_ref) / np.linalg.norm(w_ref) < 3e-3
    want = np.asarray(period_errors(scores(ref, x), np.arange(n), periods))
    errors = stream_errors(frames, np.arange(n), periods, got, block_rows=96)
    np.testing.assert_allclose(errors, want, atol=1.5 / n)


def _small_stream(tmp_path, seed, n=50, d=6, periods=(4, 5)):
    """Unit rows (n, d) written to shards of 20 and their passes in blocks of 7:
    ``(x, passes, xa (n, d + 1) float64, y (n, p) float64)``."""
    x = np.random.default_rng(seed).normal(size=(n, d)).astype(np.float32)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    with ShardWriter(tmp_path / "s", rows=20) as w:
        w.write(x)
    stream = Passes(
        open_frames(tmp_path / "s"), 0, n, np.arange(n, dtype=np.int32),
        periods, 7, lambda tree: tree,
    )  # fmt: skip
    xa = np.hstack([x, np.ones((n, 1), np.float32)]).astype(np.float64)
    return x, stream, xa, np.asarray(targets(np.arange(n), periods), np.float64)


def _streamed_system(stream, theta, c, vecs=None):
    """The streamed fit's :class:`NewtonSystem` at theta (q, p) float64."""
    th32 = np.asarray(theta, np.float32)
    loss, gx, curv = stream.gradient(th32, c, vecs)
    reg, reg_grad, reg_diag = streamed._regulariser_terms(np.asarray(theta), c)
    system = streamed._system(
        stream, th32, reg + loss, reg_grad + gx, curv, c, (reg_grad, reg_diag),
        vecs=vecs,
    )  # fmt: skip
    return system, reg + loss


def test_streamed_passes_are_the_objectives_derivatives_summed_over_blocks(tmp_path):
    """What the streamed solver hands newton_cg (the objective, its gradient and
    Hessian products summed over blocks, padding included) is autodiff of the
    one objective over all frames; its line search lands on the exact
    per-template minimiser along the step (the in-memory optax search's)."""
    rng = np.random.default_rng(1)
    n, d, periods, c = 50, 6, (4, 5), 2.5
    x, stream, xa, y = _small_stream(tmp_path, 1, n, d, periods)
    with jax.enable_x64(True):
        theta = jnp.asarray(rng.normal(size=(d + 1, sum(periods))) * 0.5)

        def f(th):
            return margin_objectives(th, jnp.asarray(xa) @ th, jnp.asarray(y), c)

        grad_ref = jax.grad(lambda th: jnp.sum(f(th)))(theta)
        system, value = _streamed_system(stream, theta, c)
        np.testing.assert_allclose(value, f(theta), rtol=1e-6)
        grad = system.grad
        np.testing.assert_allclose(grad, grad_ref, rtol=1e-4, atol=1e-4)
        v = rng.normal(size=theta.shape)
        hv, margins = system.hvp(v)
        assert margins is None  # nothing of size n is kept
        hv_ref = jax.jvp(
            jax.grad(lambda th: jnp.sum(f(th))), (theta,), (jnp.asarray(v),)
        )[1]
        np.testing.assert_allclose(hv, hv_ref, rtol=1e-4, atol=1e-4)
        # the Newton step at theta, then the search along it
        th, g64 = np.asarray(theta), np.asarray(grad_ref)
        s = np.empty_like(th)
        for j in range(th.shape[1]):
            active = (y[:, j] * (xa @ th[:, j]) < 1)[:, None]
            hessian = np.eye(d + 1) + 2 * c * xa.T @ (active * xa)
            s[:, j] = np.linalg.solve(hessian, -g64[:, j])
        # newton_cg's CG on the streamed system, on the host, converges to it
        it = Iterate(th, None)
        opt = newton_cg(eta=1e-8, max_cg=200)
        cg, state = opt.update(Iterate(grad, None), opt.init(it), it, system=system)
        assert isinstance(cg.theta, np.ndarray) and cg.margins is None
        assert 0 < int(state.cg_iterations) < 200
        np.testing.assert_allclose(cg.theta, s, rtol=1e-3, atol=1e-4)
        search = scale_by_exact_linesearch()
        _, found = search.update(Iterate(s, None), search.init(it), it, system=system)
        t = found.step_size[0]
        s = jnp.asarray(s)
        it = Iterate(theta, jnp.asarray(xa) @ theta)
        step = Iterate(s, jnp.asarray(xa) @ s)

        def value_fn(p):
            return margin_objectives(p.theta, p.margins, jnp.asarray(y), c)

        _, exact = search.update(step, search.init(it), it, value_fn=value_fn)
        # the same search on float32 margins: to their rounding
        np.testing.assert_allclose(t, exact.step_size[0], rtol=1e-5)
        end = theta + jnp.asarray(t)[None, :] * s
        reached = value_fn(Iterate(end, jnp.asarray(xa) @ end))
        np.testing.assert_allclose(reached, exact.new_value, rtol=1e-5)
        np.testing.assert_allclose(found.new_value, exact.new_value, rtol=1e-5)
        assert not np.allclose(t, 1.0, rtol=1e-3)  # the search moved the step


def test_a_streamed_step_is_newton_solvers_step_in_memory(tmp_path):
    """One Newton step (CG to a tight tolerance, then the exact per-template
    search) of ``newton_solver`` on the streamed system, run on the host, is the
    same transformation's step on the in-memory system of the same frames
    (float64 design): the same step, step sizes, values and decrements, to the
    float32 rounding of the streamed products."""
    rng = np.random.default_rng(7)
    n, d, periods, c = 50, 6, (4, 5), 2.5
    x, stream, xa, y = _small_stream(tmp_path, 7, n, d, periods)
    with jax.enable_x64(True):
        theta = rng.normal(size=(d + 1, sum(periods))) * 0.5
        opt = newton_solver(eta=1e-10, max_cg=100)
        design = jnp.asarray(xa)
        spectral = spectral_setup(design, d + 1, 1, jax.random.PRNGKey(0))
        it = Iterate(jnp.asarray(theta), design @ theta)

        def value_fn(p):
            return margin_objectives(p.theta, p.margins, jnp.asarray(y), c)

        grad = jax.grad(lambda p: jnp.sum(value_fn(p)))(it)
        want, (cg_want, search_want) = opt.update(
            grad, opt.init(it), it, value_fn=value_fn, design=design,
            spectral=spectral,
        )  # fmt: skip
        vecs = np.linalg.eigh(xa.T @ xa)[1][:, ::-1].astype(np.float32)
        system, _ = _streamed_system(stream, theta, c, vecs)
        host = Iterate(theta, None)
        got, (cg, search) = opt.update(
            Iterate(system.grad, None), opt.init(host), host, system=system
        )
        want, cg_want, search_want = jax.tree.map(
            np.asarray, (want, cg_want, search_want)
        )
    assert isinstance(got.theta, np.ndarray) and got.margins is None
    assert int(cg.cg_iterations) > 1  # a diagonal preconditioner, not exact
    scale = np.linalg.norm(want.theta, axis=0)
    err = np.linalg.norm(got.theta - want.theta, axis=0)
    assert np.all(err <= 1e-5 * scale), (err / scale).max()
    np.testing.assert_allclose(search.step_size, search_want.step_size, rtol=1e-5)
    assert not np.allclose(search.step_size, 1.0, rtol=1e-3)
    np.testing.assert_allclose(search.value, search_want.value, rtol=1e-6)
    np.testing.assert_allclose(search.new_value, search_want.new_value, rtol=1e-6)
    np.testing.assert_allclose(cg.decrement, cg_want.decrement, rtol=1e-5)


def test_the_streamed_fit_steps_by_newton_solver_on_the_host(tmp_path, monkeypatch):
    """Every Newton step of a streamed fit is one ``newton_solver`` update on the
    streamed system, its CG and its line search each run by ``host_loop``."""
    calls = {"update": 0, "loop": 0}

    def solver(*args, **kwargs):
        real = newton_cg_module.newton_solver(*args, **kwargs)

        def update(*a, system, **kw):
            assert system.loop is counted and system.line is not None
            calls["update"] += 1
            return real.update(*a, system=system, **kw)

        return optax.GradientTransformationExtraArgs(real.init, update)

    def counted(cond, body, init):
        calls["loop"] += 1
        return newton_cg_module.host_loop(cond, body, init)

    monkeypatch.setattr(streamed, "newton_solver", solver)
    monkeypatch.setattr(streamed, "host_loop", counted)
    frames = _route_file(tmp_path, seed=8, n=120, d=8)
    _, info = _fits(frames, (9, 10), [StreamConfig(block_rows=50)])[0]
    assert info.steps > 1
    assert calls == {"update": info.steps, "loop": 2 * info.steps}


def _route_file(tmp_path, seed: int, n: int, d: int):
    """A random-walk route of n unit rows (n, d) float32 in one ``.npy``, opened."""
    rng = np.random.default_rng(seed)
    x = np.cumsum(rng.normal(size=(n, d)), axis=0).astype(np.float32)
    np.save(tmp_path / "x.npy", x / np.linalg.norm(x, axis=1, keepdims=True))
    return open_frames(tmp_path / "x.npy")


def _fits(frames, periods, configs):
    """The streamed fit of frames' n places with each of ``configs``, C = log n:
    a list of (templates, info)."""
    n = frames.n
    return [
        streamed_newton_fit(
            frames, np.arange(n), periods, float(np.log(n)), config, progress=False
        )
        for config in configs
    ]


def _same_optimum(ref, got):
    """Two fits' (templates, info) reach the same objectives (1e-6) and, as far as
    the objective pins them near its optimum, the same templates."""
    (ref, ref_info), (got, info) = ref, got
    np.testing.assert_allclose(info.objective, ref_info.objective, rtol=1e-6)
    # the sums round differently; w is as flat as the objective near its optimum
    assert np.linalg.norm(got.w - ref.w) / np.linalg.norm(ref.w) < 3e-3


def test_a_stopped_streamed_fit_resumes_from_its_checkpoint(tmp_path):
    n = 200
    frames = _route_file(tmp_path, seed=1, n=n, d=12)
    periods, c, ckpt = (14, 15), float(np.log(n)), tmp_path / "state.npz"
    config = StreamConfig(block_rows=64)
    whole, whole_info = streamed_newton_fit(
        frames, np.arange(n), periods, c, config, progress=False
    )
    assert whole_info.steps > 2
    from dataclasses import replace

    streamed_newton_fit(frames, np.arange(n), periods, c,
                        replace(config, max_iter=2), progress=False,
                        checkpoint=ckpt)  # fmt: skip
    assert ckpt.is_file()
    got, info = streamed_newton_fit(
        frames, np.arange(n), periods, c, config, progress=False, checkpoint=ckpt
    )
    assert info.steps == whole_info.steps
    assert info.cg_iterations == whole_info.cg_iterations
    assert info.line_passes == whole_info.line_passes
    np.testing.assert_allclose(info.objective, whole_info.objective, rtol=1e-9)
    np.testing.assert_allclose(got.w, whole.w, rtol=1e-5, atol=1e-7)
    # a checkpoint of other settings is not taken up
    other, other_info = streamed_newton_fit(
        frames, np.arange(n), periods, 2 * c, config, progress=False, checkpoint=ckpt
    )
    assert other_info.cg_iterations[:2] != info.cg_iterations[:2] or not np.allclose(
        other.w, got.w
    )


def test_kept_active_sets_take_the_same_steps(tmp_path):
    n = 150
    frames = _route_file(tmp_path, seed=2, n=n, d=10)
    configs = [StreamConfig(block_rows=40, keep_active=keep) for keep in (False, True)]
    ref, got = _fits(frames, (11, 13, 14), configs)
    assert got[1].cg_iterations == ref[1].cg_iterations
    _same_optimum(ref, got)


def test_line_pass_is_the_loss_along_the_step_differentiated_in_t():
    rng = np.random.default_rng(5)
    rows, q, periods, c = 40, 9, (3, 4), 2.0
    xa = jnp.asarray(rng.normal(size=(rows, q)).astype(np.float32))
    labels = jnp.asarray(np.r_[np.arange(36), -np.ones(4)].astype(np.int32))  # padding
    theta = jnp.asarray(rng.normal(size=(q, 7)).astype(np.float32) * 0.3)
    step = jnp.asarray(rng.normal(size=(q, 7)).astype(np.float32) * 0.3)

    def phi(t):  # (p,) -> (p,): the block's loss at theta + t step, per template
        # the pass's own precision: the backend's default (TF32 on a GPU) is not
        m = jnp.matmul(
            xa, theta + t[None, :] * step, precision=jax.lax.Precision.HIGHEST
        )
        return passes._block_loss(m, labels, periods, c)

    ones = jnp.ones(7, jnp.float32)

    def dphi(t):
        return jax.jvp(phi, (t,), (ones,))[1]

    for value in (0.0, 0.5, 2.0):
        t = jnp.full((1, 7), value, jnp.float32)
        change, slope, curv = passes._line_pass(xa, labels, theta, step, t, c, periods)
        d1 = dphi(t[0])
        d2 = jax.jvp(dphi, (t[0],), (ones,))[1]
        np.testing.assert_allclose(change[0], phi(t[0]) - phi(0 * ones), atol=1e-4)
        np.testing.assert_allclose(slope[0], d1, rtol=1e-4, atol=1e-4)
        np.testing.assert_allclose(curv[0], d2, rtol=1e-4, atol=1e-4)


def test_compacted_passes_take_the_same_steps_on_fewer_columns(tmp_path):
    """Once some templates stop, the passes carry only the others (padded to a
    power of two): the same steps and optimum as passes over every column."""
    n = 240
    frames = _route_file(tmp_path, seed=3, n=n, d=14)
    configs = [
        StreamConfig(gap_tol=1e-5, block_rows=64, compact=compact)
        for compact in (False, True)
    ]
    ref, got = _fits(frames, (15, 16, 17), configs)
    ref_info, info = ref[1], got[1]
    assert set(ref_info.columns) == {48}
    assert info.columns[0] == 48 and min(info.columns) < 48  # compacted
    assert all(w in (8, 16, 32, 48) for w in info.columns)
    assert info.steps == ref_info.steps
    assert info.cg_iterations == ref_info.cg_iterations
    _same_optimum(ref, got)  # float32 products of other widths round differently


def test_spectral_preconditioning_reaches_the_optimum_in_fewer_cg_passes(tmp_path):
    n = 300
    frames = _route_file(tmp_path, seed=4, n=n, d=24)
    periods, c = (17, 18), float(np.log(n))
    x = frames.read(0, n)
    _, ref = newton_fit(x, targets(np.arange(n), periods), c, progress=False)
    configs = [
        StreamConfig(gap_tol=1e-6, block_rows=128, spectral_rank=rank)
        for rank in (0, 8)
    ]
    (_, jacobi), (_, spectral) = _fits(frames, periods, configs)
    for info in (jacobi, spectral):
        rel = np.abs(info.objective - ref.objective) / ref.objective
        assert rel.max() < 1e-5
        assert np.all(info.gap_estimate <= 1e-6)
    assert sum(spectral.cg_iterations) < sum(jacobi.cg_iterations)


_COUNT = r"""
import collections, json, sys
import jax
jax.config.update("jax_enable_compilation_cache", False)
import numpy as np
from rhythmic_jax.io.frame_files import open_frames
from rhythmic_jax.solvers.streamed import StreamConfig, streamed_newton_fit
names = collections.Counter()
def listen(event, duration, **kw):
    if event == "/jax/core/compile/backend_compile_duration":
        names["programs"] += 1
jax.monitoring.register_event_duration_secs_listener(listen)
frames = open_frames(sys.argv[1])
n = frames.n
_, info = streamed_newton_fit(frames, np.arange(n), (15, 16, 17), float(np.log(n)),
                              StreamConfig(gap_tol=1e-5, block_rows=64), progress=False)
print("RESULT " + json.dumps(dict(programs=names["programs"], columns=info.columns)))
"""


def test_a_streamed_fit_compiles_a_few_programs_whatever_columns_it_carries(tmp_path):
    """In a fresh process a compacted streamed fit compiles its pass kernels for
    two widths and one regulariser program, no eager op: 9 programs (165 when
    CG ran as eager jnp ops and every power of two compiled)."""
    _route_file(tmp_path, seed=3, n=240, d=14)
    env = dict(os.environ, JAX_PLATFORMS="cpu", TF_CPP_MIN_LOG_LEVEL="3")
    env["PYTHONPATH"] = os.pathsep.join(
        [str(Path(streamed.__file__).parents[2]), env.get("PYTHONPATH", "")]
    )
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    proc = subprocess.run(
        [sys.executable, "-c", _COUNT, str(tmp_path / "x.npy")],
        env=env, capture_output=True, text=True, check=False, cwd=tmp_path,
    )  # fmt: skip
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    assert lines, proc.stderr[-2000:]
    got = json.loads(lines[-1][len("RESULT ") :])
    assert min(got["columns"]) < max(got["columns"])  # it compacted
    # gram, grad, kept Hessian and line kernels (x2 widths), final grad, regulariser
    assert got["programs"] <= 9
