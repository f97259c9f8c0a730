"""The views that follow the session's state in threads of their own, so a GUI callback only
records a change and pokes them: the overlay frame (a coarse preview while inputs move, the frame
at rest once they stop), the score readout (after the overlay's frame of the same state), the
scene tables and the 3D pose at rest, the selected scene's 3D cloud, before/after, and the
recording's length. :class:`Views` owns those workers and their jobs; :class:`~.server.App`
decides when to poke which.
"""

from __future__ import annotations

import threading
import time
from typing import TYPE_CHECKING

from .workers import LatestWorker, Settle, join_by

if TYPE_CHECKING:  # (the app holds the views: no import at run time)
    from .server import App

#: s without a change before the frame at rest replaces the preview (key auto-repeat and drags
#: send a change every 16-50 ms; a person nudging pauses longer). The frame at rest should be
#: painted within 400 ms of the input: this leaves ~250 ms to draw, encode, send and paint it.
OVERLAY_REST_S = 0.15
#: s after the readout before the scene table (every scene's score) is redrawn
TABLE_REST_S = 0.25
#: s without a change before the 3D view follows rapid inputs. In a browser without a GPU one
#: camera move costs the page several 3D redraws of 50-80 ms each, which would hold up the next
#: overlay frame of someone nudging the extrinsic; with a GPU it is a few milliseconds.
POSE_3D_REST_S = 1.0
#: s the readout and before/after wait for the overlay frame of their state (see ``_update_mi``)
FRAME_FIRST_S = 0.25


class Views:
    """The background views of one :class:`~.server.App` (created last in its constructor)."""

    def __init__(self, app: "App") -> None:
        self.app = app
        self.overlay_seconds: list[float] = []  # server-side render+encode time of each frame
        self._reference_mi: dict[tuple, float] = {}
        self._want_rest = True  # the next overlay frame is the one at rest (at start, and once inputs stop)
        self._pose_3d_pending = False
        self._frame_cond = threading.Condition()
        self._frame_version = -1  # the state version of the last overlay frame handed to viser
        self._tables_stale = False  # the scene tables still show the previous selection
        self.overlay_worker = LatestWorker("overlay", self._render_overlay)
        self.overlay_settle = Settle("overlay-rest", self._overlay_at_rest, OVERLAY_REST_S)
        self.pose_settle = Settle("pose-3d-rest", self._pose_3d_at_rest, POSE_3D_REST_S)
        # the scene table (every scene's score) follows at rest: re-rendering a table of 40-100
        # rows on every step would hold up the readout and the next frame in the page
        self.table_settle = Settle("scene-table-rest", self._table_at_rest, TABLE_REST_S)
        self.mi_worker = LatestWorker("mi", self._update_mi)
        self.compare_worker = LatestWorker("compare", self._render_compare)
        self.scene_3d_worker = LatestWorker("scene-3d", self._show_scene_3d)
        self.recording_worker = LatestWorker("recording", app.maps.read_recording)

    # --- what the app asks for ----------------------------------------------------------------------
    def pose_3d_at_rest(self) -> None:
        """Pose the 3D view once rapid inputs rest (see ``POSE_3D_REST_S``)."""
        self._pose_3d_pending = True
        self.pose_settle.poke()

    def tables_at_rest(self) -> None:
        """Redraw the scene tables once the selection rests: re-rendering 40-100 rows of markdown
        takes the page's main thread just when the new overlay should be painted."""
        self._tables_stale = True
        self.table_settle.poke()

    def stop(self, deadline: float) -> None:
        """Tell every view's thread to stop and wait for them until ``deadline`` (``time.monotonic()``)."""
        threads = (self.overlay_settle, self.pose_settle, self.table_settle, self.overlay_worker, self.mi_worker,
                   self.compare_worker, self.scene_3d_worker, self.recording_worker)
        for t in threads:
            t.request_stop()
        join_by(threads, deadline)

    # --- the jobs -------------------------------------------------------------------------------------
    def _render_overlay(self) -> None:
        app = self.app
        t0 = time.perf_counter()
        snap = app.state.snapshot()
        rest, self._want_rest = self._want_rest, False
        try:
            app.overlay.render(snap, rest=rest)
        finally:
            with self._frame_cond:
                self._frame_version = max(self._frame_version, snap.version)
                self._frame_cond.notify_all()
            if not rest:
                # the quiet time counts from the last change, not from this preview's end: the
                # frame at rest is not held up by the preview's own drawing
                self.overlay_settle.poke(at=self.overlay_worker.last_poke)
            else:
                # the 3D cloud of a newly selected scene (~600 KB) follows the frame at rest: drawing
                # it costs a GPU-less page 100+ ms on its main thread, which would hold up the paint
                # of the new overlay
                self.scene_3d_worker.poke()
        self.overlay_seconds.append(time.perf_counter() - t0)
        del self.overlay_seconds[:-200]

    def _overlay_at_rest(self) -> None:
        """Nothing moved for a moment: send the frame at rest (the best quality within the
        byte budget; previews are coarser)."""
        if not self.app.overlay.rest_frame:
            self._want_rest = True
            self.overlay_worker.poke()

    def _pose_3d_at_rest(self) -> None:
        """Rapid inputs stopped: pose the 3D camera (not on every step of a drag or of a run of
        key presses, see ``POSE_3D_REST_S``)."""
        app = self.app
        with app.ui_lock:
            if self._pose_3d_pending:
                self._pose_3d_pending = False
                app.view3d.show_pose(app.state.snapshot().extrinsic)

    def _update_mi(self) -> None:
        # Starts once the overlay's frame of this state is handed to viser (or after
        # FRAME_FIRST_S): the frame is what a person waits for, and at 40 full-size scenes on
        # 2 loaded cores the readout beside it made it 54-76 ms instead of 26-36 ms, while the
        # readout itself finished at about the same time (144-188 ms either way).
        app = self.app
        self._wait_for_frame(app.state.snapshot().version)
        snap = app.state.snapshot()  # the latest state: it may have moved on meanwhile
        key = (app.readout.generation, snap.included)  # read first: a newer map only makes it stale
        reading = app.readout.read(snap.extrinsic, snap.included)
        if key not in self._reference_mi:
            self._reference_mi[key] = app.readout.read(snap.reference, snap.included).total
        app.reading = reading
        app.extrinsic.show_mi(reading, snap, self._reference_mi[key])
        app.overlay.show_caption(snap, reading)
        self.table_settle.poke()

    def _table_at_rest(self) -> None:
        app = self.app
        with app.ui_lock:
            if app.reading is not None or self._tables_stale:
                app.scenes.show_mi(app.reading)
            if self._tables_stale:
                self._tables_stale = False
                app.target.show_table()

    def _wait_for_frame(self, version: int) -> None:
        """Return once the overlay frame of state ``version`` is handed to viser (at most
        ``FRAME_FIRST_S``; at once when no frame is coming)."""
        if not self.overlay_worker.wait_idle(0):
            with self._frame_cond:
                self._frame_cond.wait_for(lambda: self._frame_version >= version, FRAME_FIRST_S)

    def _render_compare(self) -> None:
        self._wait_for_frame(self.app.state.snapshot().version)  # the live overlay first (it is on show)
        self.app.compare.render()

    def _show_scene_3d(self) -> None:
        app = self.app
        self.overlay_worker.wait_idle(1.0)
        with app.ui_lock:
            selected = app.state.snapshot().selected
            app.view3d.show_scene(selected)
            app.target.show_3d(selected)
