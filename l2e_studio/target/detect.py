"""The board in the image: inner corners to sub-pixel, the board's pose, its reprojection error.

Images are frame-camera pictures, grey images reconstructed from events (E2VID: 346x260,
blurred, noisy) or accumulated event maps of a moving or flashing board. Detectors are tried in
order until one finds the full grid (measured on the dev sets, benchmarks/bench_target.py):

1. ``findChessboardCorners`` (adaptive threshold, normalised) + ``cornerSubPix``: fast, finds
   every board of the frame-camera sets;
2. the same on the image upscaled 2x (cubic): small, blurred boards (E2VID at 346x260);
3. ``findChessboardCornersSB`` (exhaustive, accuracy): the sector-based detector, slower,
   robust to noise and blur where the quad detector fails;
4. the quad detector on the board's region alone, upscaled 2-4x: the largest bright blobs
   (Otsu on the blurred image, closed), each cropped with a margin. A flashing board's event
   map is a bright, speckled board on a dark field, often only ~100 px wide: on the whole image
   the speckle defeats the detectors (10 of 20 synthetic flashing boards found), on the region
   every one is (20 of 20, 25 ms a frame);
5. the quad detector on a moving board's event lines made a checkerboard picture again
   (:mod:`.event_lines`: the cells between the lines two-coloured), in each bright region. A
   shaken board's map shows the squares' edges as bright lines, black and white squares alike
   empty: no chessboard detector sees a checkerboard in it (0 of 30 synthetic shaken boards
   found by stages 1-4).

Before detection the image is stretched to 0..255 between its 0.5th and 99.5th percentiles
(event maps are counts, reconstructions are often low contrast). A frame where none finds the
full grid is reported with the reason, never guessed.

The pose is solved on undistorted normalised coordinates (the project's lens model, radtan or
equidistant), so any lens OpenCV's PnP does not model the same way is handled alike, and the
reprojection error is measured with :func:`l2e_studio.geometry.project_points`.

Detections are cached in ``$XDG_CACHE_HOME/l2e-studio/target`` keyed by the image's bytes, the
board and the camera (a JSON file per image; delete at will).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass

import cv2
import numpy as np

from ..atomic import atomic_write_bytes
from ..cachedir import user_cache_dir
from ..camera import CameraModel
from ..geometry import Extrinsic, project_points, undistort_normalised
from .board import Board
from .event_lines import TRIALS as LINE_TRIALS
from .event_lines import checker_picture, upscale

#: bump when detection changes, so stale cache entries are not used
DETECTOR_VERSION = 3
#: a detection whose corners reproject worse than this (px, at 1280 px wide) is not a board
MAX_REPROJECTION_PX = 3.0


@dataclass(frozen=True)
class Detection:
    """The board in one image. ``found`` False: ``reason`` says why and the rest is empty.

    ``corners``: (N, 2) inner corners in pixels (row-major as :meth:`Board.corners`);
    ``pose``: ``T_cam_board`` (board-frame points into the camera frame); ``reprojection_px``:
    RMS distance between the detected corners and the board reprojected at ``pose``;
    ``method``: which detector found it."""

    name: str
    found: bool
    reason: str = ""
    corners: np.ndarray | None = None
    pose: Extrinsic | None = None
    reprojection_px: float = float("nan")
    method: str = ""

    @property
    def normal(self) -> np.ndarray:
        """The board's normal in the camera frame (unit, pointing to the camera)."""
        assert self.pose is not None
        n = self.pose.R[:, 2]
        return -n if n @ self.pose.translation > 0 else n

    @property
    def plane(self) -> tuple[np.ndarray, float]:
        """``(n, d)`` of the board's plane in the camera frame: ``n . x = d`` (n towards the camera, d < 0)."""
        n = self.normal
        return n, float(n @ self.pose.translation)

    def to_dict(self) -> dict:
        d = {"name": self.name, "found": self.found, "reason": self.reason, "method": self.method,
             "reprojection_px": None if not np.isfinite(self.reprojection_px) else float(self.reprojection_px)}
        if self.found:
            d["corners"] = np.round(self.corners, 4).tolist()
            d["pose"] = {"rotvec": self.pose.rotvec.tolist(), "translation": self.pose.translation.tolist()}
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "Detection":
        pose = None if "pose" not in d else Extrinsic(d["pose"]["rotvec"], d["pose"]["translation"])
        corners = None if "corners" not in d else np.asarray(d["corners"], dtype=np.float64).reshape(-1, 2)
        rep = float("nan") if d.get("reprojection_px") is None else float(d["reprojection_px"])
        return cls(str(d["name"]), bool(d["found"]), str(d.get("reason", "")), corners, pose, rep, str(d.get("method", "")))


def normalise_image(image: np.ndarray) -> np.ndarray:
    """uint8 grey image stretched between its 0.5th and 99.5th percentiles (colour is averaged)."""
    img = np.asarray(image, dtype=np.float32)
    if img.ndim == 3:
        img = img.mean(axis=2)
    lo, hi = np.percentile(img, [0.5, 99.5])
    if hi <= lo:
        return np.zeros(img.shape, dtype=np.uint8)
    return np.clip((img - lo) * (255.0 / (hi - lo)), 0, 255).astype(np.uint8)


def find_corners(image: np.ndarray, board: Board) -> tuple[np.ndarray | None, str]:
    """(N, 2) inner corners to sub-pixel and the detector that found them, or ``(None, reason)``."""
    grey = normalise_image(image)
    pattern = board.inner
    for scale in (1, 2):
        corners = _quads(grey, pattern, scale)
        if corners is not None:
            return corners, f"findChessboardCorners{'' if scale == 1 else ' x2'} + cornerSubPix"
    sb = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
    ok, corners = cv2.findChessboardCornersSB(grey, pattern, flags=sb)
    if ok:
        return corners.reshape(-1, 2).astype(np.float64), "findChessboardCornersSB"
    regions = bright_regions(grey)
    for x0, y0, crop in regions:
        for scale in REGION_SCALES:
            corners = _quads(crop, pattern, scale)
            if corners is not None:
                return corners + (x0, y0), f"findChessboardCorners, board region x{scale} + cornerSubPix"
    lines = ""
    for x0, y0, crop in regions:
        corners, how = _line_grid(crop, pattern)
        if corners is not None:
            return corners + (x0, y0), how
        lines = lines or how
    return None, (f"no {pattern[0]}x{pattern[1]} inner-corner grid found (quad detector at 1x and 2x, "
                  "sector detector, bright regions upscaled, event lines two-coloured"
                  + (f": {lines}" if lines else "") + ")")


def _line_grid(crop: np.ndarray, pattern: tuple[int, int]) -> tuple[np.ndarray | None, str]:
    """Stage 5: the quad detector on the two-coloured picture of a moving board's event lines
    (:mod:`.event_lines`), refined there, either polarity; corners in ``crop``'s pixels, or
    ``(None, reason)``."""
    up, scale, cell = upscale(crop)
    why = ""
    for local, erode in LINE_TRIALS:
        picture, reason = checker_picture(up, cell, local, erode, (pattern[0] + 1) * (pattern[1] + 1))
        if picture is None:
            why = why or reason
            continue
        for inverted in (False, True):  # which colour is white: the quad detector wants the margin white
            corners = _quads(255 - picture if inverted else picture, pattern, 1)
            if corners is not None:
                return _to_original(corners, scale), (f"findChessboardCorners on the event lines two-coloured "
                                                      f"(x{scale}, lines > {local:g} x local mean) + cornerSubPix")
        why = "cells two-coloured, but not into the board's full grid"
    return None, why


def _quads(grey: np.ndarray, pattern: tuple[int, int], scale: int) -> np.ndarray | None:
    """The quad detector on ``grey`` upscaled ``scale`` times (cubic), refined by cornerSubPix
    there; corners in ``grey``'s pixels, or None."""
    img = grey if scale == 1 else cv2.resize(grey, None, fx=scale, fy=scale, interpolation=cv2.INTER_CUBIC)
    ok, corners = cv2.findChessboardCorners(img, pattern, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not ok:
        return None
    corners = corners.reshape(-1, 2).astype(np.float32)
    win = _subpix_window(corners, pattern)
    corners = cv2.cornerSubPix(img, corners.reshape(-1, 1, 2), (win, win), (-1, -1),
                               (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 40, 0.01)).reshape(-1, 2)
    return _to_original(corners, scale)


#: upscaling tried on a bright region (a board a few pixels a square needs 3-4x for the quad detector)
REGION_SCALES = (3, 4, 2)


def bright_regions(grey: np.ndarray, count: int = 3, min_share: float = 0.002) -> list[tuple[int, int, np.ndarray]]:
    """``(x0, y0, crop)`` of the ``count`` largest bright blobs of ``grey`` (Otsu threshold of
    the image blurred by 2 px, closed by 5 px), each cropped with a margin of 20 % of its size
    (at least 6 px); blobs under ``min_share`` of the image are skipped."""
    blurred = cv2.GaussianBlur(grey, (0, 0), 2.0)
    _, mask = cv2.threshold(blurred, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))
    n, _, stats, _ = cv2.connectedComponentsWithStats(mask)
    H, W = grey.shape
    out = []
    for i in np.argsort(-stats[1:, cv2.CC_STAT_AREA])[:count] + 1:
        x, y, w, h, area = (int(v) for v in stats[i])
        if area < min_share * H * W:
            continue
        m = max(6, int(0.2 * max(w, h)))
        x0, y0, x1, y1 = max(0, x - m), max(0, y - m), min(W, x + w + m), min(H, y + h + m)
        out.append((x0, y0, grey[y0:y1, x0:x1]))
    return out


def _subpix_window(corners: np.ndarray, pattern: tuple[int, int]) -> int:
    """Half-window for cornerSubPix: 40 % of the smallest square side seen, 2..11 px."""
    grid = corners.reshape(pattern[1], pattern[0], 2)
    step = min(np.linalg.norm(np.diff(grid, axis=1), axis=2).min(), np.linalg.norm(np.diff(grid, axis=0), axis=2).min())
    return int(np.clip(0.4 * step, 2, 11))


def _to_original(corners: np.ndarray, scale: int) -> np.ndarray:
    """Pixel coordinates of an image upscaled ``scale`` x (cv2.resize centres) back to the original."""
    return (np.asarray(corners, dtype=np.float64) + 0.5) / scale - 0.5


def board_pose(corners: np.ndarray, board: Board, camera: CameraModel) -> tuple[Extrinsic, float]:
    """``T_cam_board`` from detected corners and the RMS reprojection error in pixels."""
    obj = board.corners()
    xy = undistort_normalised(corners, camera)
    ok, rvec, tvec = cv2.solvePnP(obj, xy.reshape(-1, 1, 2), np.eye(3), None, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        raise ValueError("solvePnP failed")
    rvec, tvec = cv2.solvePnPRefineLM(obj, xy.reshape(-1, 1, 2), np.eye(3), None, rvec, tvec)
    pose = Extrinsic(rvec.ravel(), tvec.ravel())
    uv, _ = project_points(pose.transform(obj), camera)
    return pose, float(np.sqrt(np.mean(np.sum((uv - corners) ** 2, axis=1))))


def detect_board(image: np.ndarray, board: Board, camera: CameraModel, name: str = "") -> Detection:
    """Corners, pose and reprojection error of the board in one image (see the module docstring)."""
    if image.shape[:2] != (camera.height, camera.width):
        return Detection(name, False, f"image is {image.shape[1]}x{image.shape[0]}, the camera {camera.width}x{camera.height}")
    corners, how = find_corners(image, board)
    if corners is None:
        return Detection(name, False, how)
    try:
        pose, rep = board_pose(corners, board, camera)
    except (ValueError, cv2.error) as exc:
        return Detection(name, False, f"corners found ({how}) but no board pose ({exc})", corners, method=how)
    limit = MAX_REPROJECTION_PX * max(1.0, camera.width / 1280.0)
    if not np.isfinite(rep) or rep > limit or pose.translation[2] <= 0:
        return Detection(name, False, f"corners found ({how}) but they reproject {rep:.2f} px off the board "
                                      f"(limit {limit:.1f} px): not a flat grid of this board", corners, method=how)
    return Detection(name, True, "", corners, pose, rep, how)


def detection_cache_key(image_bytes: bytes, board: Board, camera: CameraModel) -> str:
    """The cache key of one detection: image content, board and camera (and the detector version)."""
    h = hashlib.sha1(image_bytes)
    h.update(json.dumps([DETECTOR_VERSION, board.to_dict(), camera.model, camera.width, camera.height,
                         np.round(camera.K, 9).tolist(), np.round(camera.D, 12).tolist()]).encode())
    return h.hexdigest()[:24]


def detect_cached(image: np.ndarray, board: Board, camera: CameraModel, name: str = "",
                  use_cache: bool = True) -> Detection:
    """:func:`detect_board`, its answer cached under the key of :func:`detection_cache_key`."""
    if not use_cache:
        return detect_board(image, board, camera, name)
    arr = np.ascontiguousarray(image)
    key = detection_cache_key(arr.tobytes() + str(arr.shape).encode() + str(arr.dtype).encode(), board, camera)
    path = user_cache_dir("target") / f"{key}.json"
    if path.is_file():
        try:
            cached = Detection.from_dict(json.loads(path.read_text()))
            return Detection(name, cached.found, cached.reason, cached.corners, cached.pose,
                             cached.reprojection_px, cached.method)
        except (OSError, ValueError, KeyError, TypeError):
            pass  # a damaged entry is rebuilt
    det = detect_board(image, board, camera, name)
    try:
        atomic_write_bytes(path, json.dumps(det.to_dict()).encode())
    except OSError:
        pass  # best effort: an unwritable cache only costs time
    return det
