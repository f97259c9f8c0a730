"""Checking the shape of a whitespace-separated number table before parsing it."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError


#: ASCII whitespace, as ``bytes.split()`` sees it.
_SPACE = np.zeros(256, bool)
_SPACE[list(b" \t\n\r\x0b\x0c")] = True


def count_rows(path: Path, body: bytes, ncols: int, first_line: int = 1) -> int:
    """The number of non-blank lines of ``body`` (whitespace-separated), after checking that each
    holds ``ncols`` tokens: a ragged file whose total happens to be a multiple of the column count
    would otherwise be read with its rows shifted. ``first_line`` numbers ``body``'s first line
    in the error."""
    b = np.frombuffer(body, np.uint8)
    if b.size == 0:
        return 0
    token = ~_SPACE[b]
    starts = np.flatnonzero(token[1:] & ~token[:-1]) + 1
    if token[0]:
        starts = np.concatenate([[0], starts])
    line_of = np.searchsorted(np.flatnonzero(b == ord("\n")), starts)  # the line each token is on
    per_line = np.bincount(line_of)
    filled = per_line[per_line > 0]
    wrong = np.flatnonzero((per_line > 0) & (per_line != ncols))
    if wrong.size:
        raise InputError(path, f"line {int(wrong[0]) + first_line} has {int(per_line[wrong[0]])} columns, expected "
                               f"{ncols} columns ({wrong.size} of {filled.size} lines differ)")
    return int(filled.size)
