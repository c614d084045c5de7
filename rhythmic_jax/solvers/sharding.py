"""Sharding the one objective over frames and templates with ``jax.sharding``.

The joint objective is a sum over frames of per-frame losses, ``jax.vmap``-ed
over templates that share no parameters. So frames (rows of x and y) can live on
one mesh axis and templates (columns of w, b and y) on another: each device
holds a block of frames and a block of templates, computes its block of margins
with one local matrix product, and XLA adds the frame blocks together. The same
code runs on one CPU, on several local devices, and across hosts once
``jax.distributed.initialize()`` has made every host's devices visible.

Names: n frames, d features, p templates.
"""

from __future__ import annotations

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from rhythmic_jax.jit_options import jit
from rhythmic_jax.solvers.objective import Templates, total_objective

__all__ = ["make_mesh", "shard_problem", "sharded_value_and_grad"]

FRAMES, TEMPLATES = "frames", "templates"


def make_mesh(frames: int | None = None, templates: int = 1) -> Mesh:
    """A (frames x templates) mesh over the visible devices (all on ``frames``)."""
    devices = jax.devices()
    frames = frames or len(devices) // templates
    grid = np.asarray(devices[: frames * templates]).reshape(frames, templates)
    return Mesh(grid, (FRAMES, TEMPLATES))


def shard_problem(
    mesh: Mesh, x, y, params: Templates
) -> tuple[jax.Array, jax.Array, Templates]:
    """Place x (n, d) by frames, y (n, p) by frames x templates, w/b by templates.

    n must divide by the mesh's frame axis and p by its template axis.
    """
    x = jax.device_put(x, NamedSharding(mesh, P(FRAMES, None)))
    y = jax.device_put(y, NamedSharding(mesh, P(FRAMES, TEMPLATES)))
    params = Templates(
        w=jax.device_put(params.w, NamedSharding(mesh, P(None, TEMPLATES))),
        b=jax.device_put(params.b, NamedSharding(mesh, P(TEMPLATES))),
    )
    return x, y, params


@jit
def sharded_value_and_grad(params: Templates, x, y, c):
    """The joint objective and its gradient; shardings follow the inputs'."""
    return jax.value_and_grad(total_objective)(params, x, y, c)
