"""An initial guess from clicked correspondences: lidar points (picked in the 3D view) paired
with pixels (clicked on the map), solved with OpenCV's PnP (pure numpy / OpenCV, no viser).

With at least four pairs, :func:`solve_pnp` gives ``T_cam_lidar`` directly (PnP solves for
the pose of the points' frame in the camera frame), and :func:`reprojection_errors` each
pair's error in pixels at any extrinsic.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..camera import CameraModel
from ..geometry import Extrinsic, project_points

MIN_PAIRS = 4


@dataclass(frozen=True)
class Pair:
    """One correspondence: a lidar-frame point (m) and a map pixel (x right, y down)."""

    point: tuple[float, float, float]
    pixel: tuple[float, float]


def nearest_point_to_ray(points: np.ndarray, origin, direction, max_angle_deg: float = 1.0) -> int | None:
    """Index of the point closest in angle to the ray (in front of it, within ``max_angle_deg``)."""
    pts = np.asarray(points, dtype=np.float64)
    o = np.asarray(origin, dtype=np.float64)
    d = np.asarray(direction, dtype=np.float64)
    d = d / max(np.linalg.norm(d), 1e-12)
    rel = pts - o
    along = rel @ d
    dist = np.linalg.norm(rel, axis=1)
    ok = along > 0
    if not ok.any():
        return None
    cos = np.where(ok, along / np.maximum(dist, 1e-12), -1.0)
    best = int(np.argmax(cos))
    angle = np.degrees(np.arccos(np.clip(cos[best], -1.0, 1.0)))
    return best if angle <= max_angle_deg else None


def reprojection_errors(extrinsic: Extrinsic, pairs: list[Pair], camera: CameraModel) -> np.ndarray:
    """Pixel distance between each clicked pixel and its lidar point projected at ``extrinsic``."""
    if not pairs:
        return np.zeros(0)
    pts = np.array([p.point for p in pairs], dtype=np.float64)
    px = np.array([p.pixel for p in pairs], dtype=np.float64)
    uv, in_front = project_points(extrinsic.transform(pts), camera)
    err = np.linalg.norm(uv - px, axis=1)
    return np.where(in_front, err, np.inf)


def solve_pnp(pairs: list[Pair], camera: CameraModel, guess: Extrinsic | None = None) -> Extrinsic:
    """``T_cam_lidar`` from >= 4 pairs (SQPnP, refined by Levenberg-Marquardt)."""
    if len(pairs) < MIN_PAIRS:
        raise ValueError(f"PnP needs at least {MIN_PAIRS} pairs, got {len(pairs)}")
    obj = np.array([p.point for p in pairs], dtype=np.float64).reshape(-1, 1, 3)
    img = np.array([p.pixel for p in pairs], dtype=np.float64).reshape(-1, 1, 2)
    K, D = np.asarray(camera.K, np.float64), np.asarray(camera.D, np.float64)
    if camera.model == "equidistant" and D.size:
        img = cv2.fisheye.undistortPoints(img, K, D, P=K)
        D = np.zeros(0)
    ok, rvec, tvec = cv2.solvePnP(obj, img, K, D if D.size else None, flags=cv2.SOLVEPNP_SQPNP)
    if not ok:
        raise ValueError("PnP found no pose for these pairs (are the points spread out, not on a line?)")
    rvec, tvec = cv2.solvePnPRefineLM(obj, img, K, D if D.size else None, rvec, tvec)
    return Extrinsic(rvec.reshape(3), tvec.reshape(3))
