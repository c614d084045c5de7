"""A map judged on queries, beside exact brute-force search on the same descriptors.

:func:`evaluate_map` gives what ``rhythmic-jax evaluate`` prints: accuracy (exact
and within a frame tolerance), recall@1/5/10/20 (the map ranks places by their
summed phase scores), PR-AUC and recall at 100 % precision, storage and
compression, single-query latency and batch throughput; and the same, when the
reference descriptors are at hand, for faiss ``IndexFlatIP`` (brute force), for
a representation at the map's own bytes and, for an embedded map, for brute
force on the embedding (:mod:`rhythmic_jax.eval.budget_peers`). Every row is
timed alike by :func:`rhythmic_jax.eval.metrics.query_latency`, from the query
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
from rhythmic_jax.eval.metrics import WARMUP, query_latency, recall_line
from rhythmic_jax.eval.outliers import finite_confidence
from rhythmic_jax.jit_options import jit
from rhythmic_jax.map.checks import check_decode
from rhythmic_jax.map.groups import Groups
from rhythmic_jax.map.periods import database_bytes, place_columns

__all__ = ["evaluate_map", "format_evaluation", "ranked_places"]

KS = (1, 5, 10, 20)
CURVE = 20  # recall at every N = 1 .. CURVE, for the figures (curves=True)


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


def _code_similarity(model, queries) -> np.ndarray:
    """The codes' similarities (b, n) of raw queries (b, d): embedded first where
    the map has an embedding, as its own decode does (its codes live there)."""
    from rhythmic_jax.decoding.queries import queries as map_queries

    return model.codebook.similarity(map_queries(model.value, queries))


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
    s, sims = model.scores(queries), _code_similarity(model, queries)
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


def _scores_of(
    pred, conf, ranked, truth, exact, ks, over="matched"
) -> dict[str, Any]:
    """Accuracy, recall@K (out of the queries ``over`` names), PR-AUC and recall
    at 100 % precision of one method."""
    from rhythmic_jax.eval.ground_truth import gt_accuracy, gt_pr_curve, gt_recall_at_k

    precision, recall, _ = gt_pr_curve(pred, conf, truth)
    row = {
        "accuracy": gt_accuracy(pred, exact if exact is not None else truth),
        "accuracy_tol": gt_accuracy(pred, truth) if exact is not None else None,
        **gt_recall_at_k(ranked, truth, ks, over),
        "recall_over": over,
        "recall_queries": int(truth.in_map.sum()) if over == "matched" else len(truth),
        "tolerance": truth.tolerance_frames
        if truth.tolerance_m is None
        else truth.tolerance_m,
        "n_queries": int(truth.in_map.sum()),
        "pr_auc": float(np.trapezoid(precision[::-1], recall[::-1])),
        "recall@100p": float(recall[precision == 1.0].max()),
    }
    row["_pr"] = (precision, recall)
    ranked = np.asarray(ranked)
    if ranked.ndim == 1:
        ranked = ranked[:, None]
    curve = gt_recall_at_k(ranked, truth, range(1, min(CURVE, ranked.shape[1]) + 1))
    row["_route"] = {  # for the figures of a route: kept with curves=True
        "recall_curve": list(curve.values()),
        "predictions": np.asarray(pred).astype(int).tolist(),
        "confidence": [float(c) if np.isfinite(c) else None
                       for c in np.asarray(conf, np.float64)],
        "correct": np.where(truth.in_map, truth.hits(np.asarray(pred, np.int64)),
                            np.asarray(pred) == -1).tolist(),
    }  # fmt: skip
    return row


def _codes_name(book) -> str:
    """A code book as the figures name it: "int8 per place" or "ITQ B bits"."""
    if getattr(book, "kind", None) == "int8":
        return "int8 per place"
    return f"ITQ {book.bits} bits"


def model_frontier(model, queries, pred, truth, sequence=None, brute=None, db=None):
    """Recall@1 against bytes for a fitted map with codes, as ``evaluate`` reports it.

    Rows as :func:`rhythmic_jax.eval.frontier.frontier_rows` gives them, for one
    length L = ``sequence`` or 1: the map's templates alone (soft decode), its
    codes alone (similarities summed along the diagonal for sequences), the
    hybrid (``pred``, the map's own decode) and, for single frames, brute force
    (``brute``: its predictions). ``db``: the bytes every share is over (the
    frames brute force searches; default one float32 frame a place).
    ``truth`` is a :class:`~rhythmic_jax.eval.ground_truth.GroundTruth`.
    """
    from rhythmic_jax.decoding.fusion import code_sequence_scores
    from rhythmic_jax.decoding.sequence import sequence_decode
    from rhythmic_jax.decoding.soft import soft_decode
    from rhythmic_jax.eval.ground_truth import gt_accuracy
    length = int(sequence) if sequence else 1
    key, n, d = f"recall@1 L={length}", model.n, model.d
    emb = model.embedding_bytes  # every part but brute force embeds its queries
    plus = " + embedding" if emb else ""
    s = model.scores(queries)
    sims = _code_similarity(model, queries)
    if length > 1:
        alone = sequence_decode(s, model.periods, n, length, (1.0,), "soft")[0]
        coded = code_sequence_scores(sims, length)
    else:
        alone, coded = soft_decode(s, model.periods, n).index, sims
    st = model.storage()
    db = database_bytes(n, d, 4) if db is None else int(db)
    w = float(model.config.fusion)
    fused = "codes alone (fusion 0)" if w == 0 else f"map + codes (fused, w={w:g})"
    parts = [
        ("map", "templates alone" + plus, sum(st["per_period"].values()) + emb, alone),
        ("codes", _codes_name(model.codebook) + " alone" + plus,
         model.codebook.storage()["total"] + emb,
         np.argmax(coded, axis=1)),
        ("hybrid", fused + plus, model.storage_bytes + emb, pred),
    ]  # fmt: skip
    if brute is not None and length == 1:
        parts.append(("brute force", "brute force", db, brute))
    return [
        {"kind": kind, "name": name, "storage_bytes": int(size),
         "share": size / db, key: gt_accuracy(np.asarray(p), truth)}
        for kind, name, size, p in parts
    ]  # fmt: skip


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
            **_scores_of(pred, conf, ranked, truth, exact, ks, recall_over),
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
            **_scores_of(top[:, 0], sims[:, 0], top, truth, exact, ks, recall_over),
            "storage_bytes": flat.storage_bytes,
        }
        if timing:
            rows["brute force"].update(
                query_latency(_brute_places(flat, reference_labels), queries)
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


def _brute_places(flat, labels):
    """Brute force's timed function: query descriptors (b, d) -> places (b,),
    each the place of its nearest reference frame."""
    lab = None if labels is None else np.asarray(labels)

    def find(q):
        top = flat.search(q, 1)[1][:, 0]
        return top if lab is None else lab[top]

    return find


def place_similarities(sims, labels, n: int) -> np.ndarray:
    """(b, m) similarities to reference frames -> (b, n), each place's best
    frame (``labels``: (m,) place of each frame; None: frame i is place i, as
    brute force's row reads them, and the (b, m) come back as they are)."""
    sims = np.asarray(sims, np.float32)
    if labels is None:
        return sims
    labels = np.asarray(labels)
    place = np.full((len(sims), n), -np.inf, np.float32)
    np.maximum.at(place.T, labels, sims.T)
    place[~np.isfinite(place)] = sims.min()
    return place


def peer_row(peer, queries, labels, n, sequence, truth, exact, ks, over="matched",
             timing=True) -> dict[str, Any]:  # fmt: skip
    """The row of a :class:`~rhythmic_jax.eval.budget_peers.Peer`: places ranked
    by their best frame's similarity (summed along the diagonal over L frames
    for a sequence, as :func:`sequence_peers` sums brute force's), the best
    place its answer and that place's score its confidence; timed from the
    query descriptors to a place."""
    from rhythmic_jax.decoding.fusion import code_sequence_scores

    place = place_similarities(peer.similarity(queries), labels, n)
    if sequence is not None and sequence > 1:
        place = np.asarray(code_sequence_scores(place, sequence))
    ranked = np.argsort(-place, axis=1, kind="stable")[:, : max(ks)]
    best = ranked[:, 0]
    row = {
        **_scores_of(
            best, place[np.arange(len(place)), best], ranked, truth, exact, ks, over
        ),
        "storage_bytes": int(peer.storage_bytes),
    }
    if timing:
        lab = None if labels is None else jnp.asarray(np.asarray(labels))

        @jit
        def find(q):  # one program: encoding, similarities, best frame, place
            top = jnp.argmax(peer.similarity(q), axis=1)
            return top if lab is None else lab[top]

        row.update(query_latency(find, jnp.asarray(queries)))
    return row


def sequence_peers(
    reference, labels, queries, n: int, length: int, truth, exact, ks, timing=True,
    over="matched",
) -> dict[str, dict[str, Any]]:
    """Brute force and SeqSLAM at sequence length L, beside the map's L.

    Brute force: inner products (b, m) of the queries with every reference
    frame, the best frame of each place kept (b, n), summed along the diagonal
    over L frames (:func:`rhythmic_jax.decoding.fusion.code_sequence_scores`, as
    :mod:`rhythmic_jax.eval.frontier` sums them); recall@K ranks those sums.
    SeqSLAM (:func:`rhythmic_jax.eval.seqslam.seqslam_decode`, velocity 1) gives
    one match per query, so only its recall@1 is reported. ``over``: recall@K's
    denominator, as :func:`evaluate_map` takes it.
    """
    from rhythmic_jax.decoding.fusion import code_sequence_scores
    from rhythmic_jax.eval.baselines import BruteForce
    from rhythmic_jax.eval.seqslam import seqslam_decode

    reference = np.asarray(reference, np.float32)
    labels = np.arange(len(reference)) if labels is None else np.asarray(labels)
    flat = BruteForce().fit(reference)
    sims = np.asarray(
        jnp.matmul(jnp.asarray(queries), jnp.asarray(reference).T, precision="highest")
    )
    place = place_similarities(sims, labels, n)  # best frame of each place
    acc = np.asarray(code_sequence_scores(place, length))  # (b, n)
    ranked = np.argsort(-acc, axis=1, kind="stable")[:, : max(ks)]
    best = ranked[:, 0]
    conf = acc[np.arange(len(acc)), best]
    rows = {
        "brute force": {
            **_scores_of(best, conf, ranked, truth, exact, ks, over),
            "storage_bytes": flat.storage_bytes,
            "ranks": f"summed place similarities (L={length}, speed 1)",
        }
    }
    idx, score = seqslam_decode(queries, reference, length)
    idx = labels[np.asarray(idx)]
    rows["SeqSLAM"] = {
        **_scores_of(idx, score, idx[:, None], truth, exact, (1,), over),
        "storage_bytes": flat.storage_bytes,
        "ranks": f"SeqSLAM (L={length}, speed 1), one match per query",
    }
    if timing:
        rows["brute force"].update(
            query_latency(_brute_places(flat, labels), queries)
        )
    return rows


def _database_words(result: dict[str, Any]) -> str:
    """The database every bytes share is over, in words."""
    if "database_bytes" not in result:
        return ""
    frames = result.get("database_frames", result["n"])
    return (f" of {frames} x {result['d']} float32, {result['database_bytes']:,} "
            "B, the frames brute force searches")  # fmt: skip


def _truth_line(result: dict[str, Any]) -> str:
    g = result.get("ground_truth") or {}
    src = g.get("source", "index-aligned (query i is place i)")
    if g.get("tolerance_m") is not None:
        return f"ground truth: {src}, tolerance {g['tolerance_m']:g} m"
    if result.get("tolerance") is None:
        return f"ground truth: {src} (lists of right places)"
    return f"ground truth: {src}, tolerance ±{result['tolerance']} frames"


def _denominator_line(result: dict[str, Any]) -> str:
    """Which queries recall@K is out of, and what the other convention divides by."""
    over, n = result.get("recall_over"), result.get("recall_queries")
    if over is None or n is None:
        return ""
    total = result["n_queries"]
    matched = int((result.get("ground_truth") or {}).get("queries_in_map", total))
    if matched == total:
        return (
            f"\nrecall@K over all {total} queries, each with a right place "
            "(VPR_Tutorial's and VPR-methods-evaluation's conventions agree)"
        )
    if over == "matched":
        return (
            f"\nrecall@K over the {n} of {total} queries that have a right place "
            f"(VPR_Tutorial's convention; VPR-methods-evaluation's divides by all "
            f"{total})"
        )
    return (
        f"\nrecall@K over all {n} queries, the {total - matched} without a right "
        "place counted as misses (VPR-methods-evaluation's convention; "
        f"VPR_Tutorial's divides by the {matched} with one)"
    )


def format_evaluation(result: dict[str, Any]) -> str:
    """A plain-text table of :func:`evaluate_map`'s result."""
    seq = result["sequence"]
    head = (
        f"n={result['n']} d={result['d']} queries={result['n_queries']}; "
        f"compression ratio {result['compression_ratio']:.4f}"
        f"{_database_words(result)}\n"
        f"decode={result['decode']} sequence={seq if seq else 'off'}; recall@K "
        f"ranks {result.get('recall_ranks', 'single-frame scores')} "
        + (f"(peers at the same L={seq})" if seq and seq > 1 else "(single frames)")
        + "\n"
        + _truth_line(result)
        + _denominator_line(result)
    )
    cols = ["accuracy", "accuracy_tol"]
    cols += [f"recall@{k}" for k in result.get("recall_values", KS)]
    cols += ["pr_auc", "recall@100p", "storage_bytes", "latency_median_s"]
    cols += ["queries_per_s"]
    names = {"latency_median_s": "latency", "storage_bytes": "bytes"}
    names |= {"queries_per_s": "queries/s", "accuracy_tol": "acc_tol"}
    w = 13
    lines = [head, f"{'method':<12}" + "".join(f"{names.get(c, c):>{w}}" for c in cols)]
    for name, row in result["methods"].items():
        cells = []
        for c in cols:
            v = row.get(c)
            if c == "storage_bytes" and v is not None:
                v += row.get("embedding_bytes") or 0  # what a query needs
            if v is None:
                cells.append(f"{'-':>{w}}")
            elif isinstance(v, int):
                cells.append(f"{v:>{w},}")
            elif c == "latency_median_s":
                cells.append(f"{v * 1e3:>{w - 3}.3f} ms")
            else:
                cells.append(f"{v:>{w}.4f}" if v < 100 else f"{v:>{w},.0f}")
        lines.append(f"{row.get('label', name):<12}" + "".join(cells))
    for name, row in result["methods"].items():  # the line papers quote
        label = row.get("label", name)
        lines.append(f"{label}: {row.get('recall_line') or recall_line(row)}")
    return "\n".join(lines + legend(result))


def legend(result: dict[str, Any]) -> list[str]:
    """What the table's columns mean, for the result printed above them."""
    decode = result.get("decode")
    ranks = result.get("recall_ranks", "single-frame scores")
    if (result.get("methods", {}).get("map") or {}).get("codes_bits"):
        decode = "fused" if decode == "hard" else f"fused {decode}"  # no -1 there
    nomatch = " (a -1, no match, counts as wrong)" if decode == "hard" else ""
    lines = [
        f"accuracy: the {decode} decode's place{nomatch} is the right place exactly;"
        " acc_tol: within the tolerance",
        f"recall@K: a right place (within the tolerance) among the K best by the "
        f"{ranks}; they rank every place, so the map's recall@1 can exceed a "
        "hard decode's acc_tol",
    ]
    rows = result.get("methods", {}).values()
    if any(r.get("embedding_bytes") for r in rows):
        lines.append("bytes: what a query needs, the embedding included (the "
                     "compression ratio counts it too)")  # fmt: skip
    lines += result.get("peer_notes") or []
    if any("latency_median_s" in r for r in rows):
        lines.append("latency: one query alone, from its descriptor to a place (a "
                     "map's template product, a code's encoding and an embedding "
                     f"included), median of up to 200 calls after {WARMUP} warm "
                     f"ones; queries/s: all {result.get('n_queries')} queries in "
                     "one call (batched: not 1/latency)")  # fmt: skip
        if (result.get("sequence") or 1) > 1:
            lines.append("latency and queries/s time single frames (the sequence's "
                         "sums are not timed), alike for every row")  # fmt: skip
    return lines
