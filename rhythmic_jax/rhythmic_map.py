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
from dataclasses import asdict, replace
from typing import Any

import jax
import numpy as np

from rhythmic_jax import map_file
from rhythmic_jax.codes import CodeBook, fit_codebook
from rhythmic_jax.config import MapConfig
from rhythmic_jax.decoding.batch import decode_queries, sequence_queries
from rhythmic_jax.decoding.fusion import (
    fused_decode,
    fused_place_scores,
    fused_sequence_decode,
)
from rhythmic_jax.decoding.hard import Decoded
from rhythmic_jax.decoding.hard import decode as localise
from rhythmic_jax.decoding.small import SMALL_BATCH, SmallDecoder
from rhythmic_jax.embedding import Embedding, embedding_bytes
from rhythmic_jax.embedding import apply as apply_embedding
from rhythmic_jax.errors import InputError
from rhythmic_jax.fit_plan import FitPlan
from rhythmic_jax.fit_plan import plan as plan_fit
from rhythmic_jax.groups import Groups
from rhythmic_jax.objective import (
    Templates,
    period_errors,
    scores,
    targets,
)
from rhythmic_jax.periods import (
    database_bytes,
)
from rhythmic_jax.quantize import dequantize, quantize, template_bytes
from rhythmic_jax.scalar_codes import ScalarCodeBook
from rhythmic_jax.solvers.protocol import solver_for
from rhythmic_jax.validate import (
    check_features,
    check_int,
    check_labels,
    check_number,
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
          plan: the fit's plan when made already (:func:`rhythmic_jax.fit_plan.plan`
            of this map's config for these places and the templates' d), its
            memory checked (:meth:`~rhythmic_jax.fit_plan.FitPlan.check_memory`).
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
        solver = solver_for(cfg.solver, cfg.gap, progress)
        params, _ = solver.run(None, x, targets(labels, trained), c)
        if refine is not None:
            params = refine(params, trained, c)
        params = Templates(*(np.asarray(v, np.float32) for v in params))
        if not all(np.isfinite(v).all() for v in params):
            raise InputError(
                "reference features: the solve gave non-finite templates (largest "
                f"|feature| {float(np.abs(x).max()):.3g}); scale the features, "
                "e.g. to unit-length rows"
            )
        errors = period_errors(_host_scores(params, x), labels, trained)
        self._take(plan.keep(params, errors, cfg.dtype), d_in)
        if cfg.codes is not None:
            self.codebook = fit_codebook(x, cfg.codes)
        return self

    def _plan(self, n: int) -> tuple[tuple[int, ...], float]:
        """Candidate periods and the penalty C for n places
        (:func:`rhythmic_jax.fit_plan.plan`; they do not depend on d)."""
        fit_plan = plan_fit(self.config, n, self.d or 1)
        return fit_plan.candidates, fit_plan.c

    def _take(self, kept, d: int) -> RhythmicMap:
        """Hold the templates and record of ``kept`` (a
        :class:`~rhythmic_jax.fit_plan.Kept` or a loaded
        :class:`~rhythmic_jax.map_file.MapFile`), fitted on d-dim frames."""
        self._set_stored(kept.stored)
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
        w, b = dequantize(self._stored)
        other._set_stored(quantize(w, b, dtype))
        return other

    def _set_stored(self, stored: dict[str, np.ndarray]) -> None:
        """Keep the stored arrays; queries use them as float32."""
        self._stored = stored
        w, b = dequantize(stored)
        # device_put: a transfer, where jnp.asarray compiles a program
        self.params = Templates(w=jax.device_put(w), b=jax.device_put(b))

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
        return _scores(self.params, self._queries(q))

    def place_scores(self, q) -> jax.Array:
        """Score of every place for queries (b, d) -> (b, n): the map's summed phase
        scores, or with codes the fused z-scores
        (:mod:`rhythmic_jax.decoding.fusion`)."""
        q = self._queries(q)
        book, w = self.codebook, self.config.fusion
        sims = None if book is None else book.similarity(q)
        return fused_place_scores(
            _scores(self.params, q), sims, self.periods, self.n, w
        )

    def decode(self, q, method: str | None = None, m: int | None = None) -> Decoded:
        """Decode queries (b, d): index (-1 no match), score, runner-up, confidence.

        A map with codes fuses its place scores with the code similarities
        (``hard`` then scores every place, as ``soft``).
        """
        if self.codebook is not None:
            q = self._queries(q)
            if (method or self.config.decode) == "hard":
                method = "soft"
            return fused_decode(
                _scores(self.params, q),
                self.codebook.similarity(q),
                self.periods,
                self.n,
                self.config.fusion,
                method or self.config.decode,
                m or self.config.m,
            )
        self._check_fitted()
        if (method or self.config.decode) == "hard" and self.groups.kind == "periods":
            x = check_features(q, "queries", d=self.d)
            if self.embedding is not None:
                x = np.asarray(apply_embedding(self.embedding, x), np.float32)
            if len(x) <= SMALL_BATCH:  # numpy: no dispatch for a single query
                return self._small_decoder()(x)
            # host BLAS product, jitted argmaxes and look-ups
            return localise(self.params, x, self.periods, self.n)
        return decode_queries(
            self.params,
            self._queries(q),
            self.groups,
            self.n,
            method or self.config.decode,
            m or self.config.m,
        )

    def _few_places(self, q, method: str) -> np.ndarray | None:
        """Places (b,) int64 of up to :data:`SMALL_BATCH` queries by the numpy hard
        decode, one matrix-vector product each and nothing else (no runner-up,
        no dispatch); None where that decode does not apply."""
        if self.codebook is not None or method != "hard":
            return None
        self._check_fitted()
        if self.groups.kind != "periods":
            return None
        if (
            type(q) is np.ndarray
            and q.dtype == np.float32
            and q.ndim == 2
            and 0 < len(q) <= SMALL_BATCH
            and q.shape[1] == self.d
            and self.embedding is None
        ):  # the fast lane: the scores' finiteness checks the values
            small = self._small_decoder()
            found = [small.place(row) for row in q]
            if None not in found:
                return np.array(found, np.int64)
        x = check_features(q, "queries", d=self.d)
        if len(x) > SMALL_BATCH:
            return None
        if self.embedding is not None:
            x = np.asarray(apply_embedding(self.embedding, x), np.float32)
        small = self._small_decoder()
        return np.array([small.index(row) for row in x], np.int64)

    def locate(self, q) -> int:
        """Place of one descriptor ``q`` (d,), -1 for no match:
        ``predict(q[None])[0]`` with nothing around it. For the paper's hard
        decode (no threshold, codes or embedding) a float32 (d,) numpy array
        goes straight to one BLAS product (no dispatch, no copies; a NaN or inf
        is caught on its scores); anything else takes ``predict``'s checks."""
        small = self._small
        if (
            small is not None
            and small.params is self.params
            and type(q) is np.ndarray
            and q.dtype == np.float32
            and q.shape == (self.d,)
            and self.embedding is None
            and self.codebook is None
            and self.config.decode == "hard"
            and self.config.threshold is None
        ):
            found = small.place(q)
            if found is not None:
                return found
        self._check_fitted()
        try:
            x = np.asarray(q)
        except ValueError:  # ragged: predict's checks say so
            x = None
        if x is not None and x.ndim != 1:
            raise InputError(
                f"query: expected one descriptor of shape ({self.d},), "
                f"got shape {x.shape}"
            )
        return int(self.predict([q] if x is None else x[None])[0])

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
        if threshold is not None:
            threshold = check_number(threshold, "{opt:threshold}")
        if sequence is not None:
            sequence = check_int(
                sequence,
                "sequence",
                1,
                msg=f"{{opt:sequence}} length L must be "
                f"an integer >= 1, got {sequence!r}",
            )
            if sequence > 1:  # embedded once here; single frames go to decode
                q = self._queries(q)
            if sequence > len(q):
                raise InputError(
                    f"{{opt:sequence}} length L={sequence} is longer than the "
                    f"{len(q)} queries"
                )
        if sequence is not None and sequence > 1 and self.codebook is not None:
            idx, conf = fused_sequence_decode(
                _scores(self.params, q),
                self.codebook.similarity(q),
                self.periods,
                self.n,
                sequence,
                speeds,
                self.config.fusion,
                method,
                m or self.config.m,
            )
        elif sequence is not None and sequence > 1:
            idx, conf = sequence_queries(
                self.params,
                q,
                self.groups,
                self.n,
                sequence,
                speeds,
                method,
                m or self.config.m,
            )
        else:
            thr = self.config.threshold if threshold is None else threshold
            few = self._few_places(q, method) if thr is None else None
            if few is not None:
                return few
            out = self.decode(q, method, m)
            idx, conf = out.index, out.confidence
        idx = np.asarray(idx).astype(np.int64)
        thr = self.config.threshold if threshold is None else threshold
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
        """Bytes of the templates in their dtype, plus with codes their
        :meth:`storage` (ITQ: ``n * ceil(bits / 8) + (bits * d + d) * 4``; int8:
        ``n * d + 2 * d * 4``); an embedding is counted apart
        (:attr:`embedding_bytes`)."""
        return self.storage()["total"]

    @property
    def embedding_bytes(self) -> int:
        """Bytes of the embedding's parameters (0 without one; do not grow with N)."""
        return 0 if self.embedding is None else embedding_bytes(self.embedding)

    def storage(self) -> dict[str, Any]:
        """Bytes split into a fixed part (the code transform), a per-place part
        (the codes) and a per-period part (``tau`` templates each, stored dtype);
        ``embedding`` is shown apart, and ``share`` counts everything against the
        n x d float32 database."""
        self._check_fitted()
        codes = self.codebook.storage() if self.codebook else {}
        per_period = {
            (str(t) if self.groups.kind == "periods" else f"{k}:{t}"): template_bytes(
                t, self.template_d, self.config.dtype
            )
            for k, t in enumerate(self.groups.sizes)
        }
        fixed, per_place = codes.get("fixed", 0), codes.get("per_place", 0)
        total = fixed + per_place + sum(per_period.values())
        return {
            "fixed": fixed,
            "per_place": per_place,
            "per_period": per_period,
            "embedding": self.embedding_bytes,
            "total": total,
            "share": (total + self.embedding_bytes) / database_bytes(self.n, self.d, 4),
        }

    @property
    def compression_ratio(self) -> float:
        """Bytes search needs (embedding included) over the n x d float32 database."""
        self._check_fitted()
        return self.storage()["share"]

    def info(self) -> dict[str, Any]:
        """What ``rhythmic-jax info --json`` prints."""
        self._check_fitted()
        return {
            "n": self.n,
            "d": self.d,
            "periods": list(self.periods),
            "layout": self.groups.describe(),
            "groups": self.groups.to_dict(),
            "group_errors": list(self.group_errors),
            "storage_bytes": self.storage_bytes,
            "embedding_bytes": self.embedding_bytes,
            "embedding": None
            if self.embedding is None
            else {"kind": self.embedding.kind, "k": self.embedding.k},
            "database_bytes": database_bytes(self.n, self.d, 4),
            "compression_ratio": self.compression_ratio,
            "storage": self.storage(),
            "codes_bits": self.codebook.bits if self.codebook else None,
            "codes_kind": self.codebook.kind if self.codebook else None,
            "c": self.c,
            "candidates": list(self.candidates),
            "candidate_errors": list(self.candidate_errors),
            "descriptor": self.config.descriptor,
            "descriptor_settings": self.config.descriptor_settings,
            "config": {k: v for k, v in asdict(self.config).items()},
            "reference": self.reference,
        }

    # ----------------------------------------------------------------- disk
    def save(self, path: str | os.PathLike) -> None:
        """Save to the folder ``path`` (atomic; the format:
        :mod:`rhythmic_jax.map_file`)."""
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
            path,
            MapConfig,
            descriptor=descriptor,
            descriptor_settings=descriptor_settings,
            d=d,
        )
        self = cls(got.config, embedding=got.embedding)._take(got, got.d)
        self.extra, self.codebook, self.reference = (
            got.extra,
            got.codebook,
            got.reference,
        )
        return self


@jax.jit
def _scores(params: Templates, q: jax.Array) -> jax.Array:
    return scores(params, q)


def _host_scores(params: Templates, x) -> np.ndarray:
    """Scores ``x @ w + b`` (n, p) of the reference frames on the host (float32
    BLAS): a fit's training errors compile no XLA program."""
    x = np.asarray(x, np.float32)
    return x @ np.asarray(params.w, np.float32) + np.asarray(params.b, np.float32)
