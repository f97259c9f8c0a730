"""The six seed sliders <-> an extrinsic.

``x, y, z`` are the translation of ``T_cam_lidar`` itself (metres, camera frame), so they read
like the numbers in a result file. ``roll, pitch, yaw`` are a *correction* to the reference
(file seed) rotation, in degrees, about the camera's body axes in the ROS convention
(x forward, y left, z up): yaw pans the image left/right, pitch tilts it up/down, roll turns
it about the optical axis. Absolute Euler angles of ``T_cam_lidar`` are no good for sliders:
the usual lidar (x forward) to optical camera (z forward) rotation sits exactly at the
pitch = -90 deg gimbal lock, where roll and yaw do the same thing.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from ..geometry import LIDAR_TO_CAMERA_AXES, Extrinsic, euler_xyz

SLIDER_NAMES = ("x", "y", "z", "roll", "pitch", "yaw")


def extrinsic_from_sliders(values: np.ndarray, reference: Extrinsic) -> Extrinsic:
    """Slider values (x, y, z [m], roll, pitch, yaw [deg]) -> ``T_cam_lidar``."""
    v = np.asarray(values, dtype=np.float64).reshape(6)
    delta_body = Rotation.from_euler("xyz", v[3:], degrees=True).as_rotvec()
    delta_optical = LIDAR_TO_CAMERA_AXES @ delta_body
    rotated = reference.perturbed(np.zeros(3), delta_optical)
    return Extrinsic(rotated.rotvec, v[:3])


def sliders_from_extrinsic(
    extrinsic: Extrinsic, reference: Extrinsic, near: np.ndarray | None = None
) -> np.ndarray:
    """``T_cam_lidar`` -> slider values; the inverse of :func:`extrinsic_from_sliders`.

    Euler angles are not unique; with ``near`` (the sliders' current values) the equivalent
    triple closest to it is returned so the sliders do not jump by 360 deg.
    """
    _, d_optical = reference.delta_to(extrinsic)
    d_body = LIDAR_TO_CAMERA_AXES.T @ d_optical
    rot = Rotation.from_rotvec(d_body)
    a = euler_xyz(rot, degrees=True)
    if near is not None:
        near_rpy = np.asarray(near, dtype=np.float64).reshape(6)[3:]
        b = np.array([a[0] + 180.0, 180.0 - a[1], a[2] + 180.0])  # the same rotation
        candidates = [_wrap_near(c, near_rpy) for c in (a, b)]
        a = min(candidates, key=lambda c: float(np.sum((c - near_rpy) ** 2)))
    return np.concatenate([extrinsic.translation, a])


def _wrap_near(angles: np.ndarray, near: np.ndarray) -> np.ndarray:
    """Add multiples of 360 deg so each angle is within 180 deg of ``near``."""
    return near + (angles - near + 180.0) % 360.0 - 180.0


def describe(extrinsic: Extrinsic, reference: Extrinsic) -> str:
    """One line in the sliders' terms: translation, and the rotation correction to ``reference``."""
    v = sliders_from_extrinsic(extrinsic, reference)
    return (
        f"x, y, z = ({v[0]:.4f}, {v[1]:.4f}, {v[2]:.4f}) m · "
        f"roll, pitch, yaw = ({v[3]:+.3f}, {v[4]:+.3f}, {v[5]:+.3f})° vs file seed"
    )
