"""What :class:`~rhythmic_jax.rhythmic_map.RhythmicMap` takes as scikit-learn's
estimator contract asks: frames refused in its words, place labels, scaling.

scikit-learn's checks (``sklearn.utils.estimator_checks``) expect an
estimator's refusals to say certain things: a 1-d array "Reshape your data", no
features "0 feature(s) (shape=...) while a minimum of 1 is required", a query of
another width "X has k features, but RhythmicMap is expecting d features as
input", an object array holding a non-number a ``TypeError`` ("argument must be
a string or a real number"). :func:`shape_checked` says them, in one
:class:`~rhythmic_jax.errors.InputError` line that also keeps this package's
words, before :func:`rhythmic_jax.validate.check_features` checks the values.

Place labels ``y`` (:func:`place_labels`) may be any integers >= 0 (whole
floats too); the estimator numbers its places in their order. Features not of
order one (:func:`not_of_order_one`) are refused by the fit, or standardized
per feature (:func:`standardize`, :func:`standardized`) where the estimator's
``scale`` says so; :func:`query_rows` takes a fitted map's queries, the
standardization included.

Shapes: n frames, b queries, d features.
"""

from __future__ import annotations

import numpy as np

from rhythmic_jax.errors import InputError
from rhythmic_jax.validate import check_features, check_fit_scale, is_sparse, scale_sums

__all__ = [
    "SCALES",
    "check_settings",
    "SCALE_KEYS",
    "NotNumbersError",
    "not_of_order_one",
    "place_labels",
    "query_rows",
    "shape_checked",
    "standardize",
    "standardized",
]

SCALES = ("refuse", "standardize", "auto")  # what a fit does with unscaled features
SCALE_KEYS = ("scale_mean", "scale_std")  # kept in the map's extra arrays


class NotNumbersError(InputError, TypeError):
    """An object array holding something that is not a number (a TypeError,
    as numpy's conversion raises it, and this package's one-line error)."""


def shape_checked(X, name: str, d: int | None = None):
    """X as it is, refused in scikit-learn's words where its shape (when it has
    one) is 1-d, has no features or not ``d`` of them; numbers held as Python
    objects become float64."""
    if type(X) is np.ndarray and X.dtype != object:  # the common case, at once
        if X.ndim == 2 and X.shape[1] and (d is None or X.shape[1] == d):
            return X
    if isinstance(X, np.ndarray) and X.dtype == object:
        try:
            X = X.astype(np.float64)
        except (TypeError, ValueError) as err:
            raise NotNumbersError(
                f"{name}: expected numbers, got an object array ({err})"
            ) from None
    shape = getattr(X, "shape", None)
    if shape is None or is_sparse(X):
        return X
    if len(shape) == 1:
        raise InputError(
            f"{name}: expected a 2-D array (frames x features), got shape {shape}; "
            "Reshape your data: X.reshape(1, -1) for one frame"
        )
    if len(shape) == 2 and shape[1] == 0:
        raise InputError(
            f"{name}: 0 feature(s) (shape={shape}) while a minimum of 1 is required: "
            "an empty array"
        )
    if d is not None and len(shape) == 2 and shape[1] != d:
        raise InputError(
            f"{name}: {shape[1]}-d features but the map was built for {d}-d (X has "
            f"{shape[1]} features, but RhythmicMap is expecting {d} features as input)"
        )
    return X


def place_labels(y, n: int) -> np.ndarray:
    """Place labels ``y`` (n,) as int64 >= 0 (whole floats taken), else one line."""
    lab = np.asarray(y)
    if lab.shape != (n,):
        raise InputError(f"y: expected {n} place labels, got shape {lab.shape}")
    whole = np.issubdtype(lab.dtype, np.integer)
    if not whole and np.issubdtype(lab.dtype, np.floating):
        whole = bool(np.isfinite(lab).all() and (lab == np.round(lab)).all())
    if not whole or (lab.size and lab.min() < 0):
        raise InputError(
            f"y: place labels must be integers >= 0, got dtype {lab.dtype} "
            "(Unknown label type otherwise)"
        )
    return lab.astype(np.int64)


def not_of_order_one(x: np.ndarray) -> bool:
    """True for frames x (n, d) that a fit refuses as not of order one: a mean
    frame far from the origin, as unscaled 8-bit descriptors have
    (:func:`rhythmic_jax.validate.check_fit_scale`), or frames far longer or
    shorter than the solver fits (:func:`rhythmic_jax.fitting.fit_map.check_length`,
    frames multiplied by 1e30 or 1e-30), or shorter than :data:`AUTO_SHORTEST`,
    which a fit takes but places badly."""
    from rhythmic_jax.solvers.frame_length import check_length

    sums = scale_sums(x)
    try:
        check_fit_scale(sums, float(np.abs(x).max()))
        check_length(sums)
    except InputError:
        return True
    length = float(np.sqrt(sums[-2] / max(float(sums[-1]), 1.0)))
    return 0.0 < length < AUTO_SHORTEST


# Frames shorter than this (RMS length) are standardised by scale='auto' though
# a fit takes them: on 300 Nordland frames self-recall is 0.48 at lengths 1e-3 to
# 1e-2 and 0.77 at 0.1, against 0.99 at 1 and 0.98 at 10 to 100.
AUTO_SHORTEST = 0.3


def check_settings(config) -> None:
    """The estimator's parameters as the command line checks its options: each
    :class:`~rhythmic_jax.map.config.MapConfig` field that ``fit`` offers against
    its declared domain (``r`` an integer >= 2, ``gap`` in (0, 1), ...), and what
    a map's reader checks of its settings (``top``, the phases top-m keeps, an
    integer >= 1); else one :class:`InputError` line naming the parameter."""
    from dataclasses import fields

    from rhythmic_jax.map.checks import _check_config as map_settings

    for f in fields(config):
        domain, value = f.metadata.get("domain"), getattr(config, f.name)
        if domain is None or value is None or value in domain.words:
            continue
        try:
            domain.check(value)
        except InputError as err:
            raise InputError(f"{f.name} {err}") from None
    map_settings(config)


def standardize(x: np.ndarray) -> dict[str, np.ndarray]:
    """``scale_mean`` and ``scale_std`` (d,) float32 of frames x (n, d): each
    feature's mean and standard deviation (1 where it is constant), computed in
    float64."""
    mean, std = x.mean(axis=0, dtype=np.float64), x.std(axis=0, dtype=np.float64)
    std = np.where(std > 0, std, 1.0)
    return dict(scale_mean=mean.astype(np.float32), scale_std=std.astype(np.float32))


def standardized(x: np.ndarray, extra: dict) -> np.ndarray:
    """Frames x (b, d) standardized by ``extra``'s ``scale_mean`` and ``scale_std``:
    ``(x - mean) / std``, float32."""
    mean, std = _scale(extra)
    return (x - mean[None, :]) / std[None, :]


def query_rows(X, d: int, extra: dict, name: str = "queries"):
    """Queries X (b, d) of a map of d features, as its decode takes them: the
    shape checked (:func:`shape_checked`); where the fit standardized its frames
    (``extra`` holds ``scale_mean`` and ``scale_std``) the values checked too
    (:func:`rhythmic_jax.validate.check_features`) and standardized, float32
    ``(x - mean) / std`` as :func:`standardized`; else X as it is (the decode
    checks its values)."""
    plain = "scale_mean" not in extra
    if plain and type(X) is np.ndarray and X.ndim == 2 and X.shape[1] == d:
        if X.dtype != object:  # the common case, at once (a query's latency)
            return X
    X = shape_checked(X, name, d)
    if plain:
        return X
    x = check_features(X, name, d=d)
    mean, std = _scale(extra)
    return (x - mean[None, :]) / std[None, :]


def _scale(extra: dict) -> tuple[np.ndarray, np.ndarray]:
    """``scale_mean`` and ``scale_std`` (d,) of ``extra`` as float32."""
    mean, std = (np.asarray(extra[k], np.float32) for k in SCALE_KEYS)
    return mean, std
