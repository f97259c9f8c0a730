"""The workbench server: one viser server, one shared session, the panels and the views.

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
from .views import Views
from .workers import join_by

log = logging.getLogger(__name__)

TITLE = "L2E Studio"
STOP_S = 5.0  # App.stop: every thread and a run in progress get this long, all together
DEFERRED_3D_SOURCES = frozenset({"sliders", "typed", "nudge", "gizmo-fine"})  # rapid inputs: the gizmo follows at rest


class App:
    """A running workbench. Create with :func:`build_app`; stop with :meth:`stop`."""

    def __init__(self, scene_set: SceneSet, server: viser.ViserServer, out_dir: Path, objective: str = "auto",
                 edge_gradient: str = "magnitude") -> None:
        self.scene_set = scene_set
        self.server = server
        self.camera = scene_set.camera
        self.out_dir = Path(out_dir)
        self.state = SessionState(scene_set.names, reference=scene_set.seed)
        self.displays = [SceneDisplay(s) for s in scene_set.scenes]
        # The readout smooths the maps like the optimiser's default; the sigma field updates both.
        self.edge_gradient = edge_gradient  # what the edge maps read (CalibrationSettings.edge_gradient)
        self.readout = MiReadout(scene_set.scenes, self.camera, scene_set.seed, CalibrationSettings().sigma, objective,
                                 edge_gradient)
        self.reading: MiReading | None = None
        self.maps = EventMapSession(self)  # rebuilding maps from raw events, the recordings' lengths
        self.result_maps: dict[str, dict] = {}  # how each map was made when the last result's run started
        self.held_out: list[HeldOutScore] = []  # the last result's held-out scenes, scored
        self.result_scores: ResultScores | None = None  # the last result's answers, on the readout's scale
        self.runner = Runner(self)
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

        self.views = Views(self)  # the overlay, the readout and the rest follow the state in their threads
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
                self.views.pose_3d_at_rest()
            elif source != "gizmo":
                self.view3d.show_pose(extrinsic)
            self.extrinsic.show_pose_text(extrinsic)
            self.pairs.show()
        self.views.overlay_worker.poke()
        self.views.mi_worker.poke()

    def select_scene(self, index: int) -> None:
        with self.ui_lock:
            self.state.select(index)
        self.views.overlay_worker.poke()  # first: the overlay is what the user is waiting for
        with self.ui_lock:
            self.scenes.show_selection(table=False)
            self.event_maps.show()
        self.views.tables_at_rest()  # the two tables of every scene
        self.views.recording_worker.poke()
        self.views.mi_worker.poke()
        self.views.compare_worker.poke()

    def inclusion_changed(self) -> None:
        self.scenes.show_selection()
        self.target.show_table()
        self.optimise.show_start()
        self.views.mi_worker.poke()

    def target_changed(self) -> None:
        """The board, its detections or the marks' switch changed (Target tab)."""
        if getattr(self, "target", None) is None:  # the Target tab is being built
            return
        self.optimise.show_start()
        self.views.overlay_worker.poke()
        self.views.scene_3d_worker.poke()

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
        self.views.overlay_worker.poke()
        self.views.compare_worker.poke()

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
        self.views.compare_worker.poke()

    def follow_changed(self, follow: bool) -> None:
        """The overlay follows the optimiser's best estimate (and shows the result after) or not."""
        self.state.set_follow_best(follow)
        self.views.overlay_worker.poke()

    def sigma_changed(self, sigma: float) -> None:
        self.readout.set_sigma(sigma)
        self.views.mi_worker.poke()
        self.views.overlay_worker.poke()  # the "smoothed" map view uses the same sigma
        self.views.compare_worker.poke()

    def refresh(self) -> None:
        """Draw every panel from the state (at start-up)."""
        snap = self.state.snapshot()
        self.extrinsic.show(snap.extrinsic)
        self.extrinsic.show_pose_text(snap.extrinsic)
        self.view3d.show_scene(snap.selected)
        self.view3d.show_pose(snap.extrinsic)
        self.scenes.show_selection()
        self.results.show(snap)
        self.views.recording_worker.poke()
        self.views.overlay_worker.poke()
        self.views.mi_worker.poke()
        self.views.compare_worker.poke()
        self.target.detect_boards()

    # --- event maps (rebuilt from raw recordings: :class:`EventMapSession`) ------------------
    def recording(self, index: int) -> EventStats | str | None:
        return self.maps.recording(index)

    def rebuilding(self) -> bool:
        return self.maps.rebuilding()

    def rebuild_maps(self, settings: Accumulation, all_event_scenes: bool = False) -> None:
        self.maps.rebuild(settings, all_event_scenes)

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
        self.views.overlay_worker.poke()
        self.views.mi_worker.poke()  # refreshes the captions
        self.views.compare_worker.poke()

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
        self.views.compare_worker.poke()
        self.views.mi_worker.poke()

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
        run is cancelled (its result file still written), every view told to stop at once, and
        all are waited for against one deadline (not ``timeout`` each in turn: a Ctrl-C on a busy
        app could have taken past 20 s)."""
        self.cancel_run()
        deadline = time.monotonic() + timeout
        self.target.worker.request_stop()
        self.views.stop(deadline)
        self.wait_run(max(0.0, deadline - time.monotonic()))
        self.maps.rebuilder.wait(max(0.0, deadline - time.monotonic()))
        join_by((self.target.worker,), deadline)
        self.server.stop()


def build_app(
    scene_set: SceneSet,
    host: str = "127.0.0.1",
    port: int = 8080,
    out_dir: str | Path | None = None,
    verbose: bool = False,
    objective: str = "auto",
    edge_gradient: str = "magnitude",
) -> App:
    """Start a viser server on ``host:port`` and build the workbench on it; ``objective`` is
    the score read out and climbed (``auto``: from the map kind), ``edge_gradient`` what its
    edge maps read."""
    server = viser.ViserServer(host=host, port=port, label=TITLE, verbose=verbose)
    out = Path(out_dir) if out_dir is not None else default_results_dir(scene_set.root)
    try:
        return App(scene_set, server, out, objective, edge_gradient)
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
    edge_gradient: str = "magnitude",
) -> None:
    """Serve until interrupted (or until ``stop`` is set)."""
    app = build_app(scene_set, host, port, out_dir, objective=objective, edge_gradient=edge_gradient)
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
