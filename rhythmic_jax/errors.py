"""The one error type a user can act on.

Every check on user input (arrays, images, folders, map files, command-line
arguments) raises :class:`InputError` with a single line that says what was wrong
and where. The command line prints that line and exits with status 2; library
callers can catch it as a ``ValueError``.

A message about a setting names it with a placeholder, ``{opt:tile}`` (or
``{option}`` with ``option="tile"``): the library reads it as the parameter's name
(``tile``), the command line as its flag (``--tile``), so no library message
speaks of command-line flags.
"""

from __future__ import annotations

import re

__all__ = ["InputError"]

_OPT = re.compile(r"\{opt:([a-z_]+)\}")


class InputError(ValueError):
    """Bad input: one line naming what was wrong and where (file, array, option).

    Args:
      message: the line; ``{opt:NAME}`` in it stands for the setting ``NAME``.
      option: the setting ``{option}`` in the line stands for, when there is one.
    """

    def __init__(self, message: str, option: str | None = None):
        message = " ".join(str(message).split())  # always one line
        if option:
            message = message.replace("{option}", "{opt:" + option + "}")
        self.template = message
        self.option = option
        super().__init__(_OPT.sub(lambda m: m.group(1), message))

    def as_flag(self) -> str:
        """The line with every setting spelled as a command-line flag (``--tile``)."""
        return _OPT.sub(lambda m: "--" + m.group(1).replace("_", "-"), self.template)
