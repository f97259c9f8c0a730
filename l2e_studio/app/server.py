"""The workbench server: one viser server, one shared session, the panels and the workers.

:func:`build_app` wires a loaded :class:`~l2e_studio.scenes.SceneSet` into a running
:class:`App`; :func:`serve` does that and blocks (the ``l2e-studio`` command). Every GUI element
is created on the server (``server.gui``/``server.scene``), so every browser tab shows the same
state, and the optimisation runs in a thread of its own, so closing a tab loses nothing.
The app holds no calibration logic: MI comes from :mod:`l2e_studio.objective`, the search from
:func:`l2e_studio.calibrate.calibrate`, files from :mod:`l2e_studio.export`.
"""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np
import viser

from ..calibrate import CalibrationResult, CalibrationSettings
from ..geometry import Extrinsic
from ..io.events import Accumulation, EventStats
from ..scenes import SceneSet
from .display import SceneDisplay
from .files import check_results_dir, default_results_dir, save_result
from .handback import ResultScores, result_scores
from .heldout import HeldOutScore, held_out_scores
from .pairs import Pair
from .panels.compare import ComparePanel
from .panels.event_maps import EventMapsPanel
from .panels.extrinsic import ExtrinsicPanel
from .panels.optimise import OptimisePanel
from .panels.pairs import PairsPanel
from .panels.qa import QAPanel
from .panels.overlay_view import OverlayPanel
from .panels.results import ResultPanel
from .panels.scenes import ScenesPanel
from .panels.target import TargetPanel
from .panels.view3d import View3D
from .readout import MiReading, MiReadout
from .maps import EventMapSession
from .state import SessionState
from .runs import CHECKERBOARD, METHOD_NAMES, Runner, checkerboard, targetless
from .workers import LatestWorker, Settle, join_by

log = logging.getLogger(__name__)

TITLE = "L2E Studio"
STOP_S = 5.0  # App.stop: every thread and a run in progress get this long, all together
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
DEFERRED_3D_SOURCES = frozenset({"sliders", "typed", "nudge", "gizmo-fine"})  # rapid inputs: the gizmo follows at rest


class App:
    """A running workbench. Create with :func:`build_app`; stop with :meth:`stop`."""

    def __init__(self, scene_set: SceneSet, server: viser.ViserServer, out_dir: Path, objective: str = "auto") -> None:
        self.scene_set = scene_set
        self.server = server
        self.camera = scene_set.camera
        self.out_dir = Path(out_dir)
        self.state = SessionState(scene_set.names, reference=scene_set.seed)
        self.displays = [SceneDisplay(s) for s in scene_set.scenes]
        # The readout smooths the maps like the optimiser's default; the sigma field updates both.
        self.readout = MiReadout(scene_set.scenes, self.camera, scene_set.seed, CalibrationSettings().sigma, objective)
        self.reading: MiReading | None = None
        self.maps = EventMapSession(self)  # rebuilding maps from raw events, the recordings' lengths
        self.result_maps: dict[str, dict] = {}  # how each map was made when the last result's run started
        self.held_out: list[HeldOutScore] = []  # the last result's held-out scenes, scored
        self.result_scores: ResultScores | None = None  # the last result's answers, on the readout's scale
        self._reference_mi: dict[tuple, float] = {}
        self.runner = Runner(self)
        self.overlay_seconds: list[float] = []  # server-side render+encode time of each frame
        self.ui_lock = threading.RLock()  # one change at a time: state and widgets stay in step

        gui = server.gui
        gui.configure_theme(control_width="large", show_share_button=False, brand_color=(28, 126, 214))
        gui.set_panel_label(TITLE)
        server.gui.main_panel.dock_right()
        self.overlay = OverlayPanel(self)
        tabs = gui.add_tab_group()
        with tabs.add_tab("Scenes"):
            self.scenes = ScenesPanel(self)
            self.event_maps = EventMapsPanel(self)
        with tabs.add_tab("Seed"):
            self.extrinsic = ExtrinsicPanel(self)
            self.pairs = PairsPanel(self)
        with tabs.add_tab("Optimise"):
            self.optimise = OptimisePanel(self)
        with tabs.add_tab("Target"):
            self.target = TargetPanel(self)
        with tabs.add_tab("Result"):
            self.results = ResultPanel(self)
        with tabs.add_tab("QA"):
            self.qa = QAPanel(self)
        self.compare = ComparePanel(self, self.overlay)
        self.view3d = View3D(self)

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
        self.recording_worker = LatestWorker("recording", self.maps.read_recording)
        self.refresh()

    # --- the URL ----------------------------------------------------------------------------
    @property
    def url(self) -> str:
        host = self.server.get_host()
        shown = "127.0.0.1" if host in ("0.0.0.0", "") else host
        return f"http://{shown}:{self.server.get_port()}"

    # --- changes from any panel ----------------------------------------------------------------
    def set_extrinsic(self, extrinsic: Extrinsic, source: str = "", values: np.ndarray | None = None) -> None:
        """Make ``extrinsic`` current (one undo step) and update every view but its source.

        ``values``: the Seed panel's exact six numbers when the change came from there.
        """
        with self.ui_lock:
            self.state.set_extrinsic(extrinsic, source)
            self._show_extrinsic(extrinsic, source, values)

    def undo(self) -> None:
        with self.ui_lock:
            ext = self.state.undo()
            if ext is not None:
                self._show_extrinsic(ext, "undo")

    def redo(self) -> None:
        with self.ui_lock:
            ext = self.state.redo()
            if ext is not None:
                self._show_extrinsic(ext, "redo")

    def _show_extrinsic(self, extrinsic: Extrinsic, source: str, values: np.ndarray | None = None) -> None:
        with self.ui_lock:
            self.extrinsic.show(extrinsic, values, source)
            if source in DEFERRED_3D_SOURCES:
                self._pose_3d_pending = True  # the 3D view follows once the input rests
                self.pose_settle.poke()
            elif source != "gizmo":
                self.view3d.show_pose(extrinsic)
            self.extrinsic.show_pose_text(extrinsic)
            self.pairs.show()
        self.overlay_worker.poke()
        self.mi_worker.poke()

    def select_scene(self, index: int) -> None:
        with self.ui_lock:
            self.state.select(index)
        self.overlay_worker.poke()  # first: the overlay is what the user is waiting for
        with self.ui_lock:
            self.scenes.show_selection(table=False)
            self.event_maps.show()
        # the two tables of every scene follow at rest: re-rendering 40-100 rows of markdown takes
        # the page's main thread just when the new overlay should be painted
        self._tables_stale = True
        self.table_settle.poke()
        self.recording_worker.poke()
        self.mi_worker.poke()
        self.compare_worker.poke()

    def _show_scene_3d(self) -> None:
        self.overlay_worker.wait_idle(1.0)
        with self.ui_lock:
            selected = self.state.snapshot().selected
            self.view3d.show_scene(selected)
            self.target.show_3d(selected)

    def inclusion_changed(self) -> None:
        self.scenes.show_selection()
        self.target.show_table()
        self.optimise.show_start()
        self.mi_worker.poke()

    def target_changed(self) -> None:
        """The board, its detections or the marks' switch changed (Target tab)."""
        if getattr(self, "target", None) is None:  # the Target tab is being built
            return
        self.optimise.show_start()
        self.overlay_worker.poke()
        self.scene_3d_worker.poke()

    def annotate(self, index: int, extrinsic: Extrinsic, image: np.ndarray, point_size: int,
                 box: tuple[float, float, float, float] | None = None) -> np.ndarray:
        """The overlay of scene ``index`` (showing map window ``box``, None: all of it) with what
        the Target tab marks on it (board corners, board points)."""
        return self.target.annotate(index, extrinsic, image, point_size, box)

    def target_problem(self) -> str:
        """Why a checkerboard run cannot start ("" when it can)."""
        return self.target.problem()

    def display_changed(self) -> None:
        """A display control moved (colour, size, opacity, contrast, map)."""
        self.overlay_worker.poke()
        self.compare_worker.poke()

    def image_clicked(self, x: float, y: float) -> bool:
        """A click on the overlay at map pixel (x, y); True when a pair being picked took it."""
        if self.pairs.wants_pixel():
            self.pairs.pixel_picked(x, y)
            return True
        return False

    def picking_changed(self, on: bool) -> None:
        """Picking pairs for PnP started or stopped: the 3D view looks through the camera and widens."""
        with self.ui_lock:
            self.overlay.set_picking(on)
            self.view3d.set_picking(on)

    def current_pairs(self) -> list[Pair]:
        """The clicked lidar/pixel pairs (saved with the seed)."""
        return self.pairs.pairs()

    def compare_changed(self) -> None:
        """A before/after control moved."""
        self.compare_worker.poke()

    def follow_changed(self, follow: bool) -> None:
        """The overlay follows the optimiser's best estimate (and shows the result after) or not."""
        self.state.set_follow_best(follow)
        self.overlay_worker.poke()

    def sigma_changed(self, sigma: float) -> None:
        self.readout.set_sigma(sigma)
        self.mi_worker.poke()
        self.overlay_worker.poke()  # the "smoothed" map view uses the same sigma
        self.compare_worker.poke()

    def refresh(self) -> None:
        """Draw every panel from the state (at start-up)."""
        snap = self.state.snapshot()
        self.extrinsic.show(snap.extrinsic)
        self.extrinsic.show_pose_text(snap.extrinsic)
        self.view3d.show_scene(snap.selected)
        self.view3d.show_pose(snap.extrinsic)
        self.scenes.show_selection()
        self.results.show(snap)
        self.recording_worker.poke()
        self.overlay_worker.poke()
        self.mi_worker.poke()
        self.compare_worker.poke()
        self.target.detect_boards()

    # --- event maps (rebuilt from raw recordings: :class:`EventMapSession`) ------------------
    def recording(self, index: int) -> EventStats | str | None:
        return self.maps.recording(index)

    def rebuilding(self) -> bool:
        return self.maps.rebuilding()

    def rebuild_maps(self, settings: Accumulation, all_event_scenes: bool = False) -> None:
        self.maps.rebuild(settings, all_event_scenes)

    # --- workers ----------------------------------------------------------------------------
    def _render_overlay(self) -> None:
        t0 = time.perf_counter()
        snap = self.state.snapshot()
        rest, self._want_rest = self._want_rest, False
        try:
            self.overlay.render(snap, rest=rest)
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
        if not self.overlay.rest_frame:
            self._want_rest = True
            self.overlay_worker.poke()

    def _pose_3d_at_rest(self) -> None:
        """Rapid inputs stopped: pose the 3D camera (not on every step of a drag or of a run of
        key presses, see ``POSE_3D_REST_S``)."""
        with self.ui_lock:
            if self._pose_3d_pending:
                self._pose_3d_pending = False
                self.view3d.show_pose(self.state.snapshot().extrinsic)

    def _update_mi(self) -> None:
        # Starts once the overlay's frame of this state is handed to viser (or after
        # FRAME_FIRST_S): the frame is what a person waits for, and at 40 full-size scenes on
        # 2 loaded cores the readout beside it made it 54-76 ms instead of 26-36 ms, while the
        # readout itself finished at about the same time (144-188 ms either way).
        self._wait_for_frame(self.state.snapshot().version)
        snap = self.state.snapshot()  # the latest state: it may have moved on meanwhile
        key = (self.readout.generation, snap.included)  # read first: a newer map only makes it stale
        reading = self.readout.read(snap.extrinsic, snap.included)
        if key not in self._reference_mi:
            self._reference_mi[key] = self.readout.read(snap.reference, snap.included).total
        self.reading = reading
        self.extrinsic.show_mi(reading, snap, self._reference_mi[key])
        self.overlay.show_caption(snap, reading)
        self.table_settle.poke()

    def _table_at_rest(self) -> None:
        with self.ui_lock:
            if self.reading is not None or self._tables_stale:
                self.scenes.show_mi(self.reading)
            if self._tables_stale:
                self._tables_stale = False
                self.target.show_table()

    def _wait_for_frame(self, version: int) -> None:
        """Return once the overlay frame of state ``version`` is handed to viser (at most
        ``FRAME_FIRST_S``; at once when no frame is coming)."""
        if not self.overlay_worker.wait_idle(0):
            with self._frame_cond:
                self._frame_cond.wait_for(lambda: self._frame_version >= version, FRAME_FIRST_S)

    def _render_compare(self) -> None:
        self._wait_for_frame(self.state.snapshot().version)  # the live overlay first (it is on show)
        self.compare.render()

    # --- the optimisation -----------------------------------------------------------------------
    def run_settings(self) -> CalibrationSettings:
        """The optimiser settings the Optimise tab holds now (raises ValueError when refused)."""
        return self.optimise.settings()

    def start_run(self, settings: CalibrationSettings, method: str = METHOD_NAMES[0]) -> int:
        """Start ``method`` (one of ``METHOD_NAMES``: the score climb with ``settings``, or the
        checkerboard solve with the Target tab's board) on the included scenes from the current
        extrinsic (RuntimeError while event maps are being rebuilt, ValueError for a refused board)."""
        if method == CHECKERBOARD:
            board = self.target.board()
            return self.runner.start(checkerboard(self.scene_set.scenes, self.camera, board,
                                                  self.target.cached_detections(board)))
        return self.runner.start(targetless(settings, self.target.evidence()))

    def run_label(self) -> str:
        """The name of the score the current (or last) run reports."""
        return self.runner.label() or self.readout.label

    def cancel_run(self) -> bool:
        """Ask a running calibration to stop (it returns its best point so far)."""
        return self.runner.cancel()

    def cancel_requested(self) -> bool:
        """True once Cancel was pressed for the run in progress."""
        return self.runner.cancel_requested()

    def wait_run(self, timeout: float = 60.0) -> bool:
        return self.runner.wait(timeout)

    def result_shown(self, snap) -> None:
        """A run ended: score its held-out scenes and its answers, and show the result everywhere."""
        self.held_out = self._score_held_out(snap.result)
        try:
            self.result_scores = result_scores(snap, self.state.scene_names, self.readout)
        except Exception:  # a score is not worth losing the result over
            log.exception("scoring the result's answers failed")
            self.result_scores = None
        self.results.show(snap, self.held_out, self.result_scores)
        self.optimise.show_handed_back(self.result_scores)
        self.target.result_shown(snap.result)
        self.overlay_worker.poke()
        self.mi_worker.poke()  # refreshes the captions
        self.compare_worker.poke()

    # --- results ----------------------------------------------------------------------------------
    def _score_held_out(self, result: CalibrationResult | None) -> list[HeldOutScore]:
        if result is None:
            return []
        try:
            return held_out_scores(result, self.state.scene_names, self.readout)
        except Exception:  # a score is not worth losing the result over
            log.exception("scoring the held-out scenes failed")
            return []

    def accept_result(self) -> None:
        with self.ui_lock:
            self._show_extrinsic(self.state.accept_result(), "accept")

    def save_result(self) -> tuple[Path, Path | None]:
        """Write the result file and a full-size side-by-side PNG of the selected scene."""
        snap = self.state.snapshot()
        if snap.result is None:
            raise RuntimeError("there is no result to save")
        image = self.compare.compose(snap, mode="side by side", scale=1.0)
        held = self._score_held_out(snap.result)  # the inclusion may have changed since the run
        now = {sc.name: sc.map_record() for sc in self.scene_set.scenes}
        # optimised scenes: the maps the run used; held-out scenes are scored now, on today's maps
        maps = {name: (now if name in {h.name for h in held} else self.result_maps).get(name, now.get(name))
                for name in self.state.scene_names}
        return save_result(self.out_dir, snap.result, self.camera, Path(self.scene_set.root), image, held,
                           snap.verdict, maps, snap.judging_cancelled)

    def set_out_dir(self, text: str) -> str:
        """Use the folder ``text`` for results and seeds from now on; returns a note ("" if none).

        Raises ValueError (nothing changes) when ``text`` cannot be a folder."""
        folder, note = check_results_dir(text, self.scene_set.root)
        if folder is None:
            raise ValueError(note)
        self.out_dir = folder
        return note

    def discard_result(self) -> None:
        self.state.discard_result()
        self.held_out, self.result_scores = [], None
        self.results.show(self.state.snapshot())
        self.compare_worker.poke()
        self.mi_worker.poke()

    # --- notifications --------------------------------------------------------------------------------
    def notify(self, client: Any, title: str, body: str, color: str | None = None) -> None:
        """Show a notification in one tab (``client``), or in all when ``client`` is None."""
        if client is None:
            self.notify_all(title, body, color)
            return
        client.add_notification(title, body, auto_close_seconds=12.0, color=color)

    def notify_all(self, title: str, body: str, color: str | None = None) -> None:
        for client in self.server.get_clients().values():
            try:
                self.notify(client, title, body, color)
            except Exception:  # a tab closing right now
                log.debug("notification to a closing client failed", exc_info=True)

    # --- shutdown -------------------------------------------------------------------------------------
    def stop(self, timeout: float = STOP_S) -> None:
        """Stop the app's threads and its server in about ``timeout`` seconds, however busy: a
        run is cancelled (its result file still written), every worker told to stop at once,
        then all are waited for against one deadline (not ``timeout`` each in turn: a Ctrl-C
        on a busy app had taken past 20 s)."""
        self.cancel_run()
        threads = (self.overlay_settle, self.pose_settle, self.table_settle, self.target.worker, self.overlay_worker,
                   self.mi_worker, self.compare_worker, self.scene_3d_worker, self.recording_worker)
        for t in threads:
            t.request_stop()
        deadline = time.monotonic() + timeout
        self.wait_run(max(0.0, deadline - time.monotonic()))
        self.maps.rebuilder.wait(max(0.0, deadline - time.monotonic()))
        join_by(threads, deadline)
        self.server.stop()


def build_app(
    scene_set: SceneSet,
    host: str = "127.0.0.1",
    port: int = 8080,
    out_dir: str | Path | None = None,
    verbose: bool = False,
    objective: str = "auto",
) -> App:
    """Start a viser server on ``host:port`` and build the workbench on it; ``objective`` is
    the score read out and climbed (``auto``: from the map kind)."""
    server = viser.ViserServer(host=host, port=port, label=TITLE, verbose=verbose)
    out = Path(out_dir) if out_dir is not None else default_results_dir(scene_set.root)
    try:
        return App(scene_set, server, out, objective)
    except BaseException:
        server.stop()
        raise


def serve(
    scene_set: SceneSet,
    host: str = "127.0.0.1",
    port: int = 8080,
    out_dir: str | Path | None = None,
    on_ready: Callable[[App], None] | None = None,
    stop: threading.Event | None = None,
    objective: str = "auto",
) -> None:
    """Serve until interrupted (or until ``stop`` is set)."""
    app = build_app(scene_set, host, port, out_dir, objective=objective)
    if on_ready is not None:
        on_ready(app)
    try:
        if stop is None:
            while True:
                time.sleep(3600)
        else:
            stop.wait()
    finally:
        app.stop()
