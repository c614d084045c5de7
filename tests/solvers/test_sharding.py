"""The objective sharded over frames and templates equals the single-device one."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap


def test_sharded_objective_matches_single_device():
    code = textwrap.dedent(
        """
        import jax, numpy as np
        from rhythmic_jax.solvers.objective import targets
        from rhythmic_jax.solvers.sharding import make_mesh, shard_problem
        from rhythmic_jax.solvers.sharding import sharded_value_and_grad
        from rhythmic_jax.solvers.optax_loops import ridge_start
        assert len(jax.devices()) == 4
        rng = np.random.default_rng(0)
        x = rng.normal(size=(64, 12)).astype(np.float32)
        y = targets(np.arange(64), (5, 7, 8, 4))  # p = 24
        params = ridge_start(x, y, 1.0)
        params = params._replace(w=params.w * 0.5)
        ref_v, ref_g = sharded_value_and_grad(params, x, y, 1.0)
        mesh = make_mesh(frames=2, templates=2)
        xs, ys, ps = shard_problem(mesh, x, y, params)
        v, g = sharded_value_and_grad(ps, xs, ys, 1.0)
        assert len(xs.sharding.device_set) == 4 and not xs.sharding.is_fully_replicated
        assert g.w.sharding.spec == ps.w.sharding.spec, g.w.sharding
        np.testing.assert_allclose(float(v), float(ref_v), rtol=1e-5)
        for a, b in ((g.w, ref_g.w), (g.b, ref_g.b)):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), atol=1e-4)
        print("ok")
        """
    )
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=4")
    env["JAX_PLATFORMS"] = "cpu"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().endswith("ok")
