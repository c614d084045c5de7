"""Lines that native libraries write to the process's stderr, gathered.

faiss's C++ code prints its warnings (``WARNING clustering 2356 points to 256
centroids: ...``, one per k-means it runs) straight to file descriptor 2, where
Python cannot catch them. :func:`gathered_stderr` points that descriptor at a
temporary file for the length of a block, while Python's own ``sys.stderr``
(progress bars) keeps writing to the terminal; when the block ends, the lines
matching a pattern are handed back and every other line is written to stderr
as it came.
"""

from __future__ import annotations

import contextlib
import os
import re
import sys
import tempfile
from collections.abc import Iterator

__all__ = ["gathered_stderr"]


@contextlib.contextmanager
def gathered_stderr(pattern: str) -> Iterator[list[str]]:
    """Within the block, what is written to descriptor 2 is held back; the
    yielded list then holds the lines matching ``pattern`` (``re.search``),
    and the other lines go to stderr once the block ends (also on error)."""
    found: list[str] = []
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):  # no descriptor 2 to redirect: let it be
        yield found
        return
    python_stderr = sys.stderr
    with tempfile.TemporaryFile() as held, open(
        os.dup(saved), "w", buffering=1, encoding="utf-8", errors="replace"
    ) as terminal:
        os.dup2(held.fileno(), 2)
        sys.stderr = terminal  # Python's writes still reach the terminal
        try:
            yield found
        finally:
            sys.stderr = python_stderr
            os.dup2(saved, 2)
            os.close(saved)
            held.seek(0)
            text = held.read().decode("utf-8", "replace")
            rest = []
            for line in text.splitlines():
                (found if re.search(pattern, line) else rest).append(line)
            if rest:
                print("\n".join(rest), file=python_stderr, flush=True)
