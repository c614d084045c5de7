"""Every matrix product on the fit and query paths states its precision.

JAX multiplies float32 matrices in TF32 on NVIDIA GPUs unless a product says
otherwise (``precision=None`` means "the backend's default"); the Newton-CG solve
does not survive that. On a CPU the default is full float32, so a product that
lost its ``precision`` would go unnoticed here. These tests walk the jaxprs of
what a fit, a query, the streamed solver and the embedding learners compile --
recursing into the sub-jaxprs of jit, scan, while, cond, custom_jvp, ... -- and
fail on any ``dot_general`` whose precision is None or DEFAULT.

Two ways in: every module-level jitted function of the package is wrapped for
the length of a test (:func:`recorded`) and its jaxpr traced with the real
arguments of a small run, so a renamed argument or a new jitted helper is
covered without this file knowing; functions jitted inside a call (the
embedding learners' steps) are traced with :func:`jax.make_jaxpr` directly.
"""

from __future__ import annotations

import contextlib
import functools
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rhythmic_jax as rj
from rhythmic_jax.decoding.fusion import fused_decode, fused_sequence_decode
from rhythmic_jax.decoding.sequence import sequence_decode
from rhythmic_jax.decoding.soft import soft_decode, topm_decode
from rhythmic_jax.fitting.closed_form import ridge_templates
from rhythmic_jax.fitting.learn import infonce_loss, map_episode_loss
from rhythmic_jax.map.codes import fit_codebook
from rhythmic_jax.map.embedding import embed, fit_invariant
from rhythmic_jax.solvers.newton import NewtonConfig, newton_fit
from rhythmic_jax.solvers.objective import targets

_LOOSE = (None, jax.lax.Precision.DEFAULT)


def _sub_jaxprs(params: dict):
    """Jaxprs held by an equation's params (jit, scan, while, cond branches...)."""
    for value in params.values():
        items = value if isinstance(value, tuple | list) else (value,)
        for item in items:
            if hasattr(item, "eqns"):  # a Jaxpr
                yield item
            elif hasattr(item, "jaxpr") and hasattr(item.jaxpr, "eqns"):
                yield item.jaxpr  # a ClosedJaxpr


def loose_products(jaxpr) -> list[str]:
    """Every ``dot_general`` of a (closed) jaxpr and its sub-jaxprs whose
    precision is None or DEFAULT, as ``"dot_general f32[a,b] x f32[b,c]"``."""
    jaxpr = getattr(jaxpr, "jaxpr", jaxpr)
    found = []
    for eqn in jaxpr.eqns:
        if eqn.primitive.name == "dot_general":
            prec = eqn.params.get("precision")
            pair = prec if isinstance(prec, tuple) else (prec, prec)
            if any(p in _LOOSE for p in pair):
                shapes = " x ".join(str(v.aval) for v in eqn.invars)
                found.append(f"dot_general {shapes} precision={prec}")
        for sub in _sub_jaxprs(eqn.params):
            found.extend(loose_products(sub))
    return found


def _is_tracer(tree) -> bool:
    return any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(tree))


def _zeros(traced):
    """Zeros of a traced call's outputs, put on the device without a compile."""
    return jax.tree.map(
        lambda s: jax.device_put(np.zeros(s.shape, s.dtype)), traced.out_info
    )


@contextlib.contextmanager
def recorded(monkeypatch):
    """Wrap every module-level jitted function of ``rhythmic_jax``: each top-level
    call (not one traced inside another jit, which its caller's jaxpr holds) adds
    ``(name, jaxpr)`` to the yielded list and returns zeros of its outputs'
    shapes, so nothing is compiled (a Newton solve sees no decrease and stops
    after one step; a decode answers place 0)."""
    seen: list[tuple[str, object]] = []

    def wrap(name, fn):
        @functools.wraps(fn)
        def call(*args, **kwargs):
            if _is_tracer((args, kwargs)):
                return fn(*args, **kwargs)
            traced = fn.trace(*args, **kwargs)
            seen.append((name, traced.jaxpr))
            return _zeros(traced)

        return call

    wrapped = {}
    for mod_name, mod in list(sys.modules.items()):
        if not mod_name.startswith("rhythmic_jax") or mod is None:
            continue
        for attr, value in list(vars(mod).items()):
            if callable(value) and hasattr(value, "trace") and hasattr(value, "lower"):
                if id(value) not in wrapped:
                    wrapped[id(value)] = wrap(f"{mod_name}.{attr}", value)
                monkeypatch.setattr(mod, attr, wrapped[id(value)])
    yield seen


def _assert_stated(seen) -> None:
    loose = {name: bad for name, jx in seen if (bad := loose_products(jx))}
    assert not loose, f"products without a stated precision: {loose}"


def _route(n: int, d: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x = np.cumsum(rng.normal(size=(n, d)), axis=0).astype(np.float32)
    return x / np.linalg.norm(x, axis=1, keepdims=True)


# ------------------------------------------------------------- the walker


def test_the_walker_finds_a_product_without_precision_inside_a_loop():
    def body(a, b):
        def step(carry, _):
            return jnp.tanh(carry @ b), None

        out, _ = jax.lax.scan(step, a, None, length=2)
        return jax.lax.cond(out[0, 0] > 0, lambda v: v, lambda v: -v, out)

    a = jnp.ones((3, 4))
    b = jnp.ones((4, 4))
    assert len(loose_products(jax.make_jaxpr(jax.jit(body))(a, b))) == 1
    hi = jax.lax.Precision.HIGHEST
    stated = jax.make_jaxpr(lambda a, b: jnp.matmul(a, b, precision=hi))(a, b)
    assert loose_products(stated) == []
    default = jax.make_jaxpr(
        lambda a, b: jnp.matmul(a, b, precision=jax.lax.Precision.DEFAULT)
    )(a, b)
    assert len(loose_products(default)) == 1


def test_the_walker_enters_custom_jvp_and_while_loops():
    @jax.custom_jvp
    def f(a):
        return a @ a.T

    f.defjvp(lambda p, t: (f(p[0]), t[0] @ p[0].T))

    def loop(a):
        return jax.lax.while_loop(lambda c: c[1] < 2, lambda c: (f(c[0]), c[1] + 1),
                                  (a, 0))[0]  # fmt: skip

    assert len(loose_products(jax.make_jaxpr(loop)(jnp.ones((3, 3))))) == 1


# ------------------------------------------------------------ fit and query


@pytest.mark.parametrize(
    "config",
    [
        NewtonConfig(),  # compact: later steps gather the live columns
        NewtonConfig(compact=False, exact_gradient=False, hessian_dtype="bfloat16"),
    ],
    ids=["default", "bfloat16-cg"],
)
def test_newton_steps_state_their_precision(monkeypatch, config):
    x = _route(120, 12)
    y = targets(np.arange(120), (11, 12))
    with recorded(monkeypatch) as seen:
        newton_fit(x, y, 2.0, config)
    names = {name.rsplit(".", 1)[-1] for name, _ in seen}
    assert "_newton_step" in names and "_spectral" in names, names
    _assert_stated(seen)


def test_a_fit_and_every_decode_state_their_precision(monkeypatch):
    x = _route(150, 16)
    q = jnp.asarray(x[::3] + 0.01)
    with recorded(monkeypatch) as seen:
        m = rj.RhythmicMap(r=2, level=1).fit(x)
        m.decode(q, "hard")
        m.decode(q, "soft")
        m.decode(q, "topm")
        m.predict(q, "soft", sequence=3, speeds=(0.9, 1.0))
        m.predict(q, "hard", sequence=3)
    assert len(seen) >= 6
    _assert_stated(seen)


def test_code_fusion_states_its_precision(monkeypatch):
    x = _route(120, 16)
    q = x[::4] + 0.01
    with recorded(monkeypatch) as seen:
        m = rj.RhythmicMap(r=2, level=1, codes=12).fit(x)
        m.decode(q, "soft")
        m.decode(q, "topm")
        m.predict(q, "soft", sequence=3)
        book = fit_codebook(x, "int8")
        sims = book.similarity(q)
        s = m.scores(q)
        fused_decode(s, sims, m.periods, m.n, 0.5, "topm")
        fused_sequence_decode(s, sims, m.periods, m.n, 3)
    _assert_stated(seen)


def test_streamed_sums_state_their_precision(monkeypatch, tmp_path):
    from rhythmic_jax.io.frame_files import ShardWriter, open_frames
    from rhythmic_jax.solvers.streamed import (
        StreamConfig,
        stream_errors,
        streamed_newton_fit,
    )

    n = 90
    x = _route(n, 10)
    with ShardWriter(tmp_path / "s", rows=40) as w:
        w.write(x)
    frames = open_frames(tmp_path / "s")
    with recorded(monkeypatch) as seen:
        got, _ = streamed_newton_fit(
            frames, np.arange(n), (9, 10), 2.0, StreamConfig(block_rows=32),
            progress=False,
        )  # fmt: skip
        stream_errors(frames, np.arange(n), (9, 10), got, block_rows=32)
    names = {name.rsplit(".", 1)[-1] for name, _ in seen}
    assert {"_grad_pass", "_line_pass"} <= names or "_grad_keep" in names, names
    _assert_stated(seen)


# ------------------------------------------------ jitted inside a call


def test_decoders_and_embedding_steps_state_their_precision():
    rng = np.random.default_rng(1)
    periods, n = (5, 7), 30
    s = jnp.asarray(rng.normal(size=(6, 12)), jnp.float32)
    traced = [
        jax.make_jaxpr(lambda v: soft_decode(v, periods, n))(s),
        jax.make_jaxpr(lambda v: topm_decode(v, periods, n, 2))(s),
        jax.make_jaxpr(lambda v: sequence_decode(v, periods, n, 3)[0])(s),
    ]
    x = [_route(40, 12, seed) for seed in (2, 3)]
    emb = fit_invariant(x, 6)
    traced.append(jax.make_jaxpr(embed)(emb, x[0]))
    params = {"m": jnp.eye(6), "scale": jnp.float32(4.0)}
    params["w1"] = jnp.ones((6, 8)) * 0.1
    params["b1"] = jnp.zeros(8)
    params["w2"] = jnp.zeros((8, 6))
    ref, qry = jnp.asarray(x[0][:20, :6]), jnp.asarray(x[1][:20, :6])
    episode = jax.value_and_grad(map_episode_loss)
    traced.append(
        jax.make_jaxpr(lambda p: episode(p, ref, qry, 3, (4, 5), 0.1))(params)
    )
    contrast = jax.value_and_grad(infonce_loss)
    traced.append(jax.make_jaxpr(lambda p: contrast(p, ref, qry, 0.1))(params))
    y = jnp.asarray(rng.normal(size=(20, 9)), jnp.float32)
    traced.append(
        jax.make_jaxpr(jax.grad(lambda z: ridge_templates(z, y, 0.1).w.sum()))(ref)
    )
    loose = [bad for jx in traced if (bad := loose_products(jx))]
    assert not loose, loose
