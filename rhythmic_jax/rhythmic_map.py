"""The rhythmic map as a scikit-learn-style estimator.

``RhythmicMap(r=2, level=1).fit(X)`` trains every template of every candidate
period in one joint solve, measures each candidate's training error, chooses ``r``
pairwise co-prime periods (product >= N, least summed error) and keeps only their
templates: ``sum(periods) * (d + 1)`` numbers instead of ``N * d``.
``predict(Q)`` localises queries (int index, -1 = no match).

Example (the README's ten lines)::

    import numpy as np, rhythmic_jax as rj
    X = np.random.default_rng(0).normal(size=(500, 1000)).astype("float32")
    m = rj.RhythmicMap(r=2, level=1).fit(X)
    m.predict(X[:5])            # -> [0 1 2 3 4]
    m.periods, m.storage_bytes  # -> (23, 24), 188,188
    m.save("route.map"); rj.RhythmicMap.load("route.map")
"""

from __future__ import annotations

import logging
import os
from dataclasses import replace
from typing import Any

import jax
import numpy as np

from rhythmic_jax.decoding.hard import Decoded
from rhythmic_jax.decoding.queries import (
    decode_map,
    few_places,
    locate_fast,
    map_scores,
    one_query,
    place_scores_map,
    sequence_map,
)
from rhythmic_jax.decoding.small import SmallDecoder
from rhythmic_jax.errors import InputError
from rhythmic_jax.fitting.fit_plan import FitPlan
from rhythmic_jax.fitting.fit_plan import plan as plan_fit
from rhythmic_jax.jit_options import describe as compile_options
from rhythmic_jax.map import map_file
from rhythmic_jax.map.codes import CodeBook
from rhythmic_jax.map.config import INT8, MapConfig
from rhythmic_jax.map.embedding import Embedding, embedding_bytes
from rhythmic_jax.map.embedding import apply as apply_embedding
from rhythmic_jax.map.groups import Groups
from rhythmic_jax.map.quantize import requantize
from rhythmic_jax.map.scalar_codes import ScalarCodeBook
from rhythmic_jax.map.storage import map_storage
from rhythmic_jax.solvers.objective import (
    Templates,
    host_templates,
    period_errors,
    targets,
)
from rhythmic_jax.solvers.protocol import solver_for
from rhythmic_jax.validate import (
    check_features,
    check_labels,
    check_number,
    check_sequence,
)

__all__ = ["MapConfig", "RhythmicMap"]

log = logging.getLogger(__name__)


class RhythmicMap:
    """A place-recognition map stored as r groups of periodic linear templates."""

    def __init__(
        self,
        config: MapConfig | None = None,
        *,
        embedding: Embedding | None = None,
        **kwargs: Any,
    ):
        self.config = replace(config or MapConfig(), **kwargs)
        # applied to the reference frames and to every query (saved with the map)
        self.embedding = embedding
        self.params: Templates | None = None
        self._stored: dict[str, np.ndarray] = {}  # the templates as saved
        self.n: int | None = None
        self.d: int | None = None
        self.periods: tuple[int, ...] = ()
        self.groups: Groups | None = None
        self.candidates: tuple[int, ...] = ()
        self.candidate_errors: tuple[float, ...] = ()
        self.c: float | None = None
        self.group_errors: tuple[float, ...] = ()
        self.extra: dict[str, np.ndarray] = {}
        self.codebook: CodeBook | ScalarCodeBook | None = None
        # where the reference frames came from (paths, tiling), not the frames:
        # ``rhythmic-jax evaluate`` reads them again for its brute-force line
        self.reference: dict[str, Any] = {}
        self._small: SmallDecoder | None = None  # numpy decode of these params

    # ------------------------------------------------------------------ fit
    def fit(
        self,
        x,
        labels=None,
        *,
        verbose: int = 0,
        progress: bool | None = None,
        refine=None,
        plan: FitPlan | None = None,
    ) -> RhythmicMap:
        """Train on reference frames x (n_frames, d).

        Args:
          verbose: 0 (default) is quiet; 1 shows the solver's progress bar
            (``TQDM_DISABLE=1`` hides it still), as ``rhythmic-jax fit`` does.
          progress: the same as a bool (overrides ``verbose`` when given).
          labels: (n_frames,) place of each frame (default: its row), so several
            traversals of one route share templates (multi-exemplar map).
          refine: optional ``refine(params, candidates, c) -> params`` run after
            the exact solve and before the period choice (e.g. minibatch steps
            over augmented frames, :func:`rhythmic_jax.augment.stream.fit_augmented`).
          plan: the fit's plan when made already
          (:func:`rhythmic_jax.fitting.fit_plan.plan`
            of this map's config for these places and the templates' d), its
            memory checked
            (:meth:`~rhythmic_jax.fitting.fit_plan.FitPlan.check_memory`).
        """
        progress = bool(verbose) if progress is None else bool(progress)
        x = check_features(x, "reference features")
        labels = check_labels(np.arange(len(x)) if labels is None else labels, len(x))
        d_in = int(x.shape[1])
        if self.embedding is not None:
            x = apply_embedding(self.embedding, x)
        cfg = self.config
        n, d = int(labels.max()) + 1, int(x.shape[1])
        if plan is None:  # else planned, and its memory checked, by the caller
            plan = plan_fit(cfg, n, d)
            plan.check_memory(len(x))
        elif (plan.n, plan.d) != (n, d):
            raise ValueError(f"a plan for {plan.n} x {plan.d}, not {n} x {d}")
        if cfg.codes is not None and not np.array_equal(labels, np.arange(len(x))):
            raise InputError("codes need one reference frame per place, in order")
        trained, c = plan.trained, plan.c
        log.info("fitting %s on %d x %d, C=%.3g", plan.describe(), *x.shape, c)
        log.info("compile options %s", compile_options(jax.default_backend()))
        solver = solver_for(cfg.solver, cfg.gap, progress)
        params, _ = solver.run(None, x, targets(labels, trained), c)
        if refine is not None:
            params = refine(params, trained, c)
        params = host_templates(params, x)
        # the training errors from scores on the host (float32 BLAS): no XLA program
        errors = period_errors(x @ params.w + params.b, labels, trained)
        kept = plan.keep(params, errors, cfg.dtype)
        if cfg.codes is not None:  # planned: bits within the templates' d
            self.codebook = (CodeBook.fit(x, cfg.codes) if cfg.codes != INT8
                             else ScalarCodeBook.fit(x))  # fmt: skip
        return self._take(kept, d_in)

    def _take(self, kept, d: int) -> RhythmicMap:
        """Hold the templates and record of ``kept`` (a fit's :class:`Kept` or a
        loaded :class:`~rhythmic_jax.map.map_file.MapFile`), fitted on d-dim frames."""
        self._set_stored(kept.stored, kept.params)
        self.groups, self.periods = kept.groups, kept.periods
        self.n, self.d, self.c = kept.n, d, float(kept.c)
        self.candidates, self.candidate_errors = kept.candidates, kept.candidate_errors
        self.group_errors = kept.group_errors
        return self

    def with_dtype(self, dtype: str) -> RhythmicMap:
        """A copy of this fitted map storing its templates as ``dtype`` (from the
        values it stores now: requantize a float32 map, not a float16 one)."""
        self._check_fitted()
        other = RhythmicMap(replace(self.config, dtype=dtype))
        skip = ("config", "params", "_stored")
        other.__dict__.update({k: v for k, v in vars(self).items() if k not in skip})
        other._set_stored(*requantize(self._stored, dtype))
        return other

    def _set_stored(self, stored: dict[str, np.ndarray], params) -> None:
        """Keep the stored arrays and their float32 values (w, b) queries use."""
        self._stored = stored
        # device_put: a transfer, where jnp.asarray compiles a program
        self.params = Templates(*(jax.device_put(v) for v in params))

    # -------------------------------------------------------------- queries
    def _check_fitted(self) -> None:
        if self.params is None:
            raise InputError("this map is not fitted yet: call fit() or load() first")

    def _queries(self, q) -> np.ndarray:
        """Checked (b, d) queries of a fitted map, in host memory (the bucketed
        decodes pad them there, :mod:`rhythmic_jax.decoding.batch`)."""
        self._check_fitted()
        q = check_features(q, "queries", d=self.d)
        if self.embedding is not None:
            q = apply_embedding(self.embedding, q)
        return q

    def scores(self, q) -> jax.Array:
        """Decision values of queries (b, d) -> (b, sum(periods))."""
        return map_scores(self.params, self._queries(q))

    def place_scores(self, q) -> jax.Array:
        """Score of every place for queries (b, d) -> (b, n): the map's summed phase
        scores, or with codes the fused z-scores
        (:mod:`rhythmic_jax.decoding.fusion`)."""
        return place_scores_map(self, self._queries(q))

    def decode(self, q, method: str | None = None, m: int | None = None) -> Decoded:
        """Decode queries (b, d): index (-1 no match), score, runner-up, confidence.

        A map with codes fuses its place scores with the code similarities
        (``hard`` then scores every place, as ``soft``;
        :func:`rhythmic_jax.decoding.queries.decode_map`).
        """
        method, m = method or self.config.decode, m or self.config.m
        return decode_map(self, self._queries(q), method, m)

    def _few_places(self, q, method: str) -> np.ndarray | None:
        """:func:`rhythmic_jax.decoding.queries.few_places` of this map."""
        return few_places(self, q, method)

    def locate(self, q) -> int:
        """Place of one descriptor ``q`` (d,), -1 for no match:
        ``predict(q[None])[0]`` with nothing around it. For the paper's hard
        decode (no threshold, codes or embedding) a float32 (d,) numpy array
        goes straight to one BLAS product (no dispatch, no copies; a NaN or inf
        is caught on its scores); anything else takes ``predict``'s checks."""
        found = locate_fast(self, q)
        if found is not None:
            return found
        self._check_fitted()
        return int(self.predict(one_query(q, self.d))[0])

    def _small_decoder(self) -> SmallDecoder:
        """The numpy decoder of the current templates (rebuilt when they change)."""
        small = self._small
        if small is None or small.params is not self.params:
            small = SmallDecoder.build(self.params, self.periods, self.n)
            self._small = small
        return small

    def predict(
        self,
        q,
        method: str | None = None,
        *,
        m: int | None = None,
        sequence: int | None = None,
        speeds: tuple[float, ...] = (1.0,),
        threshold: float | None = None,
    ) -> np.ndarray:
        """Place index of every query (b,), -1 for no match.

        Args:
          q: (b, d) queries (consecutive frames of a traversal when ``sequence``).
          method: "hard" (paper), "soft" or "topm"; default from the config.
          sequence: decode each frame with the L previous ones in the phase
            domain (:mod:`rhythmic_jax.decoding.sequence`; mixed-radix and
            hierarchical maps sum place scores instead); None (or 1) for single
            frames; at most b.
          speeds: map frames per query frame tried by the sequence decode.
          threshold: reject queries whose confidence is below it (finite).
        """
        method = method or self.config.decode
        thr = self.config.threshold
        if threshold is not None:
            thr = check_number(threshold, "{opt:threshold}")
        sequence = check_sequence(sequence)
        if sequence is not None and sequence > 1:  # embedded once here; single
            q = self._queries(q)  # frames go to decode
        if sequence is not None:
            check_sequence(sequence, len(q))
        if sequence is not None and sequence > 1:
            m = m or self.config.m
            idx, conf = sequence_map(self, q, sequence, speeds, method, m)
        else:
            few = self._few_places(q, method) if thr is None else None
            if few is not None:
                return few
            out = self.decode(q, method, m)
            idx, conf = out.index, out.confidence
        idx = np.asarray(idx).astype(np.int64)
        if thr is not None:
            idx = np.where(np.asarray(conf, np.float64) >= thr, idx, -1)
        return idx

    # -------------------------------------------------------------- storage
    @property
    def template_d(self) -> int:
        """Dimension of the templates: the embedding's k, else the input d."""
        return self.d if self.embedding is None else self.embedding.k

    @property
    def storage_bytes(self) -> int:
        """Bytes of the templates in their dtype and of any codes (:meth:`storage`);
        an embedding is counted apart (:attr:`embedding_bytes`)."""
        return self.storage()["total"]

    @property
    def embedding_bytes(self) -> int:
        """Bytes of the embedding's parameters (0 without one; do not grow with N)."""
        return 0 if self.embedding is None else embedding_bytes(self.embedding)

    def storage(self) -> dict[str, Any]:
        """Bytes split into a fixed part (the code transform), a per-place part
        (the codes) and a per-period part (``tau`` templates each, stored dtype);
        ``embedding`` is shown apart, and ``share`` counts everything against the
        n x d float32 database (:func:`rhythmic_jax.map.storage.map_storage`)."""
        self._check_fitted()
        return map_storage(
            self.groups.kind, self.groups.sizes, self.template_d, self.config.dtype,
            self.n, self.d, self.codebook and self.codebook.storage(),
            self.embedding_bytes,
        )  # fmt: skip

    @property
    def compression_ratio(self) -> float:
        """Bytes search needs (embedding included) over the n x d float32 database."""
        return self.storage()["share"]

    def info(self) -> dict[str, Any]:
        """What ``rhythmic-jax info --json`` prints
        (:func:`rhythmic_jax.map.map_file.describe`)."""
        self._check_fitted()
        return map_file.describe(self)

    # ----------------------------------------------------------------- disk
    def save(self, path: str | os.PathLike) -> None:
        """Save to the folder ``path`` (atomic; the format:
        :mod:`rhythmic_jax.map.map_file`)."""
        self._check_fitted()
        map_file.save(path, self)

    @classmethod
    def load(
        cls,
        path: str | os.PathLike,
        *,
        descriptor: str | None = None,
        descriptor_settings: dict | None = None,
        d: int | None = None,
    ) -> RhythmicMap:
        """Load a map; refuse it when it was built for another descriptor or d."""
        got = map_file.load(
            path, MapConfig, descriptor=descriptor,
            descriptor_settings=descriptor_settings, d=d,
        )  # fmt: skip
        self = cls(got.config, embedding=got.embedding)._take(got, got.d)
        self.extra, self.codebook = got.extra, got.codebook
        self.reference = got.reference
        return self
