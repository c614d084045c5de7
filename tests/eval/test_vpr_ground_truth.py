"""``--ground-truth`` with the VPR tools' files: OpenVPRLab, VPR_Tutorial and
Patch-NetVLAD ground truth, against the tools' own rules written in numpy."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.neighbors import NearestNeighbors

from rhythmic_jax.errors import InputError
from rhythmic_jax.eval.ground_truth import gt_accuracy, gt_recall_at_k
from rhythmic_jax.eval.ground_truth_files import load_ground_truth

RNG = np.random.default_rng(7)


def _load(path, nq, nd):
    return load_ground_truth([str(path)], n_queries=nq, n_places=nd, query_source="q")


def _tutorial_recall(S, hard, soft, k):
    """VPR_Tutorial's recallAtK in float64: soft-only similarities set to the
    minimum, then a query is right when a hard positive is among the top k."""
    S = S.astype(np.float64).copy()
    S[soft & ~hard] = S.min()
    keep = hard.any(0)
    top = np.argsort(-S, axis=0, kind="stable")[:k]  # (k, query)
    hit = np.take_along_axis(hard, top, 0).any(0)
    return hit[keep].mean()


def test_vpr_tutorial_recall_matches_the_tutorial(tmp_path):
    nd, nq = 30, 25
    hard = np.zeros((nd, nq), bool)
    hard[RNG.integers(0, nd, nq), np.arange(nq)] = True
    soft = hard | np.roll(hard, 1, 0) | np.roll(hard, -1, 0)
    np.savez(tmp_path / "GT.npz", GThard=hard, GTsoft=soft)
    truth = _load(tmp_path / "GT.npz", nq, nd)
    assert "GThard" in truth.describe()["source"]
    S = RNG.standard_normal((nd, nq)) + 1.5 * soft  # soft neighbours score high
    ranked = np.argsort(-S.T, axis=1, kind="stable")
    got = gt_recall_at_k(ranked, truth, (1, 5))
    for k in (1, 5):
        assert got[f"recall@{k}"] == pytest.approx(_tutorial_recall(S, hard, soft, k))
    # a single prediction on a soft-only place is not counted wrong
    only_soft = np.argmax(soft & ~hard, axis=0)  # (query,)
    assert (soft & ~hard)[only_soft, np.arange(nq)].all()
    assert gt_accuracy(only_soft, truth) == 1.0
    with pytest.raises(InputError, match="30 database images and 25 queries"):
        _load(tmp_path / "GT.npz", nq, nd + 1)


def test_openvprlab_ground_truth_and_lists(tmp_path):
    rows = [np.array([0, 1]), np.array([4]), np.array([2, 3])]
    gt = np.empty(3, dtype=object)
    gt[:] = rows
    np.save(tmp_path / "nord_gt_25m.npy", gt, allow_pickle=True)
    truth = _load(tmp_path / "nord_gt_25m.npy", 3, 5)
    assert [p.tolist() for p in truth.positives] == [r.tolist() for r in rows]
    np.save(tmp_path / "nord_dbImages.npy", np.array([f"d{i}.jpg" for i in range(4)]))
    with pytest.raises(InputError, match="nord_dbImages.npy: 4 images, but the map"):
        _load(tmp_path / "nord_gt_25m.npy", 3, 5)
    (tmp_path / "nord_dbImages.npy").unlink()
    with pytest.raises(InputError, match="3 queries, but .* 4 queries"):
        _load(tmp_path / "nord_gt_25m.npy", 4, 5)


def test_patchnetvlad_ground_truth_matches_radius_neighbours(tmp_path):
    db, q = RNG.uniform(0, 200, (40, 2)), RNG.uniform(0, 200, (15, 2))
    np.savez(tmp_path / "pitts.npz", utmQ=q, utmDb=db, posDistThr=25.0)
    truth = _load(tmp_path / "pitts.npz", 15, 40)
    # Patch-NetVLAD's own rule: sklearn's radius neighbours within posDistThr
    _, want = NearestNeighbors().fit(db).radius_neighbors(q, radius=25.0)
    assert [p.tolist() for p in truth.positives] == [sorted(w.tolist()) for w in want]
    assert truth.describe()["tolerance_m"] == 25.0
    np.savez(tmp_path / "other.npz", a=np.zeros(3))
    with pytest.raises(InputError, match="neither VPR_Tutorial's"):
        _load(tmp_path / "other.npz", 15, 40)
