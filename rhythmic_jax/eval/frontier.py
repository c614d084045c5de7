"""Recall per byte: maps, binary codes and hybrids on the same places.

:func:`frontier_rows` fits, on reference descriptors of the scored places, maps
(r = 2 and 3 at several levels), ITQ codes (64 .. 512 bits, the transform fitted
on the references) and every map + code pair (a hybrid,
:mod:`rhythmic_jax.decoding.fusion`), and reports recall@1 within a tolerance
against the bytes each needs (the codes' transform counted), for single frames
and sequences summed along the diagonal
(velocity 1), beside brute force on the raw descriptors. The hybrids' fusion
weights are learned on *training* places (their own maps, codes and queries),
never on the scored queries; without training places a fixed 0.5 is used.

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
from dataclasses import dataclass
from pathlib import Path

import jax
import numpy as np

from rhythmic_jax.decoding.fusion import (
    code_sequence_scores,
    fused_decode,
    fused_sequence_decode,
    learn_weight,
)
from rhythmic_jax.decoding.sequence import sequence_decode
from rhythmic_jax.decoding.soft import soft_decode
from rhythmic_jax.map.codes import CodeBook, code_bytes
from rhythmic_jax.map.periods import candidate_periods, choose_periods, database_bytes
from rhythmic_jax.map.periods import storage_bytes as map_bytes
from rhythmic_jax.map.quantize import dequantize, quantize, template_bytes

__all__ = [
    "FrontierConfig",
    "budget_table",
    "crossover_n",
    "fitted_codes",
    "fitted_map",
    "frontier_rows",
    "projected_bytes",
    "similarity_recalls",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FrontierConfig:
    """What :func:`frontier_rows` measures.

    ``python scripts/bench_recall_per_byte.py`` uses the defaults on the Nordland
    split (summer references, winter queries, EfficientNet-Lite0).
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


def _recall(idx, tol: int) -> float:
    idx = np.asarray(idx)
    return float(np.mean((idx >= 0) & (np.abs(idx - np.arange(len(idx))) <= tol)))


def similarity_recalls(sims, lengths, tol) -> dict[int, float]:
    """Recall@1 of place similarities (b, n) of consecutive queries (query i is
    place i) per sequence length, summed along the diagonal."""
    out = {}
    for length in lengths:
        acc = sims if length == 1 else code_sequence_scores(sims, length)
        out[length] = _recall(np.asarray(acc).argmax(1), tol)
    return out


def _fit_map(x, r, level, gap):
    """The (w (d, p), b (p,)) templates and periods of a soft-decode map of x."""
    from rhythmic_jax.rhythmic_map import RhythmicMap

    m = RhythmicMap(r=r, level=level, gap=gap, decode="soft").fit(x, progress=False)
    return np.asarray(m.params.w), np.asarray(m.params.b), tuple(m.periods)


def _since(t: float) -> float:
    return time.perf_counter() - t


def _cached(cache, key: str, make):
    """``make()``'s dict of arrays, kept as ``cache/key.npz`` when cache is set."""
    if cache is None:
        return make()
    path = Path(cache) / f"{key}.npz"
    if path.exists():
        with np.load(path, allow_pickle=False) as f:
            return dict(f)
    out = make()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, **out)
    tmp.replace(path)
    return out


def _fingerprint(x: np.ndarray) -> str:
    return hashlib.sha1(np.ascontiguousarray(x).tobytes()).hexdigest()[:16]


def fitted_map(ref, r: int, level: int, gap: float, cache=None):
    """``(w (d, p), b (p,), periods)`` of a soft-decode map of ref (n, d), kept in
    the ``cache`` folder (when given) keyed by the data and settings."""
    ref = np.asarray(ref, np.float32)

    def make():
        w, b, per = _fit_map(ref, r, level, gap)
        return {"w": w, "b": b, "periods": np.asarray(per)}

    got = _cached(cache, f"map-{_fingerprint(ref)}-r{r}-l{level}-g{gap:g}", make)
    return got["w"], got["b"], tuple(int(t) for t in got["periods"])


def fitted_codes(ref, bits: int, cache=None, fit_on=None) -> CodeBook:
    """:meth:`CodeBook.fit` of ref (n, d), kept in ``cache`` like :func:`fitted_map`."""
    ref = np.asarray(ref, np.float32)
    n, d = ref.shape
    tag = _fingerprint(ref)
    fit_tag = tag if fit_on is None else _fingerprint(np.asarray(fit_on, np.float32))
    got = _cached(
        cache,
        f"itq-{tag}-{fit_tag}-b{bits}",
        lambda: CodeBook.fit(ref, bits, fit_on=fit_on).arrays(),
    )
    return CodeBook.from_arrays(got, n, d, bits)


def _parts(ref, queries, cfg, cache=None):
    """Maps' scores (per stored dtype) and codes' similarities of ``queries``.

    Returns ``({(r, level, dtype): (periods, scores (b, p), bytes)},
    {bits: similarities (b, n)})``.
    """
    d = ref.shape[1]
    maps = {}
    for r, level in cfg.maps:
        t = time.perf_counter()
        w32, b32, per = fitted_map(ref, r, level, cfg.gap, cache)
        for dtype in cfg.dtypes:
            w, b = dequantize(quantize(w32, b32, dtype))
            s = np.asarray(
                jax.numpy.matmul(queries, w, precision="highest") + b[None, :]
            )
            maps[(r, level, dtype)] = (per, s, template_bytes(sum(per), d, dtype))
        log.info("map r=%d level %d %s: %.1f s", r, level, per, _since(t))
    codes = {}
    for bits in cfg.bits:
        t = time.perf_counter()
        book = fitted_codes(ref, bits, cache)
        codes[bits] = np.asarray(book.similarity(queries))
        log.info("ITQ %d bits on %d frames: %.1f s", bits, len(ref), _since(t))
    return maps, codes


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
) -> list[dict]:
    """Recall@1 against total bytes on the places of ``ref``.

    Args:
      ref: (n, d) reference descriptors of the scored places (place i in row i).
      queries: (n, d) descriptors of the same places in another condition.
      train: (reference, query) descriptors of *other* places, for the hybrids'
        fusion weights (learned per map + code pair on single frames).
      seqslam: add SeqSLAM on the raw descriptors (sequences only).
      cache: a folder where fitted templates and code books are kept.

    Returns one dict per representation: ``kind`` (brute force | SeqSLAM | map |
    codes | hybrid), ``name``, ``r``, ``level``, ``periods``, ``dtype``, ``bits``,
    ``weight``, ``storage_bytes``, ``share`` (of the float32 database) and
    ``recall@1 L=<L>`` for every length of the config (None where not measured).
    """
    ref, queries = np.asarray(ref, np.float32), np.asarray(queries, np.float32)
    n, d = ref.shape
    db, tol, lengths = database_bytes(n, d, 4), config.tolerance, config.lengths
    maps, codes = _parts(ref, queries, config, cache=cache)
    weights = {}
    if train is not None:
        tmaps, tcodes = _parts(*train, config, cache=cache)
        gt = np.arange(len(train[1]))
        for key, (per, s, _) in tmaps.items():
            for bits, sims in tcodes.items():
                nt = len(train[0])
                weights[key, bits] = learn_weight(s, sims, per, nt, gt, tol)[0]
                log.info("weight %s + %d bits: %.2f", key, bits, weights[key, bits])

    def row(kind, name, size, recalls, **extra):
        out = {"kind": kind, "name": name, "storage_bytes": int(size)}
        out.update(share=size / db, **extra)
        out.update({f"recall@1 L={k}": recalls.get(k) for k in lengths})
        log.info("%s", out)
        return out

    brute = np.asarray(
        jax.numpy.matmul(queries, np.asarray(ref).T, precision="highest")
    )
    rows = [
        row("brute force", "brute force", db, similarity_recalls(brute, lengths, tol))
    ]
    if seqslam:
        from rhythmic_jax.eval.seqslam import seqslam_decode

        rec = {k: _recall(seqslam_decode(queries, ref, k)[0], tol) for k in lengths}
        rows.append(row("SeqSLAM", "SeqSLAM (raw descriptors)", db, rec))
    for (r, level, dtype), (per, s, size) in maps.items():
        rec = {
            k: _recall(
                soft_decode(s, per, n).index
                if k == 1
                else sequence_decode(s, per, n, k, (1.0,), "soft")[0],
                tol,
            )
            for k in lengths
        }
        name = _map_name(r, level, per, dtype)
        extra = dict(r=r, level=level, periods=per, dtype=dtype)
        rows.append(row("map", name, size, rec, **extra))
    for bits, sims in codes.items():
        size = code_bytes(n, d, bits)["total"]
        rec = similarity_recalls(sims, lengths, tol)
        rows.append(row("codes", f"ITQ {bits} bits", size, rec, bits=bits))
    for (r, level, dtype), (per, s, msize) in maps.items():
        for bits, sims in codes.items():
            w = weights.get(((r, level, dtype), bits), config.weight)
            rec = {
                k: _recall(
                    fused_decode(s, sims, per, n, w).index
                    if k == 1
                    else fused_sequence_decode(s, sims, per, n, k, weight=w)[0],
                    tol,
                )
                for k in lengths
            }
            size = msize + code_bytes(n, d, bits)["total"]
            name = f"{_map_name(r, level, per, dtype)} + ITQ {bits}"
            extra = dict(r=r, level=level, periods=per, dtype=dtype, bits=bits)
            rows.append(row("hybrid", name, size, rec, weight=w, **extra))
    return rows


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

        own, itq = best(("map", "hybrid")), best(("codes",))
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
