"""The room a checkerboard is held up in, the board's poses, and the 16-beam lidar that sees it.

World = lidar frame (x forward, y left, z up; the lidar at the origin). A room (floor below the
lidar, a wall behind the board, side walls and a ceiling), the board (a thin box whose front face
is the board plane) and, behind it, a person holding it (body, head, two arms reaching to the
board's sides) or a stand (a pole under the board). The lidar is VLP-16-like: 16 rings 2 deg
apart from -15 to +15 deg, 0.2 deg azimuth steps over 360 deg, Gaussian range noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ..camera import CameraModel
from ..geometry import Extrinsic, in_image, project_points
from .board import Board
from .lidars import LidarModel, ring_directions
from .world import Box, cast, random_waves, surface


@dataclass
class BoardScene:
    """One synthetic board scene: the world boxes, the board's box index and its true pose."""

    boxes: list[Box]
    board_index: int
    pose_cam: Extrinsic  # T_cam_board
    pose_lidar: Extrinsic  # T_lidar_board
    holder: str  # "person" | "stand"


def board_pose(rng: np.random.Generator, index: int, n: int, distance_m: tuple[float, float],
               camera: CameraModel) -> Extrinsic:
    """A T_cam_board for scene ``index`` of ``n``: distances spread over ``distance_m``, the
    tilt direction turning by the golden angle from scene to scene (so normals fan out around
    the view axis and every axis is pinned), tilts 12-38 deg, in-plane rolls up to 30 deg."""
    lo, hi = distance_m
    d = lo + (hi - lo) * ((index + rng.uniform(0.2, 0.8)) / n)
    half_h = np.arctan2(camera.width / 2, camera.K[0, 0]) * 0.45
    half_v = np.arctan2(camera.height / 2, camera.K[1, 1]) * 0.35
    az, el = rng.uniform(-half_h, half_h), rng.uniform(-half_v, half_v)
    centre = d * np.array([np.tan(az), np.tan(el), 1.0]) / np.linalg.norm([np.tan(az), np.tan(el), 1.0])
    # facing the camera: z along the line of sight, x to the right, y down
    z = centre / np.linalg.norm(centre)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    R0 = np.column_stack([x, np.cross(z, x), z])
    phi = index * np.pi * (3 - np.sqrt(5)) + rng.uniform(-0.3, 0.3)
    tilt = np.radians(rng.uniform(12, 38))
    axis = np.array([np.cos(phi), np.sin(phi), 0.0])  # in the board plane
    roll = np.radians(rng.uniform(-30, 30))
    R = R0 @ Rotation.from_rotvec(axis * tilt).as_matrix() @ Rotation.from_rotvec([0, 0, roll]).as_matrix()
    return Extrinsic(Rotation.from_matrix(R).as_rotvec(), centre)


def board_in_view(board: Board, camera: CameraModel, pose: Extrinsic, margin_px: float = 12.0) -> bool:
    """Whether the whole board lies inside the image, ``margin_px`` from its border."""
    corners = pose.transform(board.outline())
    uv, front = project_points(corners, camera)
    return bool(front.all() and in_image(uv, camera, margin_px).all())


def make_board_scene(rng: np.random.Generator, board: Board, pose_cam: Extrinsic, truth: Extrinsic,
                     thickness_m: float = 0.01) -> BoardScene:
    """The room, the board at ``pose_cam`` (seen through ``truth`` = T_cam_lidar) and its holder."""
    pose_lidar = truth.inverse().compose(pose_cam)
    R, c = pose_lidar.R, pose_lidar.translation
    floor_z = -rng.uniform(0.9, 1.4)
    wall_x = max(c[0] + rng.uniform(1.5, 4.0), 5.0)
    side = max(rng.uniform(3.0, 6.0), abs(c[1]) + 1.5)
    top = floor_z + rng.uniform(2.6, 3.4)
    room = Box(((wall_x - 6.0) / 2, 0.0, (floor_z + top) / 2), np.eye(3),
               ((wall_x + 6.0) / 2, side, (top - floor_z) / 2), base=rng.uniform(0.3, 0.6), grain=0.08,
               inside=True, waves=random_waves(rng))
    board_box = Box(c + R[:, 2] * thickness_m / 2, R, (board.size_m[0] / 2, board.size_m[1] / 2, thickness_m / 2),
                    base=0.8)
    boxes = [room, board_box]
    # the holder stands behind the board, facing the rig
    back = R[:, 2]  # into the board, away from the rig
    behind = c + back * rng.uniform(0.25, 0.4)
    yaw = np.arctan2(-behind[1], -behind[0])
    Ry = Rotation.from_euler("z", yaw).as_matrix()
    holder = "person" if rng.random() < 0.6 else "stand"
    rho = rng.uniform(0.1, 0.4)
    if holder == "person":
        height = rng.uniform(1.6, 1.85)
        body_top = floor_z + height - 0.25
        boxes.append(Box((behind[0], behind[1], (floor_z + body_top) / 2), Ry, (0.13, 0.22, (body_top - floor_z) / 2),
                         base=rho))
        boxes.append(Box((behind[0], behind[1], body_top + 0.13), Ry, (0.1, 0.09, 0.12), base=rho * 0.8))
        for edge in (-1.0, 1.0):  # arms from the shoulders to the board's sides, just behind it
            grip = c + R[:, 0] * edge * (board.size_m[0] / 2 - 0.05) + back * 0.04
            shoulder = np.array([behind[0], behind[1], body_top - 0.05]) + Ry[:, 1] * edge * 0.2
            boxes.append(_rod(shoulder, grip, 0.04, rho))
    else:
        down = np.array([0.0, 0.0, -1.0]) - R[:, 2] * -R[2, 2]  # world down, within the board plane
        bottom = c + down / np.linalg.norm(down) * 0.4 * board.size_m[1]
        foot = np.array([behind[0], behind[1], floor_z])
        boxes.append(_rod(foot, bottom + back * 0.03, 0.025, rho))
        boxes.append(Box((foot[0], foot[1], floor_z + 0.02), Ry, (0.3, 0.3, 0.02), base=rho))
    return BoardScene(boxes, 1, pose_cam, pose_lidar, holder)


def _rod(a: np.ndarray, b: np.ndarray, radius: float, rho: float) -> Box:
    """A square rod from ``a`` to ``b``."""
    axis = b - a
    length = float(np.linalg.norm(axis))
    z = axis / length
    x = np.cross(z, [0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.cross(z, [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    return Box((a + b) / 2, np.column_stack([x, np.cross(z, x), z]), (radius, radius, length / 2), base=rho)


def lidar_scan(scene: BoardScene, board: Board, lidar: LidarModel, rng: np.random.Generator):
    """One revolution: points (N, 3) float32 (lidar frame), intensity (N,) float32 0..255,
    ring (N,) uint16, and a mask of the returns that hit the board's front face."""
    dirs, ring = ring_directions(lidar.elevations_deg, lidar.azimuth_step_deg, rng)
    origin = np.zeros(3)
    hits = cast(scene.boxes, origin, dirs, lidar.max_range_m)
    surf = surface(scene.boxes, origin, dirs, hits)
    on_board = hits.index == scene.board_index
    rho = np.minimum(surf.rho, 1.0)
    if on_board.any():
        local = (surf.points[on_board] - scene.pose_lidar.translation) @ scene.pose_lidar.R
        front = np.abs(local[:, 2]) < 1e-4
        albedo = board.albedo(local[:, 0], local[:, 1], 0.08, 0.8)
        rho[on_board] = np.where(np.isfinite(albedo), albedo, 0.8)
        idx = np.flatnonzero(on_board)
        on_board[idx[~front]] = False  # the board's rim is not its face
    cos_l = np.abs(np.einsum("ij,ij->i", surf.normals, dirs))
    intensity = np.clip(np.round(110.0 * rho * (0.4 + 0.6 * cos_l) + rng.normal(0, 2.0, rho.size)), 0, 255)
    ranges = hits.t + rng.normal(0, lidar.range_noise_m, hits.t.size)
    keep = (hits.index >= 0) & np.isfinite(hits.t) & (rng.random(hits.t.size) >= lidar.dropout)
    points = dirs * ranges[:, None]
    return (points[keep].astype(np.float32), intensity[keep].astype(np.float32), ring[keep], on_board[keep])


def background_radiance(scene: BoardScene, camera: CameraModel, rays: np.ndarray, truth: Extrinsic) -> np.ndarray:
    """(H, W) radiance 0..1 of everything but the board, seen from the camera (a lamp at the rig).
    Images wider than 640 px are cast at half resolution and upsampled (the room is smooth; the
    board, drawn over it by :func:`~l2e_studio.synth.board.render_board`, keeps full detail)."""
    import cv2

    h, w = rays.shape[:2]
    if w > 640:
        half = background_radiance(scene, camera, rays[1::2, 1::2], truth)
        return cv2.resize(half, (w, h), interpolation=cv2.INTER_LINEAR)
    cam = truth.inverse()
    dirs = rays.reshape(-1, 3) @ cam.R.T
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    others = [b for i, b in enumerate(scene.boxes) if i != scene.board_index]
    hits = cast(others, cam.translation, dirs)
    surf = surface(others, cam.translation, dirs, hits)
    lit = 0.35 + 0.65 * np.abs(np.einsum("ij,ij->i", surf.normals, dirs))
    value = np.where(hits.index >= 0, np.minimum(surf.rho, 1.0) * lit, 0.05)
    return value.reshape(h, w)
