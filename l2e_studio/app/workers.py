"""Background threads that keep the GUI callbacks short.

A :class:`LatestWorker` runs one job function whenever it is poked; pokes that arrive while it
is busy collapse into one more run, so a fast slider drag never queues up stale frames -- the
view always catches up with the latest state. A :class:`Ticker` calls a function at a fixed
rate while a condition holds (used to throttle progress updates during a run).
:func:`join_by` waits for several against one deadline.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Callable, Protocol, Sequence

log = logging.getLogger(__name__)


class LatestWorker:
    """Run ``job()`` in a daemon thread after each :meth:`poke`, coalescing bursts."""

    def __init__(self, name: str, job: Callable[[], None]) -> None:
        self.name = name
        self._job = job
        self._wake = threading.Event()
        self._idle = threading.Event()
        self._idle.set()
        self._lock = threading.Lock()
        self._pending = False
        self._stop = False
        self.runs = 0
        self.last_seconds = 0.0
        self.last_poke = 0.0  # time.monotonic() of the last poke
        self._thread = threading.Thread(target=self._loop, name=f"l2e-{name}", daemon=True)
        self._thread.start()

    def poke(self) -> None:
        """Ask for one more run (after the current one, if busy)."""
        with self._lock:
            self.last_poke = time.monotonic()
            self._pending = True
            self._idle.clear()
            self._wake.set()

    def wait_idle(self, timeout: float = 10.0) -> bool:
        """Block until no run is pending (tests and shutdown)."""
        return self._idle.wait(timeout)

    def request_stop(self) -> None:
        """Stop after the current run (if any); returns at once."""
        self._stop = True
        self._wake.set()

    def join(self, timeout: float | None = None) -> None:
        self._thread.join(timeout)

    def stop(self, timeout: float = 5.0) -> None:
        self.request_stop()
        self.join(timeout)

    def _loop(self) -> None:
        while True:
            self._wake.wait()
            if self._stop:
                return
            with self._lock:
                self._wake.clear()
                self._pending = False
            t0 = time.perf_counter()
            try:
                self._job()
            except Exception:  # a failed frame must not kill the view
                log.exception("%s worker failed", self.name)
            self.runs += 1
            self.last_seconds = time.perf_counter() - t0
            with self._lock:
                if not self._pending:
                    self._idle.set()


class Ticker:
    """Call ``tick()`` every ``period`` seconds while ``active()`` is true, then once more.

    :meth:`stop` ends the wait at once (no waiting out the period when a run finishes).
    """

    def __init__(self, name: str, tick: Callable[[], None], active: Callable[[], bool], period: float = 0.2) -> None:
        self._tick, self._active, self._period = tick, active, float(period)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name=f"l2e-{name}", daemon=True)
        self._thread.start()

    def stop(self, timeout: float | None = None) -> None:
        """Stop ticking after one last tick; waits for it."""
        self._stop.set()
        self._thread.join(timeout)

    def _loop(self) -> None:
        while self._active() and not self._stop.is_set():
            t0 = time.perf_counter()
            self._safe_tick()
            self._stop.wait(max(0.0, self._period - (time.perf_counter() - t0)))
        self._safe_tick()

    def _safe_tick(self) -> None:
        try:
            self._tick()
        except Exception:  # a failed update must not end the updates
            log.exception("ticker failed")


class Settle:
    """Call ``job()`` once things have been quiet for ``quiet`` seconds after the last :meth:`poke`.

    Used to send the overlay's frame at rest once a drag or a burst of key presses has stopped
    (the frames during it are coarser previews), and to pose the 3D view then.
    """

    def __init__(self, name: str, job: Callable[[], None], quiet: float = 0.3) -> None:
        self._job, self._quiet = job, float(quiet)
        self._last = 0.0
        self._armed = False
        self._stop = False
        self._cond = threading.Condition()
        self._thread = threading.Thread(target=self._loop, name=f"l2e-{name}", daemon=True)
        self._thread.start()

    def poke(self, at: float | None = None) -> None:
        """Start (or restart) the quiet time, counted from ``at`` (a ``time.monotonic()``;
        None: now; never earlier than a previous poke's)."""
        with self._cond:
            now = time.monotonic()
            self._last = now if at is None else max(self._last, min(now, at))
            self._armed = True
            self._cond.notify()

    def request_stop(self) -> None:
        """Stop after the current job (if any); returns at once."""
        with self._cond:
            self._stop = True
            self._cond.notify()

    def join(self, timeout: float | None = None) -> None:
        self._thread.join(timeout)

    def stop(self, timeout: float = 5.0) -> None:
        self.request_stop()
        self.join(timeout)

    def _loop(self) -> None:
        while True:
            with self._cond:
                while not self._armed and not self._stop:
                    self._cond.wait()
                if self._stop:
                    return
                wait = self._last + self._quiet - time.monotonic()
                if wait > 0:
                    self._cond.wait(wait)
                    continue
                self._armed = False
            try:
                self._job()
            except Exception:
                log.exception("settle job failed")


class _Joinable(Protocol):
    def join(self, timeout: float | None = None) -> None: ...


def join_by(threads: Sequence[_Joinable], deadline: float) -> None:
    """Wait for ``threads`` until the ``time.monotonic()`` ``deadline`` at the latest, all
    together: a busy app stops by then, not after a timeout per thread in turn (the threads
    are daemons: one still busy then does not hold the process)."""
    for t in threads:
        t.join(max(0.0, deadline - time.monotonic()))
