"""An embedding applied to descriptors before the map sees them.

``g(x) = normalise(h(x - mean) @ proj))`` with, for the small MLP, a residual
layer ``h(z) = z + relu(z @ w1 + b1) @ w2``. The embedding is fitted on the
*training segment* of a route (several traversals of the same places, under
different conditions), saved inside the map that uses it, and applied to the
reference frames and to every query. Its parameters are stored once and do not
grow with the number of places: :func:`embedding_bytes` counts them.

:func:`fit_invariant` is the closed form used to start every learned embedding
(and an option of its own): principal axes of the training frames, whitened,
then the directions in which frames of the *same place under different
conditions* differ least relative to how much places differ (Fisher's criterion
with the condition change as the within-class scatter).

Shapes: n frames, d input features, p principal axes, k output dimensions,
h hidden units of the residual layer.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.jit_options import jit
from rhythmic_jax.map.projection import fit_pca

__all__ = [
    "Embedding",
    "embed",
    "embedding_arrays",
    "embedding_bytes",
    "embedding_descriptor",
    "embedding_from_arrays",
    "fit_invariant",
    "fusion_of",
    "load_embedding",
    "save_embedding",
]


class Embedding(NamedTuple):
    """mean (d,), proj (d, k); for the MLP head also w1 (k, h), b1 (h,), w2 (h, k).

    A linear embedding keeps ``w1``, ``b1``, ``w2`` of shape (k, 0), (0,), (0, k).
    """

    mean: jax.Array
    proj: jax.Array
    w1: jax.Array
    b1: jax.Array
    w2: jax.Array

    @property
    def d(self) -> int:
        return int(self.proj.shape[0])

    @property
    def k(self) -> int:
        return int(self.proj.shape[1])

    @property
    def kind(self) -> str:
        return "mlp" if self.b1.shape[0] else "linear"


def linear(mean, proj) -> Embedding:
    """A linear embedding ``normalise((x - mean) @ proj)``."""
    proj = jnp.asarray(proj, jnp.float32)
    k = proj.shape[1]
    return Embedding(
        jnp.asarray(mean, jnp.float32),
        proj,
        jnp.zeros((k, 0)),
        jnp.zeros((0,)),
        jnp.zeros((0, k)),
    )


def embed(emb: Embedding, x: jax.Array) -> jax.Array:
    """Embedded, L2-normalised rows: x (n, d) -> (n, k)."""
    z = jnp.matmul(x - emb.mean[None, :], emb.proj, precision="highest")
    h = jax.nn.relu(jnp.matmul(z, emb.w1, precision="highest") + emb.b1[None, :])
    z = z + jnp.matmul(h, emb.w2, precision="highest")
    return z / jnp.maximum(jnp.linalg.norm(z, axis=1, keepdims=True), 1e-12)


_embed_jit = jit(embed)


def apply(emb: Embedding, x, batch: int = 4096) -> np.ndarray:
    """:func:`embed` over a host array (n, d) in batches -> float32 (n, k)."""
    x = np.asarray(x, np.float32)
    if x.ndim != 2 or x.shape[1] != emb.d:
        raise InputError(
            f"embedding: expects (n, {emb.d}) descriptors, got {tuple(x.shape)}"
        )
    out = [np.asarray(_embed_jit(emb, jnp.asarray(x[i : i + batch])))
           for i in range(0, len(x), batch)]  # fmt: skip
    return np.concatenate(out) if out else np.zeros((0, emb.k), np.float32)


def embedding_bytes(emb: Embedding, bytes_per_number: int = 4) -> int:
    """Bytes of the embedding's parameters (stored once, independent of N)."""
    return bytes_per_number * sum(int(np.prod(a.shape)) for a in emb)


def embedding_arrays(emb: Embedding) -> dict[str, np.ndarray]:
    """Arrays to save inside a map (``embedding_*``); a zero-size layer is left out."""
    return {
        f"embedding_{name}": np.asarray(a)
        for name, a in emb._asdict().items()
        if np.asarray(a).size
    }


def embedding_from_arrays(arrays: dict[str, np.ndarray]) -> Embedding | None:
    """The embedding saved by :func:`embedding_arrays` (None when there is none)."""
    if "embedding_proj" not in arrays:
        return None
    emb = linear(arrays["embedding_mean"], arrays["embedding_proj"])
    if "embedding_b1" in arrays:
        emb = emb._replace(
            w1=jnp.asarray(arrays["embedding_w1"]),
            b1=jnp.asarray(arrays["embedding_b1"]),
            w2=jnp.asarray(arrays["embedding_w2"]),
        )
    return emb


VARIANCE_FLOOR = 1e-6  # principal axes below this share of the first are dropped


def fit_invariant(
    traversals: list[np.ndarray], k: int = 256, p: int = 512, shrink: float = 0.1
) -> Embedding:
    """Closed-form condition-invariant linear embedding from aligned traversals.

    Args:
      traversals: two or more (n, d) arrays, row i = place i in every one.
      k: output dimensions (<= p).
      p: principal axes of all training frames kept first (<= total frames - 1).
      shrink: within-place scatter ``C_w`` is regularised to
        ``C_w + shrink * tr(C_w) / p * I`` before the generalised eigenproblem.

    In the whitened principal space (total scatter = I) the directions v
    maximising ``v^T v / v^T C_w v`` are the eigenvectors of ``C_w^{-1}`` of
    largest eigenvalue, each scaled by ``C_w^{-1/2}``; ``C_w`` is the scatter of
    each frame about the mean of its place over the traversals (the change of
    condition).
    """
    xs = [np.asarray(t, np.float32) for t in traversals]
    if len(xs) < 2:
        raise InputError("embedding: needs two or more traversals of the same places")
    n, d = xs[0].shape
    if any(t.shape != (n, d) for t in xs):
        raise InputError(
            "embedding: traversals must have the same shape "
            f"(got {[t.shape for t in xs]})"
        )
    total = len(xs) * n
    p = min(p, total - 1, d)
    if not 1 <= k <= p:
        raise InputError(
            f"embedding: {{opt:k}} {k} must lie in [1, {p}] ({len(xs)} traversals "
            f"of {n} places give at most {p} principal axes); give {{opt:k}} {p} or "
            "fewer, or more training places"
        )
    pca = fit_pca(np.concatenate(xs), p)
    # axes with (numerically) no variance would be whitened by ~1e6: drop them
    var = np.asarray(pca.explained_variance)
    p = int(np.sum(var > VARIANCE_FLOOR * var[0]))
    if k > p:
        raise InputError(
            f"embedding: k={k} exceeds the {p} principal axes with variance in "
            f"the {total} training frames; use k <= {p} or more training places"
        )
    pca = type(pca)(pca.mean, pca.components[:p], pca.explained_variance[:p])
    scale = 1.0 / jnp.sqrt(pca.explained_variance + 1e-12)
    zs = [
        jnp.matmul(
            jnp.asarray(t) - pca.mean[None, :], pca.components.T, precision="highest"
        )
        * scale[None, :]
        for t in xs
    ]
    centre = sum(zs) / len(zs)
    dev = jnp.concatenate([z - centre for z in zs])
    cw = jnp.matmul(dev.T, dev, precision="highest") / dev.shape[0]
    cw = cw + shrink * jnp.trace(cw) / p * jnp.eye(p)
    evals, evecs = jnp.linalg.eigh(cw)  # ascending: least within-place change first
    evals = jnp.maximum(evals, 1e-12 * evals[-1])  # rounding can make one negative
    # each kept direction scaled by C_w^{-1/2}: the condition change is whitened
    proj = jnp.matmul(
        pca.components.T,
        scale[:, None] * evecs[:, :k] / jnp.sqrt(evals[:k])[None, :],
        precision="highest",
    )
    return linear(pca.mean, proj)


def save_embedding(path, emb: Embedding, meta: dict) -> None:
    """Write an embedding to the folder ``path`` (orbax arrays + JSON, atomic)."""
    from rhythmic_jax.io import checkpoint

    info = {"kind": "embedding", "head": emb.kind, "d": emb.d, "k": emb.k}
    checkpoint.save_map(path, embedding_arrays(emb), {**meta, **info})


def embedding_descriptor(meta: dict) -> tuple[str | None, str | None]:
    """``(descriptor, weights)`` that frames need to be read the way the
    embedding's training frames were (from the metadata of :func:`load_embedding`).

    ``descriptor`` is None for an embedding learned on descriptor files
    (``features``); ``weights`` is None for none or for packaged weights, which
    the descriptor finds through their package wherever it is installed (the
    recorded file name is only a name, never a path from the current folder),
    else the absolute path of the user's file it was learned with.
    """
    name = meta.get("descriptor")
    if name in (None, "features"):
        return None, None
    settings = meta.get("descriptor_settings") or {}
    weights = settings.get("weights")
    if settings.get("weights_package") or weights is None:
        return name, None
    return name, str(weights)


def load_embedding(path) -> tuple[Embedding, dict]:
    """Read an embedding written by :func:`save_embedding` -> (embedding, meta)."""
    from rhythmic_jax.io import checkpoint

    arrays, meta = checkpoint.load_map(path)
    emb = embedding_from_arrays(arrays) if meta.get("kind") == "embedding" else None
    if emb is None:
        raise InputError(
            f"{path}: not an embedding (write one with rhythmic-jax learn)"
        )
    return emb, meta


def fusion_of(option: float | None, codes, meta: dict | None) -> dict[str, Any]:
    """The map's share of the fused score and where it comes from: ``option``
    when given, else the weight an embedding's ``meta`` learned for ``codes``,
    else 0.5. Returns ``{"weight": w, "from": "option" | "embedding" |
    "default", "note": why}``."""
    if option is not None:
        return {"weight": option, "from": "option", "note": "given with --fusion"}
    learned = (meta or {}).get("fusion")
    if meta is None:
        note = "no embedding"
    elif not learned:
        note = "the embedding holds no learned weight (saved before learn kept one)"
    elif learned.get("codes") != codes:
        note = f"the embedding's weight was learned for {learned.get('codes')} codes"
    else:
        return {
            "weight": float(learned["weight"]),
            "from": "embedding",
            "note": f"learned with the embedding for {codes} codes: R@1 "
            f"{learned['recall']:.3f} on its {learned['places']} training places",
        }
    return {"weight": 0.5, "from": "default", "note": note}
