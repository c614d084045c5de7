"""Progress bars only where asked for: the library is quiet by default.

Library calls take ``progress=False`` (``RhythmicMap.fit`` takes ``verbose=0``,
as scikit-learn estimators do); the command line turns bars on unless
``--no-progress``. ``TQDM_DISABLE=1`` in the environment hides every bar even
then (tqdm ignores it when ``disable`` is passed explicitly, so it is read here).
"""

from __future__ import annotations

import os

__all__ = ["bar", "bars_disabled"]


def bars_disabled() -> bool:
    """True when ``TQDM_DISABLE`` is set to anything but empty, 0, false or no."""
    value = os.environ.get("TQDM_DISABLE", "").strip().lower()
    return value not in ("", "0", "false", "no")


def bar(iterable=None, *, show: bool, **kwargs):
    """``tqdm(iterable, **kwargs)``, drawn only when ``show`` and not disabled."""
    from tqdm.auto import tqdm

    return tqdm(iterable, disable=not show or bars_disabled(), **kwargs)
