"""Event maps rebuilt from their raw recordings in the background (pure threading, no viser).

A :class:`MapRebuilder` runs one request at a time -- one scene, or every scene from raw events
-- in a thread of its own and reports through callbacks: a status line before each scene, each
rebuilt :class:`~l2e_studio.scenes.Scene` as soon as it is ready, and a summary at the end. A
scene whose rebuild fails keeps its old map; the reason is in the summary. :class:`RecordingInfo`
remembers each recording's length (streamed once, on first need).
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

from ..errors import InputError
from ..io.events import Accumulation, EventStats, event_stats
from ..scenes import Scene, reaccumulate

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RebuildSummary:
    """What one request did: the scenes rebuilt, one line per scene that failed, the time taken."""

    settings: Accumulation
    rebuilt: tuple[str, ...]
    errors: tuple[str, ...]
    seconds: float

    def line(self) -> str:
        """One line for the status ("✓ ..." or "✗ ..." with the first error)."""
        done = (f"✓ Rebuilt the map of {', '.join(self.rebuilt) if len(self.rebuilt) <= 3 else f'{len(self.rebuilt)} scenes'}"
                f" ({self.settings.describe()}) in {self.seconds:.2f} s") if self.rebuilt else ""
        if not self.errors:
            return done
        failed = f"✗ {self.errors[0]}" + (f" (and {len(self.errors) - 1} more)" if len(self.errors) > 1 else "")
        return "  \n".join(x for x in (done, failed + "; the old map is kept") if x)


def one_line(exc: BaseException) -> str:
    """An exception as one short line (an InputError already names its file)."""
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    return text if isinstance(exc, InputError) else f"{type(exc).__name__}: {text}"


class MapRebuilder:
    """Rebuild event maps in a daemon thread, one request at a time."""

    def __init__(
        self,
        width: int,
        height: int,
        on_status: Callable[[str], None],
        on_rebuilt: Callable[[int, Scene], None],
        on_finished: Callable[[RebuildSummary], None],
    ) -> None:
        self.width, self.height = int(width), int(height)
        self._on_status, self._on_rebuilt, self._on_finished = on_status, on_rebuilt, on_finished
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self._busy = False  # cleared before ``on_finished``: its callback sees the rebuilder idle

    def busy(self) -> bool:
        return self._busy

    def start(self, jobs: Sequence[tuple[int, Scene]], settings: Accumulation) -> None:
        """Rebuild each ``(index, scene)`` of ``jobs`` with ``settings``; RuntimeError when busy."""
        with self._lock:
            if self._busy:
                raise RuntimeError("a rebuild is in progress; wait for it to finish")
            self._busy = True
            self._thread = threading.Thread(target=self._work, args=(list(jobs), settings),
                                            name="l2e-rebuild-maps", daemon=True)
            self._thread.start()

    def wait(self, timeout: float = 60.0) -> bool:
        """Block until the current request has finished, its report included."""
        t = self._thread
        if t is not None:
            t.join(timeout)
        return t is None or not t.is_alive()

    def _work(self, jobs: list[tuple[int, Scene]], settings: Accumulation) -> None:
        t0 = time.perf_counter()
        rebuilt, errors = [], []
        for k, (index, scene) in enumerate(jobs):
            count = f" ({k + 1}/{len(jobs)})" if len(jobs) > 1 else ""
            self._safe(self._on_status, f"Rebuilding map of {scene.name}{count}...")
            try:
                new = reaccumulate(scene, settings, self.width, self.height)
            except Exception as exc:  # reported in the summary; the scene keeps its old map
                if not isinstance(exc, (InputError, ValueError, OSError)):
                    log.exception("rebuilding the map of %s failed", scene.name)
                errors.append(f"{scene.name}: {one_line(exc)}")
                continue
            if self._safe(self._on_rebuilt, index, new):
                rebuilt.append(scene.name)
            else:
                errors.append(f"{scene.name}: the new map could not be shown (see the log)")
        self._busy = False
        self._safe(self._on_finished, RebuildSummary(settings, tuple(rebuilt), tuple(errors), time.perf_counter() - t0))

    @staticmethod
    def _safe(callback: Callable, *args) -> bool:
        try:
            callback(*args)
            return True
        except Exception:  # the thread must always report its end
            log.exception("map rebuild callback failed")
            return False


class RecordingInfo:
    """Each recording's :class:`EventStats` (or why it cannot be read), computed once per file."""

    def __init__(self) -> None:
        self._known: dict[Path, EventStats | str] = {}
        self._lock = threading.Lock()

    def get(self, path: Path) -> EventStats | str | None:
        """The stats, a one-line reason they cannot be had, or None when not computed yet."""
        with self._lock:
            return self._known.get(Path(path))

    def compute(self, path: Path) -> EventStats | str:
        """Stream the recording once (slow for big files: call it from a worker thread)."""
        known = self.get(path)
        if known is not None:
            return known
        try:
            value: EventStats | str = event_stats(path)
        except (InputError, ValueError, OSError) as exc:
            value = one_line(exc)
        with self._lock:
            self._known[Path(path)] = value
        return value
