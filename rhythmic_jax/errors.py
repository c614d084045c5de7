"""The one error type a user can act on.

Every check on user input (arrays, images, folders, map files, command-line
arguments) raises :class:`InputError` with a single line that says what was wrong
and where. The command line prints that line and exits with status 2; library
callers can catch it as a ``ValueError``.
"""

from __future__ import annotations

__all__ = ["InputError"]


class InputError(ValueError):
    """Bad input: one line naming what was wrong and where (file, array, option)."""

    def __init__(self, message: str):
        message = " ".join(str(message).split())  # always one line
        super().__init__(message)
