"""Undo / redo of the extrinsic: a bounded list of earlier values, pure Python.

A burst of changes from one source (a slider drag, a gizmo drag, typing a number) becomes a
single undo step: a change that comes from the same source within ``merge_seconds`` of the
previous one does not add a step. Every other change (nudge, reset, accept, load, undo
itself) is a step of its own.
"""

from __future__ import annotations

import time
from typing import Callable, Generic, TypeVar

T = TypeVar("T")

#: Sources whose bursts merge into one undo step.
MERGING_SOURCES = frozenset({"sliders", "gizmo", "gizmo-fine", "typed"})


class History(Generic[T]):
    """Undo and redo stacks of values (at most ``limit`` undo steps kept)."""

    def __init__(self, limit: int = 200, merge_seconds: float = 0.8,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if limit < 1:
            raise ValueError("limit must be >= 1")
        self.limit = int(limit)
        self.merge_seconds = float(merge_seconds)
        self._clock = clock
        self._undo: list[T] = []
        self._redo: list[T] = []
        self._last: tuple[str, float] | None = None  # (source, time) of the last recorded change

    @property
    def can_undo(self) -> bool:
        return bool(self._undo)

    @property
    def can_redo(self) -> bool:
        return bool(self._redo)

    @property
    def depth(self) -> tuple[int, int]:
        """(undo steps, redo steps) available."""
        return len(self._undo), len(self._redo)

    def record(self, previous: T, source: str = "") -> None:
        """A change away from ``previous`` happened: keep it (unless it merges) and drop redo."""
        now = self._clock()
        merge = (self._last is not None and source in MERGING_SOURCES and self._last[0] == source
                 and now - self._last[1] <= self.merge_seconds and self._undo)
        if not merge:
            self._undo.append(previous)
            del self._undo[:-self.limit]
        self._redo.clear()
        self._last = (source, now)

    def undo(self, current: T) -> T | None:
        """The value before ``current`` (which goes onto the redo stack), or None."""
        if not self._undo:
            return None
        self._redo.append(current)
        self._last = None
        return self._undo.pop()

    def redo(self, current: T) -> T | None:
        """The value undone last (``current`` goes back onto the undo stack), or None."""
        if not self._redo:
            return None
        self._undo.append(current)
        self._last = None
        return self._redo.pop()
