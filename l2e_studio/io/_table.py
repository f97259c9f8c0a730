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
    starts = token.copy()  # the first byte of each token
    starts[1:] &= ~token[:-1]
    line_starts = np.flatnonzero(b == ord("\n")) + 1
    line_starts = np.concatenate([[0], line_starts[line_starts < b.size]])
    per_line = np.add.reduceat(starts, line_starts, dtype=np.int64)  # tokens on each line
    filled = per_line[per_line > 0]
    wrong = np.flatnonzero((per_line > 0) & (per_line != ncols))
    if wrong.size:
        raise InputError(path, f"line {int(wrong[0]) + first_line} has {int(per_line[wrong[0]])} columns, expected "
                               f"{ncols} columns ({wrong.size} of {filled.size} lines differ)")
    return int(filled.size)
