"""The one objective: squared-hinge L2-SVMs for every template of every period.

Template ``j`` of period ``tau`` labels frame ``i`` with ``y = +1`` when
``i mod tau == j`` and ``y = -1`` otherwise (paper Eq. 1, 0-based). Each template
is a linear L2-SVM in liblinear's form (paper Eq. 2 with the squared hinge)::

    f(w, b) = 0.5 * (||w||^2 + b^2) + C * sum_i max(0, 1 - y_i (w . x_i + b))^2

with the bias treated as a constant-1 feature regularised like the weights and
``C = log N`` by default. :func:`classifier_objective` is ONE classifier;
:func:`objective` ``jax.vmap``-s it over every template of every candidate period
(``p`` templates in all), which XLA lowers to one ``(n, d) x (d, p)`` product.
Both are :func:`margin_objective` (the same classifier written at its margins
``m = x . w + b``) composed with the linear scores; solvers that keep the margins
in step with the parameters (Newton-CG) differentiate :func:`margin_objectives`,
its vmap, directly.

Names: n frames, d features, p templates (sum of the periods), g periods.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax.map.groups import Groups
from rhythmic_jax.map.periods import period_offsets
from rhythmic_jax.map.pytree import (  # the map's value and its scores
    Templates,
    host_templates,
)
from rhythmic_jax.map.pytree import decision_values as scores

__all__ = [
    "Templates",
    "classifier_objective",
    "default_c",
    "host_templates",
    "margin_objective",
    "margin_objectives",
    "objective",
    "period_errors",
    "phase_predictions",
    "scores",
    "squared_hinge",
    "targets",
    "total_objective",
]


def default_c(n: int) -> float:
    """The paper's penalty ``C = log N`` (natural log, Sec. III-A)."""
    return float(math.log(n))


def _label_parts(labels, periods) -> tuple[list, tuple[int, ...]]:
    """Labels of every group and the group sizes; plain periods (any, e.g. the
    candidates, co-prime or not) label by ``labels mod tau``."""
    if isinstance(periods, Groups):
        return periods.label_parts(labels), periods.sizes
    sizes = tuple(int(t) for t in periods)
    return [labels % t for t in sizes], sizes


def targets(
    labels: np.ndarray | jax.Array, periods: Sequence[int] | Groups
) -> jax.Array:
    """±1 targets ``y[i, off_g + j] = +1 iff label_g(labels[i]) == j``.

    With periods the label is ``labels[i] mod tau_k`` (paper Eq. 1); with a
    :class:`~rhythmic_jax.map.groups.Groups` it is the group's label (a mixed-radix
    digit, a segment), so every layout trains the same objective.

    Args:
      labels: (n,) int place index of every frame (several traversals of one route
        share labels: multi-exemplar training).
      periods: static tuple of g periods, or the map's groups.

    Returns:
      (n, p) float32 array of ±1: a NumPy array for host labels (no XLA program
      is compiled), a JAX array for JAX labels (traced ones included).
    """
    if not isinstance(labels, jax.Array):
        parts, sizes = _label_parts(np.asarray(labels), periods)
        return np.concatenate(
            [
                np.where(part[:, None] == np.arange(t)[None, :], 1.0, -1.0)
                for part, t in zip(parts, sizes, strict=True)
            ],
            axis=1,
        ).astype(np.float32)
    parts, sizes = _label_parts(labels, periods)
    cols = [
        jnp.where(
            part[:, None] == jnp.arange(t)[None, :],
            jnp.float32(1.0),
            jnp.float32(-1.0),
        )
        for part, t in zip(parts, sizes, strict=True)
    ]
    return jnp.concatenate(cols, axis=1)


def squared_hinge(score: jax.Array, target: jax.Array) -> jax.Array:
    """Per-element squared hinge ``max(0, 1 - target * score) ** 2`` (input's shape).

    Written with ``jax.nn.relu``, whose derivative is 0 at 0, so the second
    derivative autodiff gives is the generalised Hessian ``2 [1 - target * score > 0]``
    (target^2 = 1) that Newton's method on the squared hinge uses (Chapelle, 2007),
    also on the kink itself.
    """
    return jnp.square(jax.nn.relu(1.0 - target * score))


def margin_objective(
    theta: jax.Array,
    m: jax.Array,
    y: jax.Array,
    c: float,
    frame_weight: jax.Array | float = 1.0,
) -> jax.Array:
    """ONE template's objective at its margins m: ``0.5 ||theta||^2 + C sum_i a_i h_i``,
    ``h_i = max(0, 1 - y_i m_i)^2``.

    Args:
      theta: (q,) all parameters, the bias among them (it is regularised like
        the weights): ``[w; b]``, q = d + 1.
      m: (n,) margins ``x_i . w + b`` of the frames.
      y: (n,) ±1 targets; c: the penalty C; frame_weight: scalar or (n,) ``a_i``.

    Returns:
      () the objective value; :func:`classifier_objective` is this at ``m = x w + b``.
    """
    loss = squared_hinge(m, y)
    return 0.5 * jnp.vdot(theta, theta, precision="highest") + c * jnp.sum(
        frame_weight * loss
    )


def margin_objectives(
    theta: jax.Array,
    m: jax.Array,
    y: jax.Array,
    c: float,
    frame_weight: jax.Array | float = 1.0,
) -> jax.Array:
    """:func:`margin_objective` vmapped over templates: theta (q, p), m and y (n, p)
    -> (p,). The objective Newton-CG differentiates (its gradient and Hessian come
    from ``jax.grad`` and ``jax.jvp`` of it), margins kept in step with theta."""
    per_template = jax.vmap(margin_objective, in_axes=(1, 1, 1, None, None))
    return per_template(theta, m, y, c, frame_weight)


def classifier_objective(
    w: jax.Array,
    b: jax.Array,
    x: jax.Array,
    y: jax.Array,
    c: float,
    frame_weight: jax.Array | float = 1.0,
) -> jax.Array:
    """ONE template's objective: ``0.5 (||w||^2 + b^2) + C sum_i a_i h(w.x_i+b, y_i)``.

    Args:
      w: (d,) weights; b: () bias; x: (n, d) frames; y: (n,) ±1 targets.
      c: the penalty C.
      frame_weight: scalar or (n,) multiplier ``a_i`` of each frame's loss; a
        minibatch of size m out of n uses ``n / m`` for an unbiased estimate.

    Returns:
      () the objective value.
    """
    theta = jnp.concatenate([w, jnp.reshape(b, (1,))])
    return margin_objective(
        theta, jnp.matmul(x, w, precision="highest") + b, y, c, frame_weight
    )


def objective(
    params: Templates,
    x: jax.Array,
    y: jax.Array,
    c: float,
    frame_weight: jax.Array | float = 1.0,
) -> jax.Array:
    """Every template's objective at once: :func:`classifier_objective` vmapped.

    Args:
      params: ``w`` (d, p), ``b`` (p,).
      x: (n, d) frames; y: (n, p) ±1 targets from :func:`targets`.

    Returns:
      (p,) one objective per template. Their sum is the joint objective; the
      templates share no parameters, so its optimum is every template's optimum.
    """
    per_template = jax.vmap(
        classifier_objective, in_axes=(1, 0, None, 1, None, None), out_axes=0
    )
    return per_template(params.w, params.b, x, y, c, frame_weight)


def total_objective(
    params: Templates,
    x: jax.Array,
    y: jax.Array,
    c: float,
    frame_weight: jax.Array | float = 1.0,
) -> jax.Array:
    """Sum of :func:`objective` over templates: the scalar an optimiser minimises."""
    return jnp.sum(objective(params, x, y, c, frame_weight))


def phase_predictions(s: jax.Array, periods: Sequence[int]) -> jax.Array:
    """Per-period argmax phase ``f(x | tau_g)`` (paper Eq. 3): (n, p) -> (n, g)."""
    offs = period_offsets(periods)
    return jnp.stack(
        [
            jnp.argmax(s[:, o : o + t], axis=1)
            for o, t in zip(offs, periods, strict=True)
        ],
        axis=1,
    ).astype(jnp.int32)


def period_errors(
    s: jax.Array, labels: jax.Array, periods: Sequence[int] | Groups
) -> jax.Array:
    """Training error of every period: fraction of frames whose argmax phase is wrong.

    Args:
      s: (n, p) decision values of the frames; labels: (n,) place indices.
      periods: the periods, or a map's groups (then the error of every group).

    Returns:
      (g,) float32 error of each period (paper Sec. III-B, "training error
      e"): NumPy, computed on the host, unless ``s`` is traced (a JAX array);
      the same float32 values either way (a wrong count over n, rounded once).
    """
    if isinstance(s, jax.core.Tracer) or isinstance(labels, jax.core.Tracer):
        parts, sizes = _label_parts(jnp.asarray(labels), periods)
        pred = phase_predictions(s, sizes)
        truth = jnp.stack(parts, axis=1)
        return jnp.mean(pred != truth, axis=0)
    s, labels = np.asarray(s), np.asarray(labels)
    parts, sizes = _label_parts(labels, periods)
    offs = period_offsets(sizes)
    wrong = [
        np.count_nonzero(np.argmax(s[:, o : o + t], axis=1) != part)
        for o, t, part in zip(offs, sizes, parts, strict=True)
    ]
    return np.asarray(wrong, np.float32) / np.float32(len(labels))
