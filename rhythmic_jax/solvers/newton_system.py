"""The Newton iterate and system every Newton step works on, whoever sums it.

:class:`Iterate` is every template's parameters with their margins;
:class:`NewtonSystem` the gradient, Hessian-vector products and objective along
a step given as functions, summed in memory
(:func:`rhythmic_jax.solvers.newton_cg.in_memory_system`) or over blocks of
frames read from disk (:mod:`rhythmic_jax.solvers.streamed`); :func:`host_loop`
runs a loop of numpy arrays as ``jax.lax.while_loop`` runs a traced one, and
:func:`array_module` says which module an array's arithmetic takes.

Names: n frames, q = d + 1 parameters, p templates.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["Iterate", "NewtonSystem", "array_module", "host_loop", "summed"]


class Iterate(NamedTuple):
    """Parameters ``theta`` (q, p), bias last, and their margins ``Xa theta`` (n, p)."""

    theta: jax.Array
    margins: jax.Array


def summed(value_fn):
    """``value_fn`` summed over its templates: a scalar objective."""
    return lambda params: jnp.sum(value_fn(params))


def array_module(a):
    """The array module of ``a``: numpy for host arrays (a :func:`host_loop`'s
    CG or line search), else jax.numpy (traced, or eager jax arrays)."""
    return np if isinstance(a, np.ndarray) else jnp


def host_loop(cond, body, init):
    """``jax.lax.while_loop``'s contract run by Python, for bodies that cannot be
    traced (a Hessian-vector product that reads its frames from disk): the loop
    of a :class:`NewtonSystem` over numpy arrays."""
    state = init
    while bool(cond(state)):
        state = body(state)
    return state


class NewtonSystem(NamedTuple):
    """The Newton system ``H s = -g`` as
    :func:`rhythmic_jax.solvers.newton_cg.newton_cg`'s CG takes it, and the
    objective along a step as
    :func:`rhythmic_jax.solvers.exact_linesearch.scale_by_exact_linesearch` takes it.

    ``grad`` (q, p) the gradient in theta (the iterate's dtype); ``hvp``:
    (q, p) -> ``(scale H v, Xa v or None)``; ``precond``: an approximate inverse
    of ``scale H``; ``scale``: the factor the system is multiplied by before
    CG (the step is the same); ``dtype`` CG's; ``loop`` runs CG and the line
    search (``jax.lax.while_loop``, or :func:`host_loop` over numpy arrays).
    ``value`` (p,): the objective of every template at the iterate; ``line``:
    ``s`` (q, p) -> ``along``, with ``along(t)`` for step lengths t (1, p) giving
    ``phi(t) - phi(0)`` (p,), ``phi'(t)`` and ``phi''(t)`` (1, p), ``phi_j(t)``
    the objective of template j at ``theta + t s`` (None: the line search
    differentiates ``value_fn``).
    :func:`rhythmic_jax.solvers.newton_cg.in_memory_system` builds the first six
    from the objective and the design; a streamed fit sums all of them over
    blocks of frames (:mod:`rhythmic_jax.solvers.streamed`).
    """

    grad: jax.Array
    hvp: Any
    precond: Any
    scale: Any
    dtype: Any
    loop: Any = jax.lax.while_loop
    value: Any = None
    line: Any = None
