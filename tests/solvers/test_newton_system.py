"""The host loop keeps jax.lax.while_loop's contract in Python; each array's
arithmetic takes its own module."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax.solvers.newton_system import (
    Iterate,
    array_module,
    host_loop,
    summed,
)


def test_host_loop_gives_while_loops_state():
    def cond(state):
        return state[0] < 10

    def body(state):
        i, total = state
        return i + 1, total + i * i

    want = jax.lax.while_loop(cond, body, (jnp.int32(0), jnp.int32(0)))
    got = host_loop(cond, body, (0, 0))
    assert got == (10, 285) == tuple(int(v) for v in want)
    assert host_loop(cond, body, (12, 7)) == (12, 7)  # no iteration


def test_array_module_and_summed_objective():
    assert array_module(np.zeros(2)) is np
    assert array_module(jnp.zeros(2)) is jnp
    it = Iterate(jnp.ones((3, 2)), jnp.ones((4, 2)))
    total = summed(lambda p: jnp.sum(p.theta, axis=0) + jnp.sum(p.margins, axis=0))
    assert float(total(it)) == 14.0
