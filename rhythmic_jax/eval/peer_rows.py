"""The rows beside the map's: brute force and SeqSLAM at the map's sequence
length, and a representation at the map's bytes
(:class:`~rhythmic_jax.eval.budget_peers.Peer`), each scored by
:func:`rhythmic_jax.eval.method_scores.method_scores` and timed by
:func:`rhythmic_jax.eval.timing.query_latency` from the query descriptors to a
place, as the map's row is.
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
import numpy as np

from rhythmic_jax.eval.method_scores import method_scores
from rhythmic_jax.eval.timing import query_latency
from rhythmic_jax.jit_options import jit

__all__ = ["brute_places", "peer_row", "place_similarities", "sequence_peers"]


def brute_places(flat, labels):
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
        **method_scores(
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
    denominator, as :func:`rhythmic_jax.eval.report.evaluate_map` takes it.
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
            **method_scores(best, conf, ranked, truth, exact, ks, over),
            "storage_bytes": flat.storage_bytes,
            "ranks": f"summed place similarities (L={length}, speed 1)",
        }
    }
    idx, score = seqslam_decode(queries, reference, length)
    idx = labels[np.asarray(idx)]
    rows["SeqSLAM"] = {
        **method_scores(idx, score, idx[:, None], truth, exact, (1,), over),
        "storage_bytes": flat.storage_bytes,
        "ranks": f"SeqSLAM (L={length}, speed 1), one match per query",
    }
    if timing:
        rows["brute force"].update(
            query_latency(brute_places(flat, labels), queries)
        )
    return rows
