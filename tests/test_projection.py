"""PCA and LDA against scikit-learn."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.decomposition import PCA as SkPCA
from sklearn.discriminant_analysis import LinearDiscriminantAnalysis

from rhythmic_jax.errors import InputError
from rhythmic_jax.projection import fit_lda, fit_pca, project


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


@pytest.mark.parametrize("c,per,d", [(12, 30, 16), (20, 8, 100)])
def test_lda_matches_sklearn(c, per, d):
    x, labels = _places(c=c, per=per, d=d, seed=0)
    k = 5
    ours = fit_lda(x, labels, k=k)
    ref = LinearDiscriminantAnalysis(solver="svd", n_components=k)
    y_ref = ref.fit(x.astype(np.float64), labels).transform(x.astype(np.float64))
    y = np.asarray(project(ours, x))
    scale = np.abs(y_ref).max()
    np.testing.assert_allclose(_align_signs(y, y_ref), y_ref, atol=2e-3 * scale)
    np.testing.assert_allclose(
        ours.explained_variance_ratio, ref.explained_variance_ratio_[:k], rtol=1e-3
    )


def _fisher_ratio(y: np.ndarray, labels: np.ndarray) -> float:
    """trace(S_b) / trace(S_w) of projected data y (n, k)."""
    mean = y.mean(0)
    sb = sw = 0.0
    for c in np.unique(labels):
        yc = y[labels == c]
        sb += len(yc) * np.sum((yc.mean(0) - mean) ** 2)
        sw += np.sum((yc - yc.mean(0)) ** 2)
    return sb / sw


def test_lda_separates_places_where_pca_does_not():
    # fewer training frames (90) than features (120): S_w is singular, the
    # whitening keeps its range (the Gram path)
    x, labels = _places(c=30, per=6, d=120, seed=3)
    test, test_labels = x[1::2], labels[1::2]  # held-out traversals
    x, labels = x[::2], labels[::2]
    k = 8
    lda, pca = fit_lda(x, labels, k=k), fit_pca(x, k)
    assert _fisher_ratio(np.asarray(project(lda, x)), labels) > 10 * _fisher_ratio(
        np.asarray(project(pca, x)), labels
    )

    def nn_accuracy(model):  # held-out frame -> nearest training frame's place
        a, b = np.asarray(project(model, x)), np.asarray(project(model, test))
        d2 = ((b[:, None] - a[None]) ** 2).sum(-1)
        return np.mean(labels[np.argmin(d2, 1)] == test_labels)

    assert nn_accuracy(lda) > 0.9 > 0.5 > nn_accuracy(pca)


def test_bad_inputs():
    x, labels = _places(c=5, per=4, d=6, seed=0)
    with pytest.raises(InputError, match="k=5"):
        fit_lda(x, labels, k=5)  # at most c - 1 = 4
    with pytest.raises(InputError, match="labels"):
        fit_lda(x, labels[:-1], k=2)
    with pytest.raises(InputError, match="k=7"):
        fit_pca(x, 7)  # d = 6
    with pytest.raises(InputError, match="NaN"):
        fit_pca(np.full((4, 3), np.nan), 1)
    with pytest.raises(InputError, match=r"\(n, 6\)"):
        project(fit_pca(x, 2), x[:, :5])
