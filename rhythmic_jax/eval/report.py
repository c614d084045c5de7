"""A map judged on queries, beside exact brute-force search on the same descriptors.

:func:`evaluate_map` gives what ``rhythmic-jax evaluate`` prints: accuracy (exact
and within a frame tolerance), recall@1/5/10/20 (the map ranks places by their
summed phase scores), PR-AUC and recall at 100 % precision, storage and
compression, single-query latency and batch throughput; and the same, when the
reference descriptors are at hand, for faiss ``IndexFlatIP`` (brute force), for
a representation at the map's own bytes and, for an embedded map, for brute
force on the embedding (:mod:`rhythmic_jax.eval.budget_peers`). Every row is
timed alike by :func:`rhythmic_jax.eval.timing.query_latency`, from the query
descriptors to a place, and every share is over one database: the reference
frames brute force searches (all traversals), else one float32 frame a place.
Ground truth is index-aligned (query i is place i) unless given.
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from rhythmic_jax.decoding.group_decode import place_scores
from rhythmic_jax.errors import InputError
from rhythmic_jax.eval.budget_peers import at_bytes, on_embedding
from rhythmic_jax.eval.method_scores import KS, method_scores
from rhythmic_jax.eval.metrics import recall_line
from rhythmic_jax.eval.model_frontier import code_similarity, model_frontier
from rhythmic_jax.eval.outliers import finite_confidence
from rhythmic_jax.eval.peer_rows import brute_places, peer_row, sequence_peers
from rhythmic_jax.eval.report_text import format_evaluation as format_evaluation
from rhythmic_jax.eval.timing import query_latency
from rhythmic_jax.jit_options import jit
from rhythmic_jax.map.checks import check_decode
from rhythmic_jax.map.groups import Groups
from rhythmic_jax.map.periods import database_bytes, place_columns

__all__ = ["evaluate_map", "format_evaluation", "ranked_places"]


@functools.partial(jit, static_argnames=("periods", "n", "k"))
def _ranked(scores: jax.Array, periods: tuple[int, ...], n: int, k: int) -> jax.Array:
    cols = place_columns(periods, n)
    total = jnp.sum(scores[:, cols], axis=1)  # (b, n)
    return jax.lax.top_k(total, k)[1]


def ranked_places(scores, periods, n: int, k: int = 10) -> np.ndarray:
    """The k best places by ``sum_k s_k[i mod tau_k]``: (b, p) -> (b, k) indices.

    ``periods`` may be a map's :class:`~rhythmic_jax.map.groups.Groups` (then the
    summed evidence of every group,
    :func:`rhythmic_jax.decoding.group_decode.place_scores`).
    """
    if isinstance(periods, Groups) and periods.kind != "periods":
        # jitted sums; the ranking on the host (top_k's order: ties by index)
        total = np.asarray(place_scores(scores, periods, n))
        return np.argsort(-total, axis=1, kind="stable")[:, : min(k, n)]
    periods = tuple(int(t) for t in getattr(periods, "sizes", periods))
    scores = scores if isinstance(scores, jax.Array) else jax.device_put(scores)
    return np.asarray(_ranked(scores, periods, int(n), min(k, n)))



def map_label(model) -> str:
    """What a map's row measures: the map, the map and its codes fused, or, at
    a fusion weight of 0, its codes alone (at 1, its templates alone)."""
    if model.codebook is None:
        return "map"
    w = float(model.config.fusion)
    return "codes alone" if w == 0 else "map" if w == 1 else "map + codes"


def _hybrid_decisions(model, queries, method, sequence):
    """A map with codes: confidence and places ranked by the fused scores, over
    the sequence when one is asked for (as its decode fuses them)."""
    from rhythmic_jax.decoding.fusion import (
        code_sequence_scores,
        fused_place_scores,
        fused_sequence_decode,
    )
    from rhythmic_jax.decoding.sequence import sequence_scores

    if sequence is None or sequence <= 1:
        conf = model.decode(queries, method).confidence
        return conf, np.asarray(model.place_scores(queries)), "fused place scores"
    s, sims = model.scores(queries), code_similarity(model, queries)
    w, per = model.config.fusion, model.periods
    _, conf = fused_sequence_decode(
        s, sims, per, model.n, sequence, (1.0,), w, method, model.config.top
    )
    acc = sequence_scores(s, per, sequence)
    total = fused_place_scores(acc, code_sequence_scores(sims, sequence), per,
                               model.n, w)  # fmt: skip
    return conf, np.asarray(total), f"fused sequence scores (L={sequence}, speed 1)"


def _map_decisions(model, queries, method, sequence, depth: int = max(KS)):
    """(pred (b,), confidence (b,), ranked places (b, K), what recall@K ranks);
    K = ``depth`` (at most the map's places)."""
    pred = model.predict(queries, method, sequence=sequence)
    method = method or model.config.decode
    if model.codebook is not None:
        conf, total, which = _hybrid_decisions(model, queries, method, sequence)
        ranked = np.argsort(-total, axis=1, kind="stable")[:, : min(depth, model.n)]
        return pred, finite_confidence(conf), ranked, which
    s = model.scores(queries)
    if sequence is not None and sequence > 1:
        from rhythmic_jax.decoding.sequence import sequence_decode, sequence_scores

        _, conf = sequence_decode(
            s, model.groups, model.n, sequence, (1.0,), method, model.config.top
        )
        if model.groups.kind == "periods":
            s = sequence_scores(s, model.periods, sequence)
            which = f"sequence scores (L={sequence}, speed 1)"
        else:  # place-domain sequences keep no per-group scores to rank
            which = "single-frame scores"
    else:
        conf = model.decode(queries, method).confidence
        which = "single-frame scores"
    ranked = ranked_places(s, model.groups, model.n, depth)
    return pred, finite_confidence(conf), ranked, which


def evaluate_map(
    model,
    queries: np.ndarray,
    *,
    reference: np.ndarray | None = None,
    reference_labels: np.ndarray | None = None,
    gt: np.ndarray | None = None,
    tolerance: int = 0,
    method: str | None = None,
    sequence: int | None = None,
    timing: bool = True,
    ground_truth=None,
    curves: bool = False,
    recall_over: str = "matched",
    recall_values: tuple[int, ...] = KS,
) -> dict[str, Any]:
    """Score a fitted :class:`~rhythmic_jax.RhythmicMap` on (b, d) queries.

    Every metric follows one ground truth (:mod:`rhythmic_jax.eval.ground_truth`):
    ``ground_truth`` when given (several right places per query), else the
    index alignment ``gt`` (default ``arange``) with ``tolerance`` frames.
    The map's recall@K ranks places by their summed phase scores, accumulated
    over the sequence when ``sequence`` is set (``result["recall_ranks"]``
    says which); its PR curve thresholds the decode's confidence, brute
    force's the inner product of the best match (single frames).

    Args:
      reference: the (m, d) reference descriptors, for the brute-force line.
      reference_labels: (m,) place of each reference row (several traversals);
        default ``arange(m)``.
      gt: (b,) true place of each query (-1: not in the map); default ``arange``.
      tolerance: frames of slack for the tolerant accuracy and recall@K.
      method, sequence: decode options passed to ``predict``.
      timing: measure latency and throughput.
      ground_truth: a :class:`~rhythmic_jax.eval.ground_truth.GroundTruth`.
      curves: keep, for the figures, each method's PR curve (``"pr_curve"``),
        recall at every N = 1..20 (``"recall_curve"``), ``"predictions"``,
        ``"confidence"`` and ``"correct"`` per query, and the right places of
        each query (``result["right_places"]``).
      recall_over: recall@K's denominator, ``"matched"`` (the queries with a
        right place, VPR_Tutorial's) or ``"all"`` (every query,
        VPR-methods-evaluation's); said in the result (``"recall_over"``,
        ``"recall_queries"``). The PR curve's recall is out of the matched
        queries either way (VPR_Tutorial's ``createPR``).
      recall_values: the K of recall@K (those above the map's places left out;
        ``result["recall_values"]`` says which).
    """
    from rhythmic_jax.eval.ground_truth import from_indices

    queries = np.asarray(queries, np.float32)
    exact = None
    if ground_truth is None:
        gt = np.arange(len(queries)) if gt is None else np.asarray(gt)
        truth = from_indices(gt, model.n, tolerance)
        exact = from_indices(gt, model.n, 0)
    else:
        truth = ground_truth
    if len(truth) != len(queries):
        raise InputError(
            f"{len(queries)} queries but the ground truth ({truth.source}) has "
            f"{len(truth)}"
        )
    check_decode(model.value, "soft", len(queries), at_once=True)  # the ranking
    # one database for every share: the frames brute force searches (all the
    # traversals), else one float32 frame per place
    frames = model.n if reference is None else len(reference)
    db = database_bytes(frames, model.d, 4)
    ratio = (model.storage_bytes + model.embedding_bytes) / db
    depth = max(max(recall_values), max(KS))
    pred, conf, ranked, which = _map_decisions(model, queries, method, sequence, depth)
    ks = tuple(k for k in recall_values if k <= ranked.shape[1])
    rows: dict[str, Any] = {
        "map": {
            **method_scores(pred, conf, ranked, truth, exact, ks, recall_over),
            "label": map_label(model),
            "storage_bytes": model.storage_bytes,
            # what a query needs: the templates, the codes and the embedding
            "storage_share": ratio,
            "codes_bits": model.codebook.bits if model.codebook is not None else None,
            "embedding_bytes": model.embedding_bytes,
            "periods": list(model.periods),
            "layout": model.groups.describe(),
        }
    }
    if timing:
        rows["map"].update(query_latency(lambda q: model.predict(q, method), queries))
    brute = None
    if reference is not None and sequence is not None and sequence > 1:
        rows.update(
            sequence_peers(
                reference,
                reference_labels,
                queries,
                model.n,
                sequence,
                truth,
                exact,
                ks,
                timing,
                recall_over,
            )  # fmt: skip
        )
    elif reference is not None:
        from rhythmic_jax.eval.baselines import BruteForce

        flat = BruteForce().fit(reference)
        sims, top = flat.search(queries, max(ks))
        if reference_labels is not None:
            top = np.asarray(reference_labels)[top]
        brute = top[:, 0]
        rows["brute force"] = {
            **method_scores(top[:, 0], sims[:, 0], top, truth, exact, ks, recall_over),
            "storage_bytes": flat.storage_bytes,
        }
        if timing:
            rows["brute force"].update(
                query_latency(brute_places(flat, reference_labels), queries)
            )
    notes = []
    if reference is not None:
        budget = model.storage_bytes + model.embedding_bytes
        peers = [at_bytes(reference, budget)]
        if model.embedding is not None:
            peers.append(on_embedding(model, reference))
        for peer in peers:
            if isinstance(peer, str):  # none fits the map's bytes
                notes.append(peer)
                continue
            notes.append(peer.note)
            rows[peer.name] = peer_row(
                peer, queries, reference_labels, model.n, sequence, truth, exact,
                ks, recall_over, timing,
            )  # fmt: skip
    for row in rows.values():
        row["recall_line"] = recall_line(row, ks)
        precision, recall = row.pop("_pr")
        route = row.pop("_route")
        if curves:
            row["pr_curve"] = {
                "precision": precision.tolist(),
                "recall": recall.tolist(),
            }
            row.update(route)
    out = {
        "n": model.n,
        "d": model.d,
        "n_queries": len(queries),
        "tolerance": tolerance if ground_truth is None else None,
        "ground_truth": truth.describe(),
        "decode": method or model.config.decode,
        "sequence": sequence,
        "recall_ranks": which,
        "recall_over": recall_over,
        "recall_queries": rows["map"]["recall_queries"],
        "recall_values": list(ks),
        "database_bytes": db,
        "database_frames": frames,
        "compression_ratio": ratio,
        "methods": rows,
        "peer_notes": notes,
    }
    if curves:  # the right places of each query, for the route's figures
        out["right_places"] = [np.asarray(p).astype(int).tolist()
                               for p in truth.positives]  # fmt: skip
    if curves and model.codebook is not None:  # recall per byte, for the plot
        out["frontier"] = model_frontier(
            model, queries, pred, truth, sequence, brute, db
        )
    return out


