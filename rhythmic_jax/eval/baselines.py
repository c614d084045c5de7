"""Nearest-neighbour search baselines a user would otherwise pick (paper Table 3).

Each baseline is fitted on the same L2-normalised reference descriptors X (n, d)
and searched with the same queries Q (b, d) as a rhythmic map:

- :class:`BruteForce`: exact inner product (faiss ``IndexFlatIP``), which on
  L2-normalised vectors is cosine similarity; the accuracy ceiling.
- :class:`KDTreeSearch`: scikit-learn ``KDTree``, exact Euclidean search (the same
  order as cosine on unit vectors), no compression.
- :class:`ITQ`: iterative quantisation to ``nbits``-bit codes (Gong et al.,
  TPAMI 2013) searched by Hamming distance (faiss ``ITQTransform`` +
  ``IndexLSH``). The paper used 256 bits.
- :class:`OPQ`: optimised product quantisation (Ge et al., TPAMI 2014) with ``m``
  sub-quantisers of ``nbits`` bits (faiss ``OPQMatrix`` + ``IndexPQ``). The
  paper used 256 bytes per vector (``m = 256``, 8 bits).

``search(Q, k)`` returns ``(values (b, k), idx (b, k))``, best first; ``values``
are similarities when ``higher_is_better`` and distances otherwise
(``confidence`` turns them into a higher-is-surer score for a PR curve).
``storage_bytes`` counts everything search needs: codes or vectors plus the
transforms, codebooks or tree; the module-level ``*_storage_bytes`` functions
give the same count for any size. Faiss runs on ``n_threads`` OpenMP threads,
set before every call (the setting is process-wide).
"""

from __future__ import annotations

import math

import faiss
import numpy as np

from rhythmic_jax.errors import InputError

__all__ = [
    "ITQ",
    "Baseline",
    "OPQ",
    "BruteForce",
    "KDTreeSearch",
    "flat_storage_bytes",
    "itq_storage_bytes",
    "kdtree_storage_bytes",
    "opq_storage_bytes",
]

_F32 = 4


def flat_storage_bytes(n: int, d: int) -> int:
    """Raw float32 database: ``n * d * 4``."""
    return n * d * _F32


def kdtree_storage_bytes(n: int, d: int, leaf_size: int = 40) -> int:
    """Arrays of a scikit-learn ``KDTree`` (it stores the data as float64).

    ``data n*d*8 + idx_array n*8 + node_data n_nodes*32 + node_bounds
    2*n_nodes*d*8`` with ``n_nodes = 2**n_levels - 1`` and ``n_levels =
    1 + floor(log2(max(1, (n - 1) / leaf_size)))`` (sklearn ``_binary_tree``).
    """
    n_levels = int(np.log2(max(1.0, (n - 1) / leaf_size))) + 1
    n_nodes = 2**n_levels - 1
    intp = np.dtype(np.intp).itemsize
    node_data = 3 * intp + 8  # idx_start, idx_end, is_leaf, radius
    return n * d * 8 + n * intp + n_nodes * node_data + 2 * n_nodes * d * 8


def itq_storage_bytes(n: int, d: int, nbits: int) -> int:
    """ITQ: codes ``n * ceil(nbits / 8)`` plus the float32 mean (d) and the
    PCA-then-rotation projection (nbits, d)."""
    return n * math.ceil(nbits / 8) + (d + nbits * d) * _F32


def opq_storage_bytes(n: int, d: int, m: int, nbits: int) -> int:
    """OPQ: codes ``n * ceil(m * nbits / 8)`` plus float32 codebooks
    (m sub-quantisers x 2**nbits centroids x d/m) and the (d, d) rotation."""
    return n * math.ceil(m * nbits / 8) + (2**nbits * d + d * d) * _F32


def _matrix(a, name: str, d: int | None = None) -> np.ndarray:
    """(rows, d) finite float32 C-contiguous copy of ``a``."""
    a = np.asarray(a)
    if a.ndim != 2 or a.shape[0] == 0 or a.shape[1] == 0:
        raise InputError(f"{name} must be a non-empty (rows, d) array, got {a.shape}")
    if d is not None and a.shape[1] != d:
        raise InputError(f"{name} has d={a.shape[1]} but the index was fitted on d={d}")
    a = np.ascontiguousarray(a, dtype=np.float32)
    if not np.isfinite(a).all():
        raise InputError(f"{name} has NaN or infinite entries")
    return a


class Baseline:
    """A fitted search index: ``fit(X)``, ``search(Q, k)``, ``storage_bytes``.

    Attributes: ``name``, ``n_threads`` (faiss OpenMP threads), ``note`` (why a
    setting was changed, else ""), ``higher_is_better`` (what ``search`` values
    mean), ``n`` and ``d`` once fitted.
    """

    name = "baseline"
    higher_is_better = False

    def __init__(self, n_threads: int = 1):
        if n_threads < 1:
            raise InputError(f"n_threads must be >= 1, got {n_threads}")
        self.n_threads = int(n_threads)
        self.note = ""
        self.n: int | None = None
        self.d: int | None = None

    def fit(self, X) -> Baseline:
        """Index the references X (n, d) float32, L2-normalised; returns self."""
        X = _matrix(X, "X")
        self.n, self.d = X.shape
        faiss.omp_set_num_threads(self.n_threads)
        self._fit(X)
        return self

    def search(self, Q, k: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """Top-k references of each query Q (b, d): ``(values (b, k), idx (b, k))``."""
        if self.n is None:
            raise InputError(f"{self.name}: call fit(X) before search(Q)")
        Q = _matrix(Q, "Q", self.d)
        if not 1 <= k <= self.n:
            raise InputError(f"k must lie in [1, {self.n}] (fitted rows), got {k}")
        faiss.omp_set_num_threads(self.n_threads)
        values, idx = self._search(Q, int(k))
        return np.asarray(values, np.float32), np.asarray(idx, np.int64)

    def confidence(self, values: np.ndarray) -> np.ndarray:
        """``values`` from ``search`` as a score where higher is surer."""
        values = np.asarray(values, np.float64)
        return values if self.higher_is_better else -values

    @property
    def storage_bytes(self) -> int:
        if self.n is None:
            raise InputError(f"{self.name}: call fit(X) before storage_bytes")
        return self._storage_bytes()

    def __repr__(self) -> str:
        return f"{type(self).__name__}(name={self.name!r}, n_threads={self.n_threads})"


class BruteForce(Baseline):
    """Exact cosine search: faiss ``IndexFlatIP`` over the float32 references."""

    name = "brute force"
    higher_is_better = True

    def _fit(self, X: np.ndarray) -> None:
        self.index = faiss.IndexFlatIP(self.d)
        self.index.add(X)

    def _search(self, Q, k):
        return self.index.search(Q, k)

    def _storage_bytes(self) -> int:
        return flat_storage_bytes(self.n, self.d)


class KDTreeSearch(Baseline):
    """Exact Euclidean search with a scikit-learn ``KDTree`` (one thread)."""

    name = "kd-tree"

    def __init__(self, leaf_size: int = 40):
        super().__init__(n_threads=1)
        if leaf_size < 1:
            raise InputError(f"leaf_size must be >= 1, got {leaf_size}")
        self.leaf_size = int(leaf_size)
        self.note = "scikit-learn KDTree keeps its data as float64; counted as such"

    def _fit(self, X: np.ndarray) -> None:
        from sklearn.neighbors import KDTree  # 1.3 s: only where it is used

        self.tree = KDTree(X, leaf_size=self.leaf_size)

    def _search(self, Q, k):
        return self.tree.query(Q, k=k, return_distance=True, sort_results=True)

    def _storage_bytes(self) -> int:
        return kdtree_storage_bytes(self.n, self.d, self.leaf_size)


class ITQ(Baseline):
    """ITQ binary codes (PCA to ``nbits``, learned rotation, sign), Hamming search.

    ``nbits`` above ``d`` is lowered to ``d`` (PCA cannot add dimensions) and
    ``note`` says so.
    """

    name = "ITQ"

    def __init__(self, nbits: int = 256, n_threads: int = 1):
        super().__init__(n_threads)
        if nbits < 1:
            raise InputError(f"nbits must be >= 1, got {nbits}")
        self.nbits_requested = int(nbits)
        self.nbits = int(nbits)

    def _fit(self, X: np.ndarray) -> None:
        self.nbits = min(self.nbits_requested, self.d)
        self.note = ""
        if self.nbits < self.nbits_requested:
            self.note = f"nbits lowered from {self.nbits_requested} to d={self.d}"
        self.name = f"ITQ {self.nbits}-bit"
        itq = faiss.ITQTransform(self.d, self.nbits, True)
        lsh = faiss.IndexLSH(self.nbits, self.nbits, False, False)
        self.index = faiss.IndexPreTransform(itq, lsh)
        self.index.train(X)
        self.index.add(X)

    def _search(self, Q, k):
        return self.index.search(Q, k)

    def _storage_bytes(self) -> int:
        return itq_storage_bytes(self.n, self.d, self.nbits)


class OPQ(Baseline):
    """OPQ codes: a learned (d, d) rotation, then ``m`` sub-quantisers of ``nbits``.

    faiss needs ``d % m == 0`` and warns below ``39 * 2**nbits`` training
    points per sub-quantiser. ``fit`` takes the largest ``m`` that divides ``d``
    (at most the requested one) and the largest ``nbits`` (at most the
    requested one) with ``n >= min_points_per_centroid * 2**nbits``, and says
    why in ``note`` when either is lowered. ``niter`` and ``niter_pq`` are the
    rotation and inner k-means iterations (faiss defaults 50 and 4); each
    rotation step is a (d, d) SVD, about 1.6 / 11 / 70 CPU-seconds at d = 512 /
    1024 / 2048 on one thread, so lower ``niter`` for large d and report it.
    """

    name = "OPQ"

    def __init__(
        self,
        m: int = 256,
        nbits: int = 8,
        min_points_per_centroid: int = 39,
        niter: int = 50,
        niter_pq: int = 4,
        n_threads: int = 1,
    ):
        super().__init__(n_threads)
        if m < 1 or not 1 <= nbits <= 16 or min_points_per_centroid < 1:
            raise InputError(
                f"OPQ needs m >= 1, 1 <= nbits <= 16 and min_points_per_centroid "
                f">= 1, got m={m}, nbits={nbits}, {min_points_per_centroid}"
            )
        self.m_requested, self.nbits_requested = int(m), int(nbits)
        self.m, self.nbits = int(m), int(nbits)
        self.min_points_per_centroid = int(min_points_per_centroid)
        self.niter, self.niter_pq = int(niter), int(niter_pq)

    def _choose(self) -> None:
        n, d, mp = self.n, self.d, self.min_points_per_centroid
        self.m = max(m for m in range(1, min(self.m_requested, d) + 1) if d % m == 0)
        fits = [b for b in range(1, self.nbits_requested + 1) if n >= mp * 2**b]
        if not fits:
            raise InputError(
                f"X has {n} rows; OPQ needs at least {2 * mp} "
                f"(min_points_per_centroid={mp} times 2 centroids)"
            )
        self.nbits = max(fits)
        notes = []
        if self.m != self.m_requested:
            notes.append(
                f"m lowered from {self.m_requested} to {self.m}: d={d} must be "
                f"divisible by m"
            )
        if self.nbits != self.nbits_requested:
            notes.append(
                f"nbits lowered from {self.nbits_requested} to {self.nbits}: "
                f"{n} training points < {mp} * 2**{self.nbits_requested}"
            )
        self.note = "; ".join(notes)

    def _fit(self, X: np.ndarray) -> None:
        self._choose()
        self.name = f"OPQ {self.m}x{self.nbits}-bit"
        opq = faiss.OPQMatrix(self.d, self.m)
        opq.niter, opq.niter_pq = self.niter, self.niter_pq
        pq = faiss.IndexPQ(self.d, self.m, self.nbits)
        opq.pq = pq.pq  # train the rotation with the same code size
        self.index = faiss.IndexPreTransform(opq, pq)
        self.index.train(X)
        self.index.add(X)

    def _search(self, Q, k):
        return self.index.search(Q, k)

    def _storage_bytes(self) -> int:
        return opq_storage_bytes(self.n, self.d, self.m, self.nbits)
