"""PCA against scikit-learn."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.decomposition import PCA as SkPCA

from rhythmic_jax.errors import InputError
from rhythmic_jax.map.projection import fit_pca, project


def _align_signs(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Flip the columns of a (n, k) to agree in sign with b (n, k)."""
    return a * np.sign(np.sum(a * b, axis=0))[None, :]


def _correlated(n: int, d: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    scales = np.geomspace(10.0, 0.1, d)  # distinct variances
    mix = np.linalg.qr(rng.normal(size=(d, d)))[0]
    return (rng.normal(size=(n, d)) * scales) @ mix.T + rng.normal(size=d)


@pytest.mark.parametrize("n,d", [(300, 20), (40, 120)])  # covariance and Gram paths
def test_pca_matches_sklearn(n, d):
    x = _correlated(n, d, seed=n).astype(np.float32)
    k = 8
    ours = fit_pca(x, k)
    ref = SkPCA(n_components=k, svd_solver="full").fit(x.astype(np.float64))
    np.testing.assert_allclose(
        ours.explained_variance, ref.explained_variance_, rtol=1e-3
    )
    np.testing.assert_allclose(ours.mean, ref.mean_, atol=1e-4)
    # same subspace: the principal angles' cosines are all 1
    cos = np.linalg.svd(np.asarray(ours.components) @ ref.components_.T)[1]
    np.testing.assert_allclose(cos, 1.0, atol=1e-4)
    y = np.asarray(project(ours, x))
    y_ref = ref.transform(x.astype(np.float64))
    np.testing.assert_allclose(
        _align_signs(y, y_ref), y_ref, atol=2e-3 * np.abs(y_ref).max()
    )
    # orthonormal rows
    c = np.asarray(ours.components)
    np.testing.assert_allclose(c @ c.T, np.eye(k), atol=1e-4)


def test_project_normalize_gives_unit_rows():
    x = _correlated(100, 10, seed=1).astype(np.float32)
    y = np.asarray(project(fit_pca(x, 4), x, normalize=True))
    np.testing.assert_allclose(np.linalg.norm(y, axis=1), 1.0, rtol=1e-5)


def _places(c: int, per: int, d: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """c places seen ``per`` times each (traversals). The places differ along
    directions of small variance; the strongest variance is nuisance (appearance
    change), which PCA keeps and LDA discards."""
    rng = np.random.default_rng(seed)
    centres = np.zeros((c, d))
    centres[:, d // 4 :] = rng.normal(size=(c, d - d // 4))
    noise = rng.normal(size=(c * per, d)) * 0.3
    noise[:, : d // 4] *= 30.0
    mix = np.linalg.qr(rng.normal(size=(d, d)))[0]
    labels = np.repeat(np.arange(c), per)
    x = (centres[labels] + noise) @ mix.T
    return x.astype(np.float32), labels * 7 + 3  # labels need not be 0..c-1


def _fisher_ratio(y: np.ndarray, labels: np.ndarray) -> float:
    """trace(S_b) / trace(S_w) of projected data y (n, k)."""
    mean = y.mean(0)
    sb = sw = 0.0
    for c in np.unique(labels):
        yc = y[labels == c]
        sb += len(yc) * np.sum((yc.mean(0) - mean) ** 2)
        sw += np.sum((yc - yc.mean(0)) ** 2)
    return sb / sw


def test_bad_inputs():
    x, labels = _places(c=5, per=4, d=6, seed=0)
    with pytest.raises(InputError, match="k=7"):
        fit_pca(x, 7)  # d = 6
    with pytest.raises(InputError, match="NaN"):
        fit_pca(np.full((4, 3), np.nan), 1)
    with pytest.raises(InputError, match=r"\(n, 6\)"):
        project(fit_pca(x, 2), x[:, :5])
