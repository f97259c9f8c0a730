"""The target mode: the board, its detection in every frame, and the frames' table.

The board comes from the scene folder's ``target.yaml`` and can be edited (checked as typed,
never clamped). Boards are detected in the background (the engine's detectors, cached) and each
frame's lidar board is searched where the current extrinsic puts the camera's board; after a
checkerboard run the table shows the run's own frames: detection, lidar points, residuals,
used or left out and why. A click on a row shows that frame, on its first cell includes or
leaves it out (the frames are the scenes: the same inclusion as the Scenes tab).

The overlay draws the detected corners (green, the first red) and the lidar board points
(magenta) through :meth:`TargetPanel.annotate`; the 3D view shows the board points too.
The run itself is :func:`l2e_studio.app.runs.checkerboard` on the Runner, like the score climb.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass

import cv2
import numpy as np

from ..context import Workbench
from ..exact import parse_number
from ..text import num
from ..workers import LatestWorker
from ...errors import InputError
from ...geometry import Extrinsic, project_points
from ...target import Board, detect_frames, find_target, load_target, scan_rings, search_board
from ...target_verdict import with_boards

log = logging.getLogger(__name__)

TABLE_MARK = "use"  # the scene table's mark: the page script sends row clicks to the Scene pointer
CORNER_RGB = (40, 220, 60)
FIRST_CORNER_RGB = (230, 40, 40)
BOARD_POINT_RGB = (255, 0, 200)


@dataclass(frozen=True)
class BoardFields:
    """The board as typed: the engine's Board, or the problems of each field."""

    board: Board | None
    problems: tuple[str, str, str]


def _numbers(text: str) -> list[float | None]:
    parts = str(text).lower().replace("×", "x").replace(",", " ").replace("x", " ").split()
    return [parse_number(p) for p in parts]


def check_board(squares: str, square_m: str, size_m: str) -> BoardFields:
    """The board from the three fields (``"10 x 7"``, ``"0.068"``, ``"0.8 x 0.6"`` or blank for
    the printed grid alone); each refused field gets a sentence saying why."""
    p_sq = p_side = p_size = ""
    sq = _numbers(squares)
    if len(sq) != 2 or any(v is None or v != int(v) or not 3 <= v <= 100 for v in sq):
        p_sq = f"Squares: “{squares}” is not two whole numbers of squares (columns x rows), 3..100 each"
    side = parse_number(square_m)
    if side is None or not 0.001 <= side <= 2.0:
        p_side = f"Square: “{square_m}” is not a side in metres within [0.001, 2]"
    size: tuple[float, float] | None = None
    if str(size_m).strip():
        vals = _numbers(size_m)
        if len(vals) != 2 or any(v is None or not 0.001 <= v <= 20 for v in vals):
            p_size = f"Board size: “{size_m}” is not width x height in metres within [0.001, 20]"
        else:
            size = (float(vals[0]), float(vals[1]))
    if not (p_sq or p_side):
        grid = (sq[0] * side, sq[1] * side)
        if size is None and not p_size:
            size = grid
        elif size is not None and (size[0] < grid[0] - 1e-6 or size[1] < grid[1] - 1e-6):
            p_size = (f"Board size: {size[0]:g} x {size[1]:g} m is smaller than the printed grid "
                      f"({grid[0]:.3f} x {grid[1]:.3f} m)")
    problems = (p_sq, p_side, p_size)
    if any(problems):
        return BoardFields(None, problems)
    return BoardFields(Board("checkerboard", (int(sq[0]), int(sq[1])), float(side), size), problems)


def draw_board_marks(image: np.ndarray, corners: np.ndarray | None, board_uv: np.ndarray | None,
                     point_size: int = 2) -> np.ndarray:
    """``image`` (H, W, 3 uint8) with the board's lidar points (magenta discs) and the detected
    corners (green rings, the first corner red) drawn over it."""
    out = image.copy()
    r = max(1, int(point_size) - 1)
    if board_uv is not None:
        for u, v in np.rint(board_uv).astype(int):
            cv2.circle(out, (int(u), int(v)), r, BOARD_POINT_RGB, -1)
    if corners is not None and len(corners):
        c = np.asarray(corners, float)
        step = float(np.median(np.linalg.norm(np.diff(c, axis=0), axis=1))) if len(c) > 1 else 10.0
        ring = max(2.0, 0.3 * step)  # a third of the squares' size: neighbours' rings never touch
        for i, (u, v) in enumerate(c):
            color = FIRST_CORNER_RGB if i == 0 else CORNER_RGB
            cv2.circle(out, (int(round(u * 16)), int(round(v * 16))), int(round(ring * 16)), color, 1, cv2.LINE_AA, shift=4)
    return out


@dataclass(frozen=True)
class FrameView:
    """What the table and the overlay show of one frame (from detection, or from the last run)."""

    name: str
    detected: bool
    detector: str = ""
    reprojection_px: float = float("nan")
    corners: np.ndarray | None = None
    board_indices: np.ndarray | None = None  # into the scene's points
    lidar_points: int = 0
    plane_rms_m: float = float("nan")
    edge_rms_m: float = float("nan")
    used: bool | None = None  # None: no run yet
    note: str = ""


def frame_views_from_result(result) -> list[FrameView]:
    """One :class:`FrameView` per frame of a checkerboard result (``result.target.frames``)."""
    out = []
    for f in result.target.frames:
        det, lb = f.detection, f.lidar
        out.append(FrameView(f.name, det.found, det.method, det.reprojection_px, det.corners,
                             lb.indices if lb.found else None, lb.n_points if lb.found else 0,
                             f.plane_rms_m, f.edge_rms_m, f.used, f.reason))
    return out


def short_detector(method: str) -> str:
    """The detector's name as the table shows it: ``quad`` (findChessboardCorners, ``x2`` on the
    image upscaled) or ``SB`` (findChessboardCornersSB)."""
    m = method.replace(" + cornerSubPix", "").replace("findChessboardCornersSB", "SB")
    return m.replace("findChessboardCorners", "quad").strip()


TABLE_KEY = ("board: the detector that found it (quad, SB) or ✗ · px: the corners' reprojection RMS · pts: lidar board points · plane, edge: RMS (mm) of the board "
             "points to the camera's board plane and of the edge points to its outline, at the last result · "
             "click a row to show it, its ✓ to leave it out or take it back")


def frames_table(views: list[FrameView], included: list[bool], names: list[str], selected: int) -> str:
    """Markdown: a row per frame (its first cell includes / leaves it out, as the scene table)."""
    by_name = {v.name: v for v in views}
    rows = [TABLE_KEY, "", f"| {TABLE_MARK} | frame | board | px | pts | plane | edge | note |",
            "|:-:|:--|:-:|--:|--:|--:|--:|:--|"]
    for i, name in enumerate(names):
        v = by_name.get(name)
        mark = "✓" if included[i] else "–"
        label = f"**{name}**" if i == selected else name
        if v is None:
            rows.append(f"| {mark} | {label} | … | | | | | not detected yet |")
            continue
        board = short_detector(v.detector) if v.detected else "✗"
        note = v.note.replace("|", "/")
        rows.append(f"| {mark} | {label} | {board} | {num(v.reprojection_px, 2)} | {v.lidar_points or '—'} | "
                    f"{num(1000 * v.plane_rms_m, 1)} | {num(1000 * v.edge_rms_m, 1)} | {note} |")
    return "\n".join(rows)


class TargetPanel:
    """The Target tab. The App calls :meth:`annotate` (overlay), :meth:`show_3d` (3D view),
    :meth:`result_shown` (a run ended), :meth:`board` / :meth:`cached_detections` (the
    checkerboard run to start) and :meth:`detect_boards` (once the workbench is up)."""

    def __init__(self, app: Workbench) -> None:
        self.app = app
        gui = app.server.gui
        self._lock = threading.Lock()
        self.views: dict[str, FrameView] = {}
        self.detections: dict[str, object] = {}  # name -> the engine's Detection, of ``_detected_for``
        self._detected_for: Board | None = None
        path = find_target(app.scene_set.root)
        board, source = None, "No `target.yaml` in the scene folder: type the board below."
        if path is not None:
            try:
                board = load_target(path)
                source = f"Board from `{path}`."
            except InputError as exc:
                source = f"⚠ {exc}; type the board below."
        self.source = gui.add_markdown(source)
        squares = "" if board is None else f"{board.squares[0]} x {board.squares[1]}"
        self.squares = gui.add_text("Squares (columns x rows)", squares,
                                    hint="Squares, not inner corners: a 10 x 7 board has 9 x 6 inner corners")
        self.squares_problem = gui.add_markdown("", visible=False)
        self.square = gui.add_text("Square (m)", "" if board is None else f"{board.square_m:g}",
                                   hint="Side of one square in metres")
        self.square_problem = gui.add_markdown("", visible=False)
        self.size = gui.add_text("Board size (m)", "" if board is None else f"{board.size_m[0]:g} x {board.size_m[1]:g}",
                                 hint="Outer width x height, white margin included (blank: the printed grid alone)")
        self.size_problem = gui.add_markdown("", visible=False)
        self.detect = gui.add_button("Detect boards", hint="Find the board in every frame's image and lidar scan")
        self.marks = gui.add_checkbox("Show board marks", True,
                                      hint="Detected corners and the lidar board points on the overlay and in 3D")
        self.status = gui.add_markdown("")
        self.table = gui.add_markdown(self._table())
        self.cloud = app.server.scene.add_point_cloud("/board_points", np.zeros((1, 3), np.float32),
                                                      np.array([BOARD_POINT_RGB], np.uint8), point_size=0.03,
                                                      point_shape="circle", visible=False)
        self.worker = LatestWorker("target-detect", self._detect_all)
        for handle in (self.squares, self.square, self.size):
            handle.on_update(lambda _: self.check())
        self.detect.on_click(lambda _: self.detect_boards())
        self.marks.on_update(lambda _: app.target_changed())
        self.check()

    def detect_boards(self) -> None:
        """Detect the board in every frame, in the background (nothing when the board is refused)."""
        if not self.detect.disabled:
            self.worker.poke()

    # --- the board ------------------------------------------------------------------------
    def check(self):
        """Show each field's problem beside it; the board, or None."""
        fields = check_board(self.squares.value, self.square.value, self.size.value)
        for note, problem in zip((self.squares_problem, self.square_problem, self.size_problem), fields.problems):
            note.content = f"⚠ {problem}" if problem else ""
            note.visible = bool(problem)
        self.detect.disabled = fields.board is None
        self.app.target_changed()
        return fields.board

    def board(self):
        """The board the fields describe (ValueError with the problems when refused)."""
        fields = check_board(self.squares.value, self.square.value, self.size.value)
        if fields.board is None:
            raise ValueError("; ".join(p for p in fields.problems if p))
        return fields.board

    def problem(self) -> str:
        """Why a checkerboard run cannot start ("" when it can)."""
        try:
            self.board()
        except ValueError as exc:
            return f"the board settings are refused ({exc})"
        return ""

    # --- detection ------------------------------------------------------------------------
    def _detect_all(self) -> None:
        """Detect the board in every frame (cached), then search each detected frame's lidar board
        where the current extrinsic puts it."""
        try:
            board = self.board()
        except ValueError:
            return
        scenes = self.app.scene_set.scenes
        self.status.content = f"Detecting the board in {len(scenes)} frames..."

        def on_frame(i: int, n: int, name: str) -> None:
            self.status.content = f"Detecting the board: frame {i + 1} of {n} ({name})..."

        detections = detect_frames(scenes, self.app.camera, board, on_frame=on_frame)
        extrinsic = self.app.state.snapshot().extrinsic
        views = {}
        for sc, det in zip(scenes, detections):
            lb = None
            if det.found:
                try:
                    lb = search_board(sc.points, scan_rings(sc), det, board, extrinsic)
                except Exception:  # a lidar search is not worth losing the detections over
                    log.exception("lidar board search failed for %s", sc.name)
            found = lb is not None and lb.found
            note = "" if det.found and found else (f"image: {det.reason}" if not det.found
                                                   else f"lidar: {lb.reason}" if lb is not None else "")
            views[sc.name] = FrameView(sc.name, det.found, det.method, det.reprojection_px, det.corners,
                                       lb.indices if found else None, lb.n_points if found else 0, note=note)
        with self._lock:
            self.detections = {d.name or sc.name: d for sc, d in zip(scenes, detections)}
            self._detected_for = board
            self.views = views
        n_found = sum(v.detected for v in views.values())
        n_lidar = sum(v.board_indices is not None for v in views.values())
        self.status.content = (f"Board found in **{n_found} of {len(scenes)}** images and {n_lidar} lidar scans "
                               f"(lidar searched around the extrinsic at detection).")
        self.show_table()
        self.app.target_changed()

    def cached_detections(self, board) -> list | None:
        """The detections of every scene for ``board`` when they are at hand (else None: the run detects)."""
        with self._lock:
            if self._detected_for != board:
                return None
            names = [sc.name for sc in self.app.scene_set.scenes]
            dets = [self.detections.get(n) for n in names]
        return None if any(d is None for d in dets) else dets

    def evidence(self):
        """The boards as evidence on a targetless verdict (``(stack, verdict, seed) -> verdict``,
        :func:`l2e_studio.target_verdict.with_boards` over the run's scenes) when a board is set
        and detected in every frame; else None."""
        try:
            board = self.board()
        except ValueError:
            return None
        dets = self.cached_detections(board)
        if dets is None:
            return None
        scenes, camera = self.app.scene_set.scenes, self.app.camera

        def check(stack, verdict, seed):
            names = set(stack.names)
            used = [i for i, sc in enumerate(scenes) if sc.name in names]
            return with_boards(verdict, seed, [scenes[i] for i in used], camera, board, [dets[i] for i in used])

        return check

    # --- after a run ----------------------------------------------------------------------
    def result_shown(self, result) -> None:
        """A run ended: a checkerboard result's frames replace the detection-time table."""
        if result is None or getattr(result, "target", None) is None:
            return
        with self._lock:
            self.views = {v.name: v for v in frame_views_from_result(result)}
        n_used = sum(bool(v.used) for v in self.views.values())
        self.status.content = f"Last run: **{n_used} of {len(self.views)} frames used**; residuals at its result."
        self.show_table()
        self.app.target_changed()  # the marks follow the run's boards

    # --- views ----------------------------------------------------------------------------
    def _table(self) -> str:
        snap = self.app.state.snapshot()
        with self._lock:
            views = list(self.views.values())
        return frames_table(views, list(snap.included), list(self.app.state.scene_names), snap.selected)

    def show_table(self) -> None:
        self.table.content = self._table()

    def view(self, index: int) -> FrameView | None:
        with self._lock:
            return self.views.get(self.app.state.scene_names[index])

    def annotate(self, index: int, extrinsic: Extrinsic, image: np.ndarray, point_size: int,
                 box: tuple[float, float, float, float] | None = None) -> np.ndarray:
        """The overlay of frame ``index`` with its board marks (unchanged when off or unknown).
        ``image`` shows the map window ``box`` = (x0, y0, width, height) in map pixels (None:
        the whole map) at its own size, so marks are placed and sized in the image's pixels."""
        v = self.view(index) if self.marks.value else None
        if v is None or (v.corners is None and v.board_indices is None):
            return image
        cam = self.app.camera
        x0, y0, w, _ = box if box is not None else (0.0, 0.0, float(cam.width), float(cam.height))
        scale = image.shape[1] / float(w)

        def to_image(uv: np.ndarray) -> np.ndarray:
            return (np.asarray(uv, float) - (x0, y0)) * scale

        board_uv = None
        if v.board_indices is not None:
            pts = self.app.scene_set.scenes[index].points[v.board_indices]
            uv, front = project_points(extrinsic.transform(pts), cam)
            board_uv = to_image(uv[front])
        corners = None if v.corners is None else to_image(v.corners)
        return draw_board_marks(image, corners, board_uv, point_size)

    def show_3d(self, index: int) -> None:
        """The 3D view's board points for frame ``index`` (hidden when there are none)."""
        v = self.view(index) if self.marks.value else None
        if v is None or v.board_indices is None or not len(v.board_indices):
            self.cloud.visible = False
            return
        self.cloud.points = self.app.scene_set.scenes[index].points[v.board_indices].astype(np.float32)
        self.cloud.colors = np.tile(np.array(BOARD_POINT_RGB, np.uint8), (len(v.board_indices), 1))
        self.cloud.visible = True

