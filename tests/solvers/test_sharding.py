"""The objective sharded over frames and templates equals the single-device one,
and the package's sharded fit (solvers.distributed over a frame mesh of local
devices) reaches the one-device fit."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap


def _run(code: str) -> None:
    """``code`` in a fresh process that sees four CPU devices; it prints ok."""
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=4")
    env["JAX_PLATFORMS"] = "cpu"
    out = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        capture_output=True, text=True, env=env,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().endswith("ok")


def test_sharded_objective_matches_single_device():
    """Frames on one mesh axis, templates on the other: XLA sums the frame
    blocks, and value and gradient equal the unsharded ones."""
    _run("""
        import jax, numpy as np
        from jax.sharding import Mesh, NamedSharding, PartitionSpec as P
        from rhythmic_jax.solvers.objective import Templates, targets, total_objective
        from rhythmic_jax.solvers.optax_loops import ridge_start
        assert len(jax.devices()) == 4
        rng = np.random.default_rng(0)
        x = rng.normal(size=(64, 12)).astype(np.float32)
        y = targets(np.arange(64), (5, 7, 8, 4))  # p = 24
        params = ridge_start(x, y, 1.0)
        params = params._replace(w=params.w * 0.5)
        value_and_grad = jax.jit(jax.value_and_grad(total_objective))
        ref_v, ref_g = value_and_grad(params, x, y, 1.0)
        mesh = Mesh(np.asarray(jax.devices()).reshape(2, 2), ("frames", "templates"))
        put = lambda a, *spec: jax.device_put(a, NamedSharding(mesh, P(*spec)))
        xs, ys = put(x, "frames", None), put(y, "frames", "templates")
        ps = Templates(put(params.w, None, "templates"), put(params.b, "templates"))
        v, g = value_and_grad(ps, xs, ys, 1.0)
        assert len(xs.sharding.device_set) == 4 and not xs.sharding.is_fully_replicated
        assert g.w.sharding.spec == ps.w.sharding.spec, g.w.sharding
        np.testing.assert_allclose(float(v), float(ref_v), rtol=1e-5)
        for a, b in ((g.w, ref_g.w), (g.b, ref_g.b)):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), atol=1e-4)
        print("ok")
        """)


def test_fit_over_a_frame_mesh_matches_one_device():
    """``distributed.fit_newton`` in one process over four devices (62 frames:
    blocks padded with zero rows) gives the one-device ``newton_fit``'s
    templates and training errors."""
    _run("""
        import jax, numpy as np
        from rhythmic_jax.solvers import distributed as dist
        from rhythmic_jax.solvers.newton import newton_fit
        from rhythmic_jax.solvers.objective import period_errors, scores, targets
        assert len(jax.devices()) == 4
        assert len(dist.frame_mesh().devices.ravel()) == 4
        rng = np.random.default_rng(1)
        x = rng.normal(size=(62, 10)).astype(np.float32)
        x /= np.linalg.norm(x, axis=1, keepdims=True)
        labels, periods = np.arange(62), (7, 9)
        ref, _ = newton_fit(x, targets(labels, periods), 1.0, progress=False)
        ref_err = np.asarray(period_errors(scores(ref, x), labels, periods))
        got, err, _ = dist.fit_newton(x, labels, 62, periods, 1.0, progress=False)
        np.testing.assert_allclose(got.w, np.asarray(ref.w), atol=2e-3)
        np.testing.assert_allclose(got.b, np.asarray(ref.b), atol=2e-3)
        np.testing.assert_allclose(err, ref_err, atol=1e-6)
        print("ok")
        """)
