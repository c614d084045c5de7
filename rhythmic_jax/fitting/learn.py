"""Learning an embedding from two or more traversals of a training route.

Three methods share one head and one data set (row i of every traversal is
place i, each traversal a different condition: season, time of day, date):

* ``pca``: the leading principal axes of the training frames of every
  traversal (unsupervised: no pairing of places across conditions used), a
  baseline with nothing learned about the change of condition.
* ``invariant``: the closed form of :func:`rhythmic_jax.map.embedding.fit_invariant`
  (no gradient steps). Every other method starts from it.
* ``map``: the embedding learned *through the map*. Each step draws an episode:
  a random window of the training places, a random phase offset (so the head
  cannot learn the phases themselves), a reference and a query condition.
  Templates for the window are fitted in closed form from the embedded
  reference frames (:func:`rhythmic_jax.fitting.closed_form.ridge_templates`), the query
  frames are decoded with the soft place-domain decode, and the loss is the
  cross-entropy of their true place plus that of their phase in every period.
* ``infonce``: the metric-learning baseline: symmetric InfoNCE between the two
  conditions of the same places in a batch.

The head on top of the closed form is a k x k matrix M (``linear``; started at
the identity, weight decay pulls it back there) and, for ``mlp``, a residual
ReLU layer (started at zero). The last ``val_fraction`` of the training places
(after a gap) is held out of the steps: the head with the lowest loss there is
kept (early stopping). The result folds into one :class:`Embedding`.

Before any of that, the last ``holdout`` share of the route's places (after a
gap) is set aside and never learned from (:mod:`rhythmic_jax.fitting.holdout`):
the embedding's codes are measured there against the raw descriptors' codes,
and a :class:`~rhythmic_jax.solvers.newton.FitWarning` says when the embedding
does worse there or learned from few places per dimension. The default method
is ``invariant``, for Python and the command line alike: the closed form takes
a twelfth of the time of ``map`` on 280 Nordland places, and ``map`` started
from it did no better on held-out places (R@1 0.152).

Shapes: n places, d input features, k dimensions, h hidden units, w window.
"""

from __future__ import annotations

import logging
import time
import warnings
from dataclasses import asdict, dataclass

import jax
import jax.numpy as jnp
import numpy as np
import optax

from rhythmic_jax.errors import InputError
from rhythmic_jax.fitting.closed_form import (
    place_log_scores,
    ridge_templates,
    window_periods,
)
from rhythmic_jax.fitting.holdout import held_out_notes, held_out_recall, split_places
from rhythmic_jax.jit_options import jit
from rhythmic_jax.map.embedding import Embedding, fit_invariant, linear
from rhythmic_jax.map.projection import fit_pca
from rhythmic_jax.solvers.newton import FitWarning
from rhythmic_jax.solvers.objective import targets

__all__ = ["LearnConfig", "learn_embedding", "map_episode_loss"]

log = logging.getLogger(__name__)
METHODS = ("pca", "invariant", "map", "infonce")
HEADS = ("linear", "mlp")


@dataclass(frozen=True)
class LearnConfig:
    """How an embedding is learned (``rhythmic-jax learn A B --out EMB``).

    Attributes:
      method: pca | invariant | map | infonce (see the module docstring).
      head: linear (k x k) | mlp (plus a residual ReLU layer of ``hidden`` units).
      k, p, shrink: of the closed form (:func:`fit_invariant`).
      window, r, level: an episode's window of places and its periods.
      ridge: relative ridge of the closed-form templates.
      steps, lr, weight_decay: optax AdamW over the head.
      temperature: InfoNCE temperature (its batch is the episode's window).
      holdout: share of the route's places (its end, after a gap) never learned
        from, where the embedding is measured (0: none).
      val_fraction: share of the learning places held out for early stopping.
      eval_every: steps between early-stopping checks.
      seed: PRNG seed of the episodes and the head.
    """

    method: str = "invariant"
    head: str = "linear"
    k: int = 256
    p: int = 512
    shrink: float = 0.1
    window: int = 300
    r: int = 2
    level: int = 2
    ridge: float = 1.0
    steps: int = 300
    lr: float = 1e-3
    weight_decay: float = 1e-2
    hidden: int = 64
    temperature: float = 0.05
    holdout: float = 0.2
    val_fraction: float = 0.2
    eval_every: int = 25
    seed: int = 0

    def __post_init__(self):
        if self.method not in METHODS:
            raise InputError(f"method must be one of {METHODS}, got {self.method!r}")
        if self.head not in HEADS:
            raise InputError(f"head must be one of {HEADS}, got {self.head!r}")
        for name in ("k", "p", "window", "steps", "hidden", "eval_every"):
            if int(getattr(self, name)) < 1:
                raise InputError(f"{name} must be >= 1, got {getattr(self, name)}")
        if not 0 <= self.holdout <= 0.5:
            raise InputError(f"holdout must lie in [0, 0.5], got {self.holdout}")
        if not 0 <= self.val_fraction < 0.9:
            raise InputError(
                f"val_fraction must lie in [0, 0.9), got {self.val_fraction}"
            )


def _init_head(key, k: int, head: str, hidden: int) -> dict:
    params = {"m": jnp.eye(k), "scale": jnp.asarray(10.0, jnp.float32)}  # strong:
    # a weakly typed scale would turn strong after the first step and retrace it
    if head == "mlp":
        params["w1"] = jax.random.normal(key, (k, hidden)) / jnp.sqrt(k)
        params["b1"] = jnp.zeros(hidden)
        params["w2"] = jnp.zeros((hidden, k))
    return params


def _head(params: dict, u: jax.Array) -> jax.Array:
    """Head applied to the closed form's output u (n, k) -> normalised (n, k)."""
    z = jnp.matmul(u, params["m"], precision="highest")
    if "w1" in params:
        h = jax.nn.relu(
            jnp.matmul(z, params["w1"], precision="highest") + params["b1"][None, :]
        )
        z = z + jnp.matmul(h, params["w2"], precision="highest")
    return z / jnp.maximum(jnp.linalg.norm(z, axis=1, keepdims=True), 1e-12)


def map_episode_loss(
    params: dict,
    ref: jax.Array,
    qry: jax.Array,
    offset: jax.Array,
    periods: tuple[int, ...],
    ridge: float,
) -> jax.Array:
    """Cross-entropy of the soft map decode on one episode.

    ref, qry: (w, k) closed-form outputs of the window's places under the
    reference and the query condition; offset: int phase offset of the window.
    Templates are fitted on ``head(ref)``; ``head(qry)`` frames are decoded over
    the window's places; loss = place CE + mean per-period phase CE.
    """
    zr, zq = _head(params, ref), _head(params, qry)
    w = ref.shape[0]
    labels = jnp.arange(w) + offset
    tmpl = ridge_templates(zr, targets(labels, periods), ridge)
    s = jnp.matmul(zq, tmpl.w, precision="highest") + tmpl.b[None, :]
    scale = params["scale"]
    place = place_log_scores(s, periods, labels, scale)
    loss = -jnp.mean(jnp.diagonal(jax.nn.log_softmax(place, axis=1)))
    start = 0
    for t in periods:
        logp = jax.nn.log_softmax(scale * s[:, start : start + t], axis=1)
        loss = loss - jnp.mean(logp[jnp.arange(w), labels % t]) / len(periods)
        start += t
    return loss


def infonce_loss(params: dict, a: jax.Array, b: jax.Array, temperature: float):
    """Symmetric InfoNCE between the rows of a and b (same places), (n, k) each."""
    za, zb = _head(params, a), _head(params, b)
    logits = jnp.matmul(za, zb.T, precision="highest") / temperature
    idx = jnp.arange(a.shape[0])
    la = -jnp.mean(jax.nn.log_softmax(logits, axis=1)[idx, idx])
    lb = -jnp.mean(jax.nn.log_softmax(logits, axis=0)[idx, idx])
    return 0.5 * (la + lb)


def _fold(base: Embedding, params: dict) -> Embedding:
    emb = linear(base.mean, jnp.matmul(base.proj, params["m"], precision="highest"))
    if "w1" in params:
        emb = emb._replace(w1=params["w1"], b1=params["b1"], w2=params["w2"])
    return emb


def _check_traversals(traversals) -> list[np.ndarray]:
    xs = [np.asarray(t, np.float32) for t in traversals]
    if len(xs) < 2:
        raise InputError("learn: needs two or more traversals of the training route")
    if any(t.ndim != 2 or t.shape != xs[0].shape for t in xs):
        raise InputError(
            "learn: traversals must share one (n, d) shape, got "
            f"{[t.shape for t in xs]}"
        )
    return xs


def learn_embedding(
    traversals, config: LearnConfig | None = None, *, codes="int8"
) -> tuple[Embedding, dict]:
    """Learn an embedding from aligned traversals [(n, d), ...] -> (embedding, info).

    The last ``config.holdout`` share of the places is never learned from
    (:func:`rhythmic_jax.fitting.holdout.split_places`); ``info["held_out"]``
    holds the recall@1 of ``codes`` (int8, or a number of ITQ bits) there, of
    the embedded and of the raw descriptors
    (:func:`~rhythmic_jax.fitting.holdout.held_out_recall`), and a
    :class:`~rhythmic_jax.solvers.newton.FitWarning` says when the embedding is
    the worse of the two there, or learned from few places per dimension.
    ``info`` also holds the method, the places (``places`` in all,
    ``learn_places`` learned from), the seconds spent, the steps run, the step
    kept by early stopping and the validation losses.
    """
    cfg = config or LearnConfig()
    xs = _check_traversals(traversals)
    n = xs[0].shape[0]
    n_learn, start = split_places(n, cfg.holdout)
    if n - start and (n - start < 4 or n_learn < 4):
        raise InputError(
            f"learn: {n} places are too few to hold {n - start} out and learn from "
            f"the rest; give more places or {{opt:holdout}} 0"
        )
    emb, info = _learn([x[:n_learn] for x in xs], cfg)
    info.update(places=n, learn_places=n_learn)
    if start < n:
        t0 = time.perf_counter()
        info["held_out"] = held_out_recall(emb, [x[start:] for x in xs], codes)
        info["held_out"]["seconds"] = time.perf_counter() - t0
    info["notes"] = held_out_notes(info, emb.k)
    for note in info["notes"]:
        warnings.warn(FitWarning(note), stacklevel=2)
    return emb, info


def _learn(xs: list[np.ndarray], cfg: LearnConfig) -> tuple[Embedding, dict]:
    """:func:`learn_embedding` on the learning places xs [(n, d), ...]."""
    n = xs[0].shape[0]
    t0 = time.perf_counter()
    if cfg.method == "pca":
        pca = fit_pca(np.concatenate(xs), cfg.k)  # a k it cannot give: one line
        info = dict(config=asdict(cfg), places=n, fit_places=n, val_places=0)
        info.update(seconds=time.perf_counter() - t0, steps=0)
        return linear(pca.mean, pca.components.T), info
    n_val = int(round(cfg.val_fraction * n)) if cfg.method != "invariant" else 0
    gap = min(20, n // 20) if n_val else 0
    n_fit = n - n_val - gap
    win = min(cfg.window, n_fit, n_val) if n_val else min(cfg.window, n_fit)
    if n_fit < 4 or (n_val and n_val < 4):
        raise InputError(f"learn: {n} places are too few to learn from")
    base = fit_invariant([x[:n_fit] for x in xs], cfg.k, cfg.p, cfg.shrink)
    info = dict(config=asdict(cfg), places=n, fit_places=n_fit, val_places=n_val)
    if cfg.method == "invariant":
        info.update(seconds=time.perf_counter() - t0, steps=0)
        return base, info
    # the head trains on the closed form's outputs, computed once
    u = jnp.stack([jnp.asarray(_base_out(base, x)) for x in xs])
    key = jax.random.PRNGKey(cfg.seed)
    key, sub = jax.random.split(key)
    params = _init_head(sub, base.k, cfg.head, cfg.hidden)
    periods = window_periods(win, cfg.r, cfg.level)
    period_lcm = int(np.lcm.reduce(periods))
    opt = optax.adamw(cfg.lr, weight_decay=0.0)
    state = opt.init(params)
    n_cond = len(xs)

    def loss_fn(prm, start, offset, a, b):
        ref = jax.lax.dynamic_slice_in_dim(u[a], start, win)
        qry = jax.lax.dynamic_slice_in_dim(u[b], start, win)
        if cfg.method == "map":
            loss = map_episode_loss(prm, ref, qry, offset, periods, cfg.ridge)
        else:
            loss = infonce_loss(prm, ref, qry, cfg.temperature)
        decay = jnp.sum((prm["m"] - jnp.eye(base.k)) ** 2)
        decay += sum(jnp.sum(prm[k] ** 2) for k in ("w1", "w2") if k in prm)
        return loss + cfg.weight_decay * decay

    @jit
    def step(prm, st, key):
        k1, k2, k3, k4 = jax.random.split(key, 4)
        start = jax.random.randint(k1, (), 0, n_fit - win + 1)
        offset = jax.random.randint(k2, (), 0, period_lcm)
        a = jax.random.randint(k3, (), 0, n_cond)
        b = (a + 1 + jax.random.randint(k4, (), 0, n_cond - 1)) % n_cond
        loss, grads = jax.value_and_grad(loss_fn)(prm, start, offset, a, b)
        updates, st = opt.update(grads, st, prm)
        return optax.apply_updates(prm, updates), st, loss

    val_start = n_fit + gap

    @jit
    def val_loss(prm):
        total = 0.0
        for a in range(n_cond):
            for b in range(n_cond):
                if a != b:
                    for off in (0, period_lcm // 3):
                        total += loss_fn(prm, val_start + n_val - win, off, a, b)
        return total

    best, best_loss, best_step, history = params, float(val_loss(params)), 0, []
    history.append((0, best_loss))
    for i in range(1, cfg.steps + 1):
        key, sub = jax.random.split(key)
        params, state, _ = step(params, state, sub)
        if i % cfg.eval_every == 0 or i == cfg.steps:
            v = float(val_loss(params))
            history.append((i, v))
            if v < best_loss:
                best, best_loss, best_step = params, v, i
    log.info(
        "learned %s/%s: kept step %d of %d", cfg.method, cfg.head, best_step, cfg.steps
    )
    info.update(
        seconds=time.perf_counter() - t0,
        steps=cfg.steps,
        kept_step=best_step,
        val_loss=[(int(s), float(v)) for s, v in history],
        periods=list(periods),
    )
    return _fold(base, best), info


def _base_out(base: Embedding, x: np.ndarray) -> np.ndarray:
    """The closed form's un-normalised output (n, k) (the head normalises)."""
    return np.asarray(
        jnp.matmul(jnp.asarray(x) - base.mean[None, :], base.proj, precision="highest")
    )
