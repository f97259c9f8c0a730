"""Checkerboard (target-based) calibration: a second method beside the targetless score climb.

A board (``target.yaml``: ``kind: checkerboard``, ``squares: [columns, rows]``, ``square_m``,
optional ``size_m: [width, height]``) is held in front of the rig and moved between scans. The
board is found in every image and every scan, and the extrinsic is solved from all frames
together. The result is the engine's own :class:`l2e_studio.calibrate.CalibrationResult`
(``method="target"``, ``objective="board planes"``, scores = minus the RMS point-to-plane
distance in mm, higher is better), with the per-frame table and the uncertainty in
``result.target`` (a :class:`TargetDetail`); it is judged by
:func:`l2e_studio.target_verdict.judge_target` into the same :class:`l2e_studio.verdict.Verdict`.

Public API (stable; the app and the synthetic boards build on it):

* :class:`Board`, :func:`load_target` (a bad file is one :class:`InputError` naming it and what
  was expected), :func:`find_target` (``target.yaml`` of a scene folder, or None).
  Board frame: origin at the board's centre, x along the columns, y along the rows, z into the
  board (OpenCV); :meth:`Board.corners` (inner corners), :meth:`Board.outline` (outer edge).
* :func:`detect_board` / :func:`detect_cached` (one image) and :func:`detect_frames` (every
  scene's image, cached in ``$XDG_CACHE_HOME/l2e-studio/target``) -> :class:`Detection`:
  ``found``, ``reason``, ``corners`` (N, 2) px, ``pose`` (``T_cam_board``), ``reprojection_px``,
  ``method``; :func:`board_pose` (PnP on undistorted corners, radtan or equidistant).
* :func:`search_board` (around a seed up to ~5 deg / 20 cm off) and :func:`crop_board` (inside the
  outline at a close extrinsic) -> :class:`LidarBoard`: ``found``, ``reason``, ``indices`` into
  the scan, ``points``, plane ``normal``/``offset``, ``edges``.
* :class:`TargetFrame` (camera board pose + lidar board points and edges), :func:`closed_form`,
  :func:`solve` -> :class:`Solution`, :func:`frame_residuals`, :func:`observability` ->
  :class:`Observability` (which direction the boards leave unobserved, which pose to add).
* :func:`calibrate_target` ``(scenes, camera, seed, board, settings=TargetSettings(),
  exclude=(), on_progress=None, cancel=None, use_cache=True, detections=None) ->
  CalibrationResult``: ``exclude`` names frames the user left out; ``on_progress`` gets
  :class:`l2e_studio.calibrate.Progress`; ``cancel`` (a ``threading.Event``) stops it.
  ``result.target.frames``: one :class:`FrameRecord` per scene (detected, reprojection, lidar
  points, plane/edge residuals, used or left out with the reason, leave-one-out move);
  ``result.target.sigma_m`` / ``sigma_deg``: per-axis standard deviations (camera frame).
* the board as a check on any calibration (e.g. a targetless result): this method run from it,
  compared in :func:`l2e_studio.target_verdict.with_boards`.

Layering: beside :mod:`l2e_studio.calibrate` (uses geometry, camera, scenes, io and calibrate's
types; never verdict, qa, app or cli).
"""

from .board import Board, find_target, load_target
from .detect import Detection, board_pose, detect_board, detect_cached
from .engine import (FrameRecord, TargetDetail, TargetSettings, calibrate_target, detect_frames,
                     scan_rings)
from .lidar import LidarBoard, crop_board, search_board
from .solve import Observability, Solution, TargetFrame, closed_form, frame_residuals, observability, solve

__all__ = [
    "Board", "find_target", "load_target",
    "Detection", "board_pose", "detect_board", "detect_cached", "detect_frames",
    "LidarBoard", "crop_board", "search_board",
    "Observability", "Solution", "TargetFrame", "closed_form", "frame_residuals", "observability", "solve",
    "FrameRecord", "TargetDetail", "TargetSettings", "calibrate_target", "scan_rings",
]
