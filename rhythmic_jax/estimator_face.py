"""scikit-learn's estimator protocol, with scikit-learn imported only when used.

``import sklearn`` loads scipy.stats and much else (``reports/startup.md``
measures what imports cost), which every command that fits or loads a map would
pay before its work. :class:`EstimatorFace`
answers ``get_params`` and prints itself as scikit-learn's estimators do, and
``set_params`` and the tags with scikit-learn's own ``BaseEstimator``
functions, imported on first call; scikit-learn's tools
(``clone``, ``GridSearchCV``, ``Pipeline``, its estimator checks) take an
estimator by these methods, not by its base class. :func:`not_fitted_error` is
the error that is both scikit-learn's ``NotFittedError`` and this package's
:class:`~rhythmic_jax.errors.InputError`, made on first use for the same reason.
"""

from __future__ import annotations

import functools
import inspect

from rhythmic_jax.errors import InputError

__all__ = ["EstimatorFace", "not_fitted_error"]


def _base() -> type:
    from sklearn.base import BaseEstimator

    return BaseEstimator


class EstimatorFace:
    """The parameters of ``__init__`` (by name) as scikit-learn's estimators
    keep them: read by ``get_params``, set by ``set_params``, shown by the repr."""

    @classmethod
    def _get_param_names(cls) -> list[str]:
        """The names of ``__init__``'s parameters, sorted (as scikit-learn's)."""
        params = inspect.signature(cls.__init__).parameters.values()
        skip = (inspect.Parameter.VAR_KEYWORD, inspect.Parameter.VAR_POSITIONAL)
        return sorted(p.name for p in params if p.name != "self" and p.kind not in skip)

    def get_params(self, deep: bool = True) -> dict:
        """The parameters by name (``deep``: those of nested estimators too, as
        ``name__param``)."""
        out = {}
        for key in self._get_param_names():
            value = getattr(self, key)
            if deep and hasattr(value, "get_params") and not isinstance(value, type):
                out.update((f"{key}__{k}", v) for k, v in value.get_params().items())
            out[key] = value
        return out

    def set_params(self, **params):
        """Set parameters by name; returns self."""
        return _base().set_params(self, **params)

    def __repr__(self) -> str:
        """``Name(p=v, ...)``: the parameters that differ from their defaults,
        by name, as scikit-learn's estimators print."""
        defaults = inspect.signature(type(self).__init__).parameters
        changed = sorted(
            (k, v) for k, v in self.get_params(deep=False).items()
            if repr(v) != repr(defaults[k].default)
        )  # fmt: skip
        return f"{type(self).__name__}({', '.join(f'{k}={v!r}' for k, v in changed)})"

    def __sklearn_tags__(self):
        return _base().__sklearn_tags__(self)


@functools.cache
def not_fitted_error() -> type:
    """The class ``NotFittedMapError(InputError, NotFittedError)``."""
    from sklearn.exceptions import NotFittedError

    return type(
        "NotFittedMapError",
        (InputError, NotFittedError),
        {
            "__doc__": "A fitted map's value asked of an estimator before ``fit`` "
            "or ``load``: scikit-learn's ``NotFittedError`` and this package's "
            "one-line error.",
            "__module__": "rhythmic_jax.rhythmic_map",
        },
    )
