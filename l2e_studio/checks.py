"""Checks that an input can inform a calibration at all, before the optimiser is asked to."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from .camera import CameraModel
from .errors import InputError
from .geometry import Extrinsic, in_image, project_points

#: Fewer lidar points than this in the image at the seed (all scenes together) leave the MI
#: nothing to measure: the seed is far off, or it maps the cloud behind the camera.
MIN_POINTS_IN_IMAGE = 50


def seed_coverage(points: Sequence[np.ndarray], camera: CameraModel, seed: Extrinsic) -> tuple[int, int, int]:
    """``(in_image, in_front, total)`` lidar points of all scans at ``seed``."""
    inside = front = total = 0
    for pts in points:
        uv, ahead = project_points(seed.transform(pts), camera)
        inside += int(np.count_nonzero(ahead & in_image(uv, camera)))
        front += int(np.count_nonzero(ahead))
        total += len(pts)
    return inside, front, total


def check_seed_coverage(points: Sequence[np.ndarray], camera: CameraModel, seed: Extrinsic,
                        source: str | Path | None) -> int:
    """Raise :class:`InputError` naming ``source`` when almost no point lands in the image at the
    seed; returns how many do."""
    inside, front, total = seed_coverage(points, camera, seed)
    if inside >= MIN_POINTS_IN_IMAGE:
        return inside
    if front < total / 2:
        why = (f"{total - front} of {total} lidar points are behind the camera: the seed maps the cloud the wrong way "
               "(is it T_lidar_cam instead of T_cam_lidar, or a lidar-frame rotation?)")
    else:
        why = f"only {inside} of {total} lidar points land in the {camera.width}x{camera.height} image: the seed is far off"
    raise InputError(source, f"at the seed extrinsic {why}")
