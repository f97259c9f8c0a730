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


#: px: how precisely a careful click lands (on the map and in the 3D view) -- the noise the
#: pose's uncertainty below is scaled to.
CLICK_SIGMA_PX = 1.0


@dataclass(frozen=True)
class PairSpread:
    """How well a set of pairs pins the pose solved from them.

    ``translation_std``: 1-sigma uncertainty (m) of the translation along the camera's x (right),
    y (down), z (forward) axes for clicks ``CLICK_SIGMA_PX`` off (inf where the pairs leave a
    direction free); ``depth``: nearest and farthest pair along the optical axis (m);
    ``coverage``: the share of the image's width and height the clicked pixels span.
    """

    translation_std: np.ndarray
    depth: tuple[float, float]
    coverage: tuple[float, float]


def pair_spread(extrinsic: Extrinsic, pairs: list[Pair], camera: CameraModel,
                click_sigma_px: float = CLICK_SIGMA_PX) -> PairSpread:
    """The pose's uncertainty from the pairs' geometry: the Gauss-Newton covariance
    ``sigma^2 (J^T J)^-1`` of the six pose parameters, with ``J`` the Jacobian of the pairs'
    projections (central differences) at ``extrinsic``. Far-only, clustered or nearly
    collinear pairs show up as a large (or infinite) translation uncertainty."""
    pts = np.array([p.point for p in pairs], dtype=np.float64).reshape(-1, 3)
    px = np.array([p.pixel for p in pairs], dtype=np.float64).reshape(-1, 2)
    p0 = np.concatenate([extrinsic.rotvec, extrinsic.translation])

    def project(p: np.ndarray) -> np.ndarray:
        uv, _ = project_points(Extrinsic(p[:3], p[3:]).transform(pts), camera)
        return uv.ravel()

    J = np.empty((2 * len(pts), 6))
    for k, h in enumerate((1e-6,) * 3 + (1e-5,) * 3):
        d = np.zeros(6)
        d[k] = h
        J[:, k] = (project(p0 + d) - project(p0 - d)) / (2 * h)
    JtJ = J.T @ J
    if len(pts) < 3 or not np.all(np.isfinite(JtJ)) or np.linalg.cond(JtJ) > 1e14:
        std = np.full(3, np.inf)
    else:
        std = click_sigma_px * np.sqrt(np.clip(np.diag(np.linalg.inv(JtJ))[3:], 0.0, None))
    z = extrinsic.transform(pts)[:, 2] if len(pts) else np.zeros(1)
    span = (np.ptp(px[:, 0]) / camera.width, np.ptp(px[:, 1]) / camera.height) if len(px) else (0.0, 0.0)
    return PairSpread(std, (float(z.min()), float(z.max())), (float(span[0]), float(span[1])))


def translation_warning(spread: PairSpread, limit_m: float) -> str:
    """A sentence saying which translation direction the pairs leave loose and what to add, or
    "" when every axis is pinned within ``limit_m`` (1 sigma)."""
    std = spread.translation_std
    worst = int(np.argmax(std))
    if std[worst] <= limit_m:
        return ""
    axis = ("sideways (x)", "up/down (y)", "along the optical axis (z)")[worst]
    size = "unconstrained" if not np.isfinite(std[worst]) else f"uncertain by ±{100 * std[worst]:.0f} cm (1σ)"
    near, far = spread.depth
    advice = []
    if worst == 2 or near > 10.0:
        advice.append(f"pairs close to the camera (the nearest is {near:.1f} m away)")
    if far < 1.5 * near:
        advice.append(f"pairs at other distances (all lie {near:.1f}-{far:.1f} m away)")
    if min(spread.coverage) < 0.5:
        advice.append(f"pairs spread over the image (these span {spread.coverage[0]:.0%} of its width, "
                      f"{spread.coverage[1]:.0%} of its height)")
    if not advice:
        advice.append("more pairs, near and far, over the whole image")
    return (f"These pairs leave the translation {size} {axis}, more than ±{100 * limit_m:.0f} cm: add "
            + "; ".join(advice) + ".")
