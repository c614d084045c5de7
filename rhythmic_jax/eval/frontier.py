"""Recall per byte: maps, binary codes and hybrids on the same places.

:func:`frontier_rows` fits, on reference descriptors of the scored places, maps
(r = 2 and 3 at several levels), ITQ codes (64 .. 512 bits, the transform fitted
on the references) and every map + code pair (a hybrid,
:mod:`rhythmic_jax.decoding.fusion`), and reports recall@1 within a tolerance
against the bytes each needs (the codes' transform counted), for single frames
and sequences at velocity 1, beside brute force on the raw descriptors. Each row
names its sequence scorer (:data:`SEQUENCE_SCORERS`): a map accumulates its scores
in the phase domain (:func:`rhythmic_jax.decoding.sequence.sequence_decode`);
codes and brute force sum their per-frame z-scored similarities along the diagonal
(:func:`rhythmic_jax.decoding.fusion.code_sequence_scores`); a hybrid fuses the
two; the SeqSLAM row is SeqSLAM on the raw descriptors. The hybrids' fusion
weights are learned on *training* places (their own maps, codes and queries),
never on the scored queries; without training places a fixed 0.5 is used. PCA
codes (:mod:`rhythmic_jax.eval.frontier_pca`, float32 and int8) are the field's
usual compression baseline beside them.

Every row but SeqSLAM is timed alike (:func:`latency`, :data:`LATENCY`): from
the query descriptors (b, d) to a place, one query alone and the whole batch,
by :func:`rhythmic_jax.eval.metrics.query_latency`. A map is timed as
:func:`rhythmic_jax.decoding.queries.predict` answers (template product, then
the soft decode), a hybrid with its codes' encoding and the fusion, codes with
their encoding, brute force as faiss's exact search.

:func:`projected_bytes` and :func:`crossover_n` give the same byte counts for any
N: a map keeps r pairwise co-prime periods from ``level * ceil(N^(1/r))`` up
(the least-sum choice of :func:`rhythmic_jax.map.periods.choose_periods`), ``sum(tau)
(d + 1) 4`` bytes; a code needs ``N ceil(bits/8) + (bits d + d) 4``.
"""

from __future__ import annotations

import functools
import hashlib
import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import jax
import numpy as np

from rhythmic_jax.decoding.fusion import (
    code_sequence_scores,
    fused_decode,
    fused_place_scores,
    fused_sequence_decode,
    learn_weight,
)
from rhythmic_jax.decoding.sequence import sequence_decode
from rhythmic_jax.decoding.soft import soft_decode
from rhythmic_jax.errors import InputError
from rhythmic_jax.eval.metrics import pr_points
from rhythmic_jax.eval.timing import query_latency
from rhythmic_jax.io.atomic import atomic_path
from rhythmic_jax.io.reader import load_npz
from rhythmic_jax.map.codes import CodeBook, code_bytes
from rhythmic_jax.map.periods import candidate_periods, choose_periods, database_bytes
from rhythmic_jax.map.periods import storage_bytes as map_bytes
from rhythmic_jax.map.quantize import template_bytes

__all__ = [
    "FrontierConfig",
    "LATENCY",
    "SEQUENCE_SCORERS",
    "budget_table",
    "trainable",
    "crossover_n",
    "fitted_codes",
    "fitted_map",
    "fitted_model",
    "frontier_rows",
    "pareto_front",
    "choose",
    "projected_bytes",
    "latency",
    "projection_rows",
    "ranked_recalls",
    "recall_at_full_precision",
    "similarity_recalls",
]

log = logging.getLogger(__name__)

#: The sequence scorer of each kind of row (the rows' ``sequence_scorer``).
SEQUENCE_SCORERS = {
    "brute force": "diagonal sum",
    "SeqSLAM": "SeqSLAM",
    "map": "phase domain",
    "codes": "diagonal sum",
    "hybrid": "phase domain + diagonal sum, fused",
}


@dataclass(frozen=True)
class FrontierConfig:
    """What :func:`frontier_rows` measures.

    ``python scripts/bench_recall.py per-byte`` uses the defaults on the Nordland
    split (summer references, winter queries, EfficientNet-Lite0);
    ``rhythmic-jax frontier`` adds float16 maps, product quantisation
    (``pq``: numbers of 8-bit sub-quantisers) and int8 per place (``scalar``).
    """

    maps: tuple[tuple[int, int], ...] = tuple(
        (r, level) for r in (2, 3) for level in (1, 2, 3, 4)
    )
    bits: tuple[int, ...] = (64, 128, 256, 512)
    lengths: tuple[int, ...] = (1, 5, 10)
    tolerance: int = 1
    gap: float = 5e-4
    weight: float = 0.5
    dtypes: tuple[str, ...] = ("float32", "int8")
    pq: tuple[int, ...] = ()  # faiss product quantisers: sub-vectors of 8 bits
    scalar: bool = False  # int8 per place (rhythmic_jax.map.scalar_codes)
    # PCA axes kept (float32 and int8 codes each); None: a few spanning the
    # maps' bytes (rhythmic_jax.eval.frontier_pca.pca_dims); (): no PCA rows
    pca: tuple[int, ...] | None = None
    # the K of recall@K on single frames (rows' ``recall@K L=1``, K > 1)
    recall_values: tuple[int, ...] = (1, 5, 10, 20)


def pq_bits(n: int) -> int:
    """Bits of each PQ sub-quantiser on ``n`` places: 8, or fewer where the route
    has fewer than 256 frames to train the k-means of ``2**bits`` centroids."""
    return min(8, int(np.log2(n))) if n >= 2 else 0


def _listed(what: str, values, why: str) -> str:
    return f"{what} {', '.join(str(v) for v in values)}: skipped ({why})"


def trainable(
    config: FrontierConfig, n: int, d: int
) -> tuple[FrontierConfig, list[str]]:
    """The part of ``config`` that can be trained on ``n`` places of ``d``
    features, and one note per kind of representation left out.

    Checked before faiss sees them: ITQ of more bits than ``min(n, d)`` (its PCA
    has one axis per frame and per dimension; faiss would stop in
    ``PCAMatrix::prepare_Ab``), PQ whose sub-quantisers do not divide ``d``, and
    PQ on fewer than 2 places (no centroid to learn). PQ on fewer than 256
    places keeps ``pq_bits(n)``-bit sub-quantisers, and says so.
    """
    notes: list[str] = []
    most = min(n, d)
    bits = tuple(b for b in config.bits if b <= most)
    if len(bits) < len(config.bits):
        left = [b for b in config.bits if b > most]
        why = (f"ITQ keeps at most {most} bits on {n} places of {d}-d: its PCA "
               f"has {most} axes")  # fmt: skip
        notes.append(_listed("ITQ bits", left, why))
    pq = tuple(m for m in config.pq if d % m == 0 and n >= 2)
    if n < 2 and config.pq:
        notes.append(_listed("PQ", config.pq, "one place: nothing to cluster"))
    elif len(pq) < len(config.pq):
        left = [m for m in config.pq if d % m]
        notes.append(_listed("PQ", left, f"sub-quantisers must divide d = {d}"))
    if pq and pq_bits(n) < 8:
        notes.append(
            f"PQ: {pq_bits(n)}-bit sub-quantisers (the {n} places cannot train "
            "256 centroids each)"
        )
    return replace(config, bits=bits, pq=pq), notes


def _recall(idx, tol: int, truth=None) -> float:
    """Recall@1 of decisions (b,): among in-map queries, the share answered with
    a right place (``truth``: a GroundTruth; else query i is place i +- tol)."""
    return float(np.mean(_correct(idx, tol, truth)[_in_map(len(idx), truth)]))


def _in_map(b: int, truth) -> np.ndarray:
    return np.ones(b, bool) if truth is None else np.asarray(truth.in_map)


def _correct(idx, tol: int, truth=None) -> np.ndarray:
    idx = np.asarray(idx).astype(np.int64)
    if truth is not None:
        return np.asarray(truth.hits(idx))
    return (idx >= 0) & (np.abs(idx - np.arange(len(idx))) <= tol)


def recall_at_full_precision(idx, confidence, tol: int, truth=None) -> float:
    """Recall at 100 % precision (b,) decisions thresholded on ``confidence``:
    the largest share of in-map queries answered before the first wrong one
    (VPR_Tutorial's single-best-match PR curve, :func:`pr_points`)."""
    idx, conf = np.asarray(idx), np.asarray(confidence, np.float64)
    finite = np.isfinite(conf)
    top = conf[finite].max() + 1.0 if finite.any() else 1.0
    conf = np.where(finite, conf, np.where(conf > 0, top, -top))
    keep = idx >= 0
    ok = _correct(idx, tol, truth)[keep]
    precision, recall, _ = pr_points(
        conf[keep], ok, int(_in_map(len(idx), truth).sum())
    )
    return float(recall[precision == 1.0].max())


LATENCY = (
    "one query alone: the median of up to 200 one-query calls after 20 "
    "untimed ones, from its descriptor to a place (a map's template product "
    "and decode, a code's encoding and search); q/s: the whole batch in one "
    "call (median of 3)"
)
"""What every row's ``latency_s`` and ``queries_per_s`` are, in words."""


def latency(fn, queries) -> dict:
    """The row's timing, :func:`rhythmic_jax.eval.metrics.query_latency` of
    ``fn`` (query descriptors (b, d) -> places (b,)): ``latency_s`` (one query,
    median), ``latency_p95_s``, ``queries_per_s`` (the batch in one call) and
    ``batch_s``."""
    got = query_latency(fn, np.asarray(queries, np.float32))
    return {
        "latency_s": got["latency_median_s"],
        "latency_p95_s": got["latency_p95_s"],
        "queries_per_s": got["queries_per_s"],
        "batch_s": got["batch_s"],
    }


def similarity_recalls(sims, lengths, tol, truth=None) -> dict[int, float]:
    """Recall@1 of place similarities (b, n) of consecutive queries (query i is
    place i, or ``truth``) per sequence length, summed along the diagonal."""
    out = {}
    for length in lengths:
        acc = sims if length == 1 else code_sequence_scores(sims, length)
        out[length] = _recall(np.asarray(acc).argmax(1), tol, truth)
    return out


def ranked_recalls(total, ks, tol: int, truth=None) -> dict[str, float | None]:
    """Recall@K of the places ranked by ``total`` (b, n) scores, best first, for
    every K > 1 of ``ks`` up to n: ``{"recall@K L=1": ...}`` over the in-map
    queries (``truth``: a GroundTruth; else query i is place i +- tol); None
    where no query has a right place."""
    from rhythmic_jax.eval.ground_truth import from_indices, gt_recall_at_k

    total = jax.numpy.asarray(total)
    b, n = total.shape
    ks = tuple(k for k in ks if 1 < k <= n)
    if not ks:
        return {}
    if truth is None:
        truth = from_indices(np.arange(b), n, tol)
    if not truth.in_map.any():
        return {f"recall@{k} L=1": None for k in ks}
    ranked = np.asarray(jax.lax.top_k(total, max(ks))[1])
    got = gt_recall_at_k(ranked, truth, ks)
    return {f"{key} L=1": v for key, v in got.items()}


def _similarity_extra(sims, tol, truth, search=None, queries=None, ks=()) -> dict:
    """R@100p (top similarity as confidence), recall@K of ``ks``
    (:func:`ranked_recalls`) and the :func:`latency` of ``search`` (query
    descriptors -> places) on ``queries``."""
    sims = np.asarray(sims)
    idx = sims.argmax(1)
    conf = sims[np.arange(len(sims)), idx]
    out = {"recall@100p": recall_at_full_precision(idx, conf, tol, truth)}
    out |= ranked_recalls(sims, ks, tol, truth)
    if search is not None:
        out |= latency(search, queries)
    return out


def _fit_map(x, r, level, gap):
    """The fitted :class:`~rhythmic_jax.map.pytree.Map` (soft decode) of x."""
    from rhythmic_jax.fitting.prepare import fit_frames
    from rhythmic_jax.map.config import MapConfig

    return fit_frames(x, MapConfig(r=r, level=level, gap=gap, decode="soft"))


def _since(t: float) -> float:
    return time.perf_counter() - t


def _cached(cache, key: str, make, read=None):
    """``make()``'s dict of arrays, kept as ``cache/key.npz`` when cache is set;
    an entry ``read`` (or :func:`load_npz`) refuses is made again and replaced."""
    read = read or (lambda got: got)
    if cache is None:
        return read(make())
    path = Path(cache) / f"{key}.npz"
    if path.exists():
        try:
            return read(load_npz(path))
        except (InputError, ValueError, KeyError, OSError) as err:
            log.warning("%s: refused (%s); fitted again", path, err)
    out = make()
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:  # no temporary left
        np.savez(fh, **out)
    return read(out)


def _fingerprint(x: np.ndarray) -> str:
    return hashlib.sha1(np.ascontiguousarray(x).tobytes()).hexdigest()[:16]


def fitted_model(ref, r: int, level: int, gap: float, cache=None):
    """The soft-decode :class:`~rhythmic_jax.map.pytree.Map` of ref (n, d), kept
    in the ``cache`` folder (when given) as a map folder keyed by the data and
    settings, and read back through the map's own reader and meaning checks
    (:func:`rhythmic_jax.map.map_file.load`: digests, shapes, finite values): an
    entry they refuse is fitted again and replaced, never used."""
    from rhythmic_jax.map import map_file

    ref = np.asarray(ref, np.float32)
    n, d = ref.shape
    if cache is None:
        return _fit_map(ref, r, level, gap)
    path = Path(cache) / f"map-{_fingerprint(ref)}-r{r}-l{level}-g{gap:g}"
    if path.exists():
        try:
            got = map_file.load(path, d=d)
            if got.n != n:
                raise InputError(f"a map of {got.n} places, not {n}")
            return got
        except InputError as err:
            log.warning("%s: refused (%s); fitted again", path, err)
    m = _fit_map(ref, r, level, gap)
    try:
        map_file.save(path, m)
    except InputError as err:  # a damaged entry we may not replace: not kept
        log.warning("%s: not kept (%s)", path, err)
    return m


def fitted_map(ref, r: int, level: int, gap: float, cache=None):
    """``(w (d, p), b (p,), periods)`` of :func:`fitted_model`."""
    m = fitted_model(ref, r, level, gap, cache)
    return np.asarray(m.w), np.asarray(m.b), tuple(int(t) for t in m.periods)


def _checked_book(arrays, n: int, d: int, bits: int) -> CodeBook:
    """:meth:`CodeBook.from_arrays` (shapes), every float array finite."""
    for key, value in arrays.items():
        value = np.asarray(value)
        if value.dtype.kind == "f" and not np.isfinite(value).all():
            raise InputError(f"{key} holds NaN or infinite values")
    return CodeBook.from_arrays(arrays, n, d, bits)


def fitted_codes(ref, bits: int, cache=None, fit_on=None) -> CodeBook:
    """:meth:`CodeBook.fit` of ref (n, d), kept in ``cache`` like
    :func:`fitted_model` (a damaged entry is fitted again)."""
    ref = np.asarray(ref, np.float32)
    n, d = ref.shape
    tag = _fingerprint(ref)
    fit_tag = tag if fit_on is None else _fingerprint(np.asarray(fit_on, np.float32))
    return _cached(
        cache,
        f"itq-{tag}-{fit_tag}-b{bits}",
        lambda: CodeBook.fit(ref, bits, fit_on=fit_on).arrays(),
        read=lambda got: _checked_book(got, n, d, bits),
    )


def _parts(ref, queries, cfg, cache=None, tick=None):
    """Maps' scores (per stored dtype) and codes' similarities of ``queries``.

    Returns ``({(r, level, dtype): (periods, scores (b, p), bytes, Map)},
    {bits: (similarities (b, n), code book)})``; each Map stores its templates
    as ``dtype`` (:func:`rhythmic_jax.map.pytree.with_dtype`), and the scores are
    its own.
    """
    from rhythmic_jax.map.pytree import with_dtype

    d = ref.shape[1]
    maps = {}
    for r, level in cfg.maps:
        t = time.perf_counter()
        m32 = fitted_model(ref, r, level, cfg.gap, cache)
        per = tuple(int(t) for t in m32.periods)
        for dtype in cfg.dtypes:
            m = m32 if dtype == "float32" else with_dtype(m32, dtype)
            s = np.asarray(
                jax.numpy.matmul(queries, m.w, precision="highest") + m.b[None, :]
            )
            maps[(r, level, dtype)] = (per, s, template_bytes(sum(per), d, dtype), m)
        log.info("map r=%d level %d %s: %.1f s", r, level, per, _since(t))
        if tick is not None:
            tick(1)
    codes = {}
    for bits in cfg.bits:
        t = time.perf_counter()
        book = fitted_codes(ref, bits, cache)
        codes[bits] = np.asarray(book.similarity(queries)), book
        log.info("ITQ %d bits on %d frames: %.1f s", bits, len(ref), _since(t))
        if tick is not None:
            tick(1)
    return maps, codes


def _map_search(m):
    """Query descriptors (b, d) -> places (b,) of the map ``m`` as the library
    answers them (:func:`rhythmic_jax.decoding.queries.predict`, soft decode):
    the template product, then the decode."""
    from rhythmic_jax.decoding.queries import predict

    return lambda q: predict(m, q, "soft")


def _hybrid_search(m, book, n: int, weight: float):
    """Query descriptors -> places of a map + code pair: the map's template
    product, the queries' codes and their similarities, fused and decoded."""
    per = tuple(int(t) for t in m.periods)

    def search(q):
        s = jax.numpy.matmul(q, m.w, precision="highest") + m.b[None, :]
        return fused_decode(s, book.similarity(q), per, n, weight).index

    return search


def _brute_search(ref):
    """Exact inner-product search of ``ref`` (faiss ``IndexFlatIP``, as
    ``evaluate``'s brute force)."""
    import faiss

    index = faiss.IndexFlatIP(ref.shape[1])
    index.add(np.ascontiguousarray(ref, np.float32))
    return lambda q: index.search(np.ascontiguousarray(q, np.float32), 1)[1]


def _map_name(r, level, per, dtype) -> str:
    kept = "" if dtype == "float32" else f" {dtype}"
    return f"map r={r} level {level} {per}{kept}"


def frontier_rows(
    ref,
    queries,
    config: FrontierConfig = FrontierConfig(),
    *,
    train: tuple[np.ndarray, np.ndarray] | None = None,
    seqslam: bool = True,
    cache=None,
    truth=None,
    progress: bool = False,
) -> list[dict]:
    """Recall@1 against total bytes on the places of ``ref``.

    Args:
      ref: (n, d) reference descriptors of the scored places (place i in row i).
      queries: (b, d) descriptors of the places in another condition, in route
        order (query i is place i unless ``truth`` says otherwise).
      train: (reference, query) descriptors of *other* places, for the hybrids'
        fusion weights (learned per map + code pair on single frames).
      seqslam: add SeqSLAM on the raw descriptors (sequences only).
      cache: a folder where fitted templates and code books are kept.
      truth: a :class:`~rhythmic_jax.eval.ground_truth.GroundTruth` of the
        queries (default: query i is place i within ``config.tolerance``).
      progress: a bar over the representations (:mod:`rhythmic_jax.progress`).

    Returns one dict per representation: ``kind`` (brute force | SeqSLAM | map |
    codes | hybrid), ``name``, ``r``, ``level``, ``periods``, ``dtype``, ``bits``,
    ``weight``, ``storage_bytes``, ``bytes_per_place``, ``share`` (of the float32
    database), ``recall@1 L=<L>`` for every length of the config (None where not
    measured), ``sequence_scorer`` (:data:`SEQUENCE_SCORERS`; None without a
    length above 1), ``recall@100p`` (single frames, thresholded on the decode's
    confidence), and for every row but SeqSLAM the timing of :func:`latency`
    (:data:`LATENCY`): ``latency_s`` (one query alone, from its descriptor to a
    place, median; a map's float16 and int8 copies, dequantised when loaded,
    run the float32 map's program and share its timing), ``latency_p95_s``,
    ``queries_per_s`` (the whole batch in one call) and ``batch_s``. PCA rows
    (``PCA <k> <dtype>``, kind ``codes``, :mod:`rhythmic_jax.eval.frontier_pca`)
    sit beside the other codes.
    """
    from rhythmic_jax.progress import bar

    ref, queries = np.asarray(ref, np.float32), np.asarray(queries, np.float32)
    n, d = ref.shape
    b = len(queries)
    db, tol, lengths = database_bytes(n, d, 4), config.tolerance, config.lengths
    ks = config.recall_values
    lengths = tuple(k for k in lengths if k <= b)
    fits = len(config.maps) + len(config.bits)  # fitted first, then judged
    total = fits + 1 + seqslam + len(config.pq) + config.scalar
    total += len(config.maps) * len(config.dtypes) * (1 + len(config.bits))
    total += len(config.bits) + 2 * (4 if config.pca is None else len(config.pca))
    ticks = bar(total=total, show=progress, desc="frontier", unit="step")
    maps, codes = _parts(ref, queries, config, cache=cache, tick=ticks.update)
    weights = {}
    if train is not None:
        tmaps, tcodes = _parts(*train, config, cache=cache)
        gt = np.arange(len(train[1]))
        for key, (per, s, _, _) in tmaps.items():
            for bits, (sims, _) in tcodes.items():
                nt = len(train[0])
                weights[key, bits] = learn_weight(s, sims, per, nt, gt, tol)[0]
                log.info("weight %s + %d bits: %.2f", key, bits, weights[key, bits])

    def row(kind, name, size, recalls, **extra):
        out = {"kind": kind, "name": name, "storage_bytes": int(size)}
        out.update(share=size / db, bytes_per_place=size / n, **extra)
        out["sequence_scorer"] = (
            SEQUENCE_SCORERS[kind] if any(k > 1 for k in lengths) else None
        )
        out.update({f"recall@1 L={k}": recalls.get(k) for k in config.lengths})
        log.info("%s", out)
        ticks.update(1)
        return out

    def decided(idx, conf) -> dict:
        return {"recall@100p": recall_at_full_precision(idx, conf, tol, truth)}

    qj, rj = jax.numpy.asarray(queries), jax.numpy.asarray(ref)
    brute = np.asarray(jax.numpy.matmul(qj, rj.T, precision="highest"))
    rows = [
        row("brute force", "brute force", db,
            similarity_recalls(brute, lengths, tol, truth),
            **_similarity_extra(brute, tol, truth, _brute_search(ref), queries, ks))
    ]  # fmt: skip
    if seqslam:
        from rhythmic_jax.eval.seqslam import seqslam_decode

        rec = {
            k: _recall(seqslam_decode(queries, ref, k)[0], tol, truth) for k in lengths
        }
        rows.append(row("SeqSLAM", "SeqSLAM (raw descriptors)", db, rec))
    # a map's templates stored as float16 or int8 are dequantised when it is
    # loaded (rhythmic_jax.map.pytree.with_dtype): its queries run the float32
    # map's program, so one timing per r and level (and code) serves every dtype
    timed = {}
    for (r, level, dtype), (per, s, size, m) in maps.items():
        one = soft_decode(jax.numpy.asarray(s), per, n)
        rec = {1: _recall(one.index, tol, truth)}
        for k in lengths:
            if k > 1:
                seq = sequence_decode(s, per, n, k, (1.0,), "soft")[0]
                rec[k] = _recall(seq, tol, truth)
        name = _map_name(r, level, per, dtype)
        extra = dict(r=r, level=level, periods=per, dtype=dtype)
        extra |= decided(np.asarray(one.index), np.asarray(one.confidence))
        extra |= ranked_recalls(fused_place_scores(s, None, per, n), ks, tol, truth)
        if (r, level) not in timed:  # one program whatever the dtype stored
            timed[r, level] = latency(_map_search(m), queries)
        extra |= timed[r, level]
        rows.append(row("map", name, size, rec, **extra))
    for bits, (sims, book) in codes.items():
        size = code_bytes(n, d, bits)["total"]
        rec = similarity_recalls(sims, lengths, tol, truth)
        find = lambda q, book=book: book.similarity(q).argmax(1)  # noqa: E731
        extra = _similarity_extra(sims, tol, truth, find, queries, ks)
        rows.append(row("codes", f"ITQ {bits} bits", size, rec, bits=bits, **extra))
    rows += _other_codes(ref, queries, config, lengths, tol, truth, row)
    sizes = [v[2] for v in maps.values()] or [r["storage_bytes"] for r in rows[1:]]
    rows += _pca_rows(ref, queries, config.pca, sizes, lengths, tol, truth, row, ks)
    for (r, level, dtype), (per, s, msize, m) in maps.items():
        for bits, (sims, book) in codes.items():
            w = weights.get(((r, level, dtype), bits), config.weight)
            one = fused_decode(s, sims, per, n, w)
            rec = {1: _recall(one.index, tol, truth)}
            for k in lengths:
                if k > 1:
                    seq = fused_sequence_decode(s, sims, per, n, k, weight=w)[0]
                    rec[k] = _recall(seq, tol, truth)
            size = msize + code_bytes(n, d, bits)["total"]
            name = f"{_map_name(r, level, per, dtype)} + ITQ {bits}"
            extra = dict(r=r, level=level, periods=per, dtype=dtype, bits=bits)
            extra |= decided(np.asarray(one.index), np.asarray(one.confidence))
            fused = fused_place_scores(s, sims, per, n, w)
            extra |= ranked_recalls(fused, ks, tol, truth)
            if (r, level, bits) not in timed:
                timed[r, level, bits] = latency(_hybrid_search(m, book, n, w), queries)
            extra |= timed[r, level, bits]
            rows.append(row("hybrid", name, size, rec, weight=w, **extra))
    ticks.close()
    return rows


def _other_codes(ref, queries, config, lengths, tol, truth, row) -> list[dict]:
    """Product quantisation (faiss ``IndexPQ``, inner product) with
    ``config.pq`` sub-quantisers of 8 bits, and int8 per place."""
    n, d = ref.shape
    out, ks = [], config.recall_values
    for m in config.pq:
        if d % m:
            log.info("PQ %d: d = %d is not a multiple; skipped", m, d)
            continue
        import faiss

        nbits = pq_bits(n)  # k-means needs 2^nbits training points
        index = faiss.IndexPQ(d, m, nbits, faiss.METRIC_INNER_PRODUCT)
        index.train(ref)
        index.add(ref)
        sims = queries @ index.reconstruct_n(0, n).T  # the ADC inner products
        # codes, and the sub-quantisers' centroids (2^nbits of d/m floats each)
        size = n * index.code_size + 2**nbits * d * 4
        find = lambda q, index=index: index.search(q, 1)[1]  # noqa: E731
        extra = _similarity_extra(sims, tol, truth, find, queries, ks)
        rec = similarity_recalls(sims, lengths, tol, truth)
        name = f"PQ {m}x{nbits} bits"
        out.append(row("codes", name, size, rec, bits=nbits * m, **extra))
    if config.scalar:
        from rhythmic_jax.map.scalar_codes import ScalarCodeBook, scalar_code_bytes

        book = ScalarCodeBook.fit(ref)
        qj = jax.numpy.asarray(queries)
        sims = np.asarray(book.similarity(qj))
        find = lambda q: book.similarity(q).argmax(1)  # noqa: E731
        extra = _similarity_extra(sims, tol, truth, find, queries, ks)
        rec = similarity_recalls(sims, lengths, tol, truth)
        size = scalar_code_bytes(n, d)["total"]
        out.append(row("codes", "int8 per place", size, rec, bits=8 * d, **extra))
    return out


def _pca_rows(
    ref, queries, ks, sizes, lengths, tol, truth, row, recall_values=()
) -> list[dict]:
    """PCA codes (:mod:`rhythmic_jax.eval.frontier_pca`) of ``ks`` axes (None: a
    few whose bytes span ``sizes``), each at float32 and int8, where smaller than
    the float32 database itself."""
    from rhythmic_jax.eval.frontier_pca import (
        PcaCodes,
        pca_bytes,
        pca_dims,
        principal_axes,
    )

    n, d = ref.shape
    if ks is None:
        ks = pca_dims(n, d, min(sizes, default=0), max(sizes, default=0))
    ks = tuple(k for k in ks if 1 <= k <= min(n, d))
    if not ks:
        return []
    t = time.perf_counter()
    axes = principal_axes(ref, max(ks))
    log.info("PCA axes of %d frames: %.1f s", n, _since(t))
    out = []
    for k in ks:
        for dtype in ("float32", "int8"):
            if pca_bytes(n, d, k, dtype) >= database_bytes(n, d, 4):
                continue
            book = PcaCodes.fit(ref, k, dtype, axes=axes)
            sims = np.asarray(book.similarity(queries))
            extra = _similarity_extra(sims, tol, truth, book.search, queries,
                                      recall_values)  # fmt: skip
            rec = similarity_recalls(sims, lengths, tol, truth)
            bits = k * (32 if dtype == "float32" else 8)
            out.append(row("codes", f"PCA {k} {dtype}", book.bytes(), rec,
                           bits=bits, pca=k, dtype=dtype, **extra))  # fmt: skip
    return out


def pareto_front(rows: Sequence[dict], key: str = "recall@1 L=1") -> list[bool]:
    """Per row: no other row is at most as large and strictly better on ``key``
    (or as good and strictly smaller). Rows without ``key`` are never on it."""
    pts = [(r["storage_bytes"], r.get(key)) for r in rows]
    out = []
    for size, rec in pts:
        if rec is None:
            out.append(False)
            continue
        beaten = any(
            v is not None and s <= size and v >= rec and (s < size or v > rec)
            for s, v in pts
        )
        out.append(not beaten)
    return out


def choose(
    rows: Sequence[dict], bytes_per_place: float, key: str = "recall@1 L=1"
) -> dict | None:
    """The row of best ``key`` within ``bytes_per_place`` (fewest bytes on ties),
    or None when nothing fits."""
    fit = [r for r in rows if r.get(key) is not None]
    fit = [r for r in fit if r["bytes_per_place"] <= bytes_per_place]
    return max(fit, key=lambda r: (r[key], -r["storage_bytes"])) if fit else None


@functools.lru_cache(maxsize=65536)
def projected_bytes(n: int, d: int, r: int = 2, level: int = 1) -> int:
    """Bytes of a map of ``n`` places at d dims: the least-sum co-prime periods."""
    cands = candidate_periods(int(n), r, level, 7)
    per = choose_periods(cands, [0.0] * len(cands), int(n), r)
    return map_bytes(per, d)


def crossover_n(
    d: int, bits: int, r: int = 2, level: int = 1, hi: int = 10**12
) -> tuple[int | None, int | None]:
    """Where a map of N places is smaller than ``bits``-bit codes, on a log grid
    of N from 100 to ``hi`` (steps of about 1 %).

    Returns ``(until, since)``: the map is smaller for every N up to ``until``
    (small N, where the codes' fixed transform dominates; None if not at N = 100)
    and for every N from ``since`` on (None if not at ``hi``).
    """
    grid = np.unique(np.round(np.logspace(2, np.log10(hi), 1200)).astype(np.int64))
    smaller = np.array(
        [projected_bytes(int(n), d, r, level) < code_bytes(int(n), d, bits)["total"]
         for n in grid]
    )  # fmt: skip
    until = None
    if smaller[0]:
        until = int(grid[np.argmin(smaller) - 1]) if not smaller.all() else int(hi)
    since = None
    if smaller[-1]:
        last_bigger = np.flatnonzero(~smaller)
        since = int(grid[last_bigger[-1] + 1]) if last_bigger.size else int(grid[0])
    return until, since


def budget_table(
    rows: Sequence[dict], budgets: Sequence[float], length: int = 1
) -> list[dict]:
    """Per storage budget (share of the database): the best row within it, the best
    row the project's own options give (map or hybrid) and ITQ's best."""
    key = f"recall@1 L={length}"
    out = []
    for b in budgets:
        fit = [r for r in rows if r["share"] <= b and r["kind"] != "brute force"]

        def best(kinds, fit=fit):
            c = [r for r in fit if r["kind"] in kinds]
            return max(c, key=lambda r: r[key]) if c else None

        own = best(("map", "hybrid"))
        itq = best(("codes",), [r for r in fit if r["name"].startswith("ITQ")])
        out.append(
            {
                "budget": b,
                "best": best(("map", "hybrid", "codes")),
                "own": own,
                "itq": itq,
                "own_minus_itq": (own[key] if own else 0.0)
                - (itq[key] if itq else 0.0),
            }
        )
    return out


def projection_rows(
    ds: Sequence[int], ns: Sequence[int], bits: Sequence[int], rs=(2, 3)
) -> list[dict]:
    """Map bytes (level 1) for every N of ``ns`` at each d and r, and where the
    map is smaller than each code size (:func:`crossover_n`): one dict per (d, r)
    with ``map N=<N>`` and ``until <bits>`` / ``since <bits>``."""
    out = []
    for d in ds:
        for r in rs:
            row = {"d": d, "r": r}
            row.update({f"map N={n:.0e}": projected_bytes(n, d, r) for n in ns})
            for b in bits:
                row[f"until {b}"], row[f"since {b}"] = crossover_n(d, b, r)
            out.append(row)
    return out
