"""Rigid transforms and camera projection.

An :class:`Extrinsic` is ``T_cam_lidar``: it maps a point from the lidar frame into the camera
frame, ``X_cam = R @ X_lidar + t``. The paper's parameter vector Theta is
``(x, y, z, v1, v2, v3)``: the translation and the axis-angle rotation vector (norm = angle, rad).
Roll/pitch/yaw are the ROS convention: ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (scipy ``"xyz"``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from .camera import CameraModel

#: Rotation from a lidar/vehicle frame (x forward, y left, z up) to a camera's optical frame
#: (x right, y down, z forward): the rotation part of an ideally mounted, forward-looking rig.
LIDAR_TO_CAMERA_AXES = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])

#: cos(pitch) under which roll/pitch/yaw are at gimbal lock (scipy's own test is 1e-7 on the angle)
GIMBAL_LOCK_COS = 1e-6


def euler_xyz(rotation: Rotation, degrees: bool = False) -> np.ndarray:
    """Roll, pitch, yaw with ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``, also at gimbal lock.

    At pitch = +-90 deg (every lidar-to-optical-camera rotation of a forward-looking rig) roll and
    yaw turn about the same axis; scipy then sets yaw to 0 and warns at the user's terminal. This
    does the same decomposition without the warning: yaw = 0 and the roll that, with that pitch,
    gives the rotation (exact at the lock, within ``GIMBAL_LOCK_COS`` rad beside it).
    """
    R = rotation.as_matrix()
    if np.hypot(R[0, 0], R[1, 0]) >= GIMBAL_LOCK_COS:
        return rotation.as_euler("xyz", degrees=degrees)
    pitch = float(np.arcsin(np.clip(-R[2, 0], -1.0, 1.0)))
    M = Rotation.from_euler("y", pitch).as_matrix().T @ R  # = Rx(roll) with yaw = 0
    angles = np.array([np.arctan2(M[2, 1], M[1, 1]), pitch, 0.0])
    return np.degrees(angles) if degrees else angles


@dataclass(frozen=True)
class Extrinsic:
    """``T_cam_lidar`` as a rotation vector (rad) and a translation (m)."""

    rotvec: np.ndarray = field(default_factory=lambda: np.zeros(3))
    translation: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        r = np.asarray(self.rotvec, dtype=np.float64).reshape(3)
        t = np.asarray(self.translation, dtype=np.float64).reshape(3)
        if not (np.all(np.isfinite(r)) and np.all(np.isfinite(t))):
            raise ValueError("extrinsic must be finite")
        object.__setattr__(self, "rotvec", r)
        object.__setattr__(self, "translation", t)

    # --- constructors -------------------------------------------------------------------
    @classmethod
    def from_params(cls, theta: np.ndarray) -> "Extrinsic":
        """From the paper's Theta = (x, y, z, v1, v2, v3)."""
        theta = np.asarray(theta, dtype=np.float64).reshape(6)
        return cls(theta[3:], theta[:3])

    @classmethod
    def from_matrix(cls, T: np.ndarray) -> "Extrinsic":
        """From a 4x4 (or 3x4) homogeneous matrix; the rotation block is re-orthonormalised."""
        T = np.asarray(T, dtype=np.float64)
        if T.shape not in ((4, 4), (3, 4)):
            raise ValueError(f"expected a 4x4 or 3x4 matrix, got shape {T.shape}")
        R = T[:3, :3]
        if not np.all(np.isfinite(T)):
            raise ValueError("matrix must be finite")
        if abs(np.linalg.det(R) - 1.0) > 1e-3:
            raise ValueError(f"rotation block has determinant {np.linalg.det(R):.4f}, expected 1")
        return cls(Rotation.from_matrix(R).as_rotvec(), T[:3, 3])

    @classmethod
    def from_quaternion(cls, xyzw: np.ndarray, translation: np.ndarray) -> "Extrinsic":
        return cls(Rotation.from_quat(np.asarray(xyzw, dtype=np.float64)).as_rotvec(), translation)

    @classmethod
    def from_rpy(cls, rpy: np.ndarray, translation: np.ndarray, degrees: bool = True) -> "Extrinsic":
        """From roll, pitch, yaw (ROS convention, see module docstring)."""
        return cls(Rotation.from_euler("xyz", rpy, degrees=degrees).as_rotvec(), translation)

    # --- views ---------------------------------------------------------------------------
    @property
    def params(self) -> np.ndarray:
        """Theta = (x, y, z, v1, v2, v3)."""
        return np.concatenate([self.translation, self.rotvec])

    @property
    def R(self) -> np.ndarray:
        return Rotation.from_rotvec(self.rotvec).as_matrix()

    @property
    def matrix(self) -> np.ndarray:
        """The 4x4 homogeneous ``T_cam_lidar``."""
        T = np.eye(4)
        T[:3, :3] = self.R
        T[:3, 3] = self.translation
        return T

    @property
    def quaternion_xyzw(self) -> np.ndarray:
        q = Rotation.from_rotvec(self.rotvec).as_quat()
        return q if q[3] >= 0 else -q

    def rpy(self, degrees: bool = True) -> np.ndarray:
        """Roll, pitch, yaw (ROS convention; at gimbal lock yaw = 0, see :func:`euler_xyz`)."""
        return euler_xyz(Rotation.from_rotvec(self.rotvec), degrees)

    def inverse(self) -> "Extrinsic":
        """``T_lidar_cam``."""
        Rinv = Rotation.from_rotvec(self.rotvec).inv()
        return Extrinsic(Rinv.as_rotvec(), -Rinv.apply(self.translation))

    def compose(self, other: "Extrinsic") -> "Extrinsic":
        """``self @ other`` as transforms (apply ``other`` first)."""
        return Extrinsic.from_matrix(self.matrix @ other.matrix)

    def perturbed(self, delta_translation: np.ndarray, delta_rotvec: np.ndarray) -> "Extrinsic":
        """Apply a small correction: ``R' = exp(delta_rotvec) R``, ``t' = t + delta_translation``.

        This is the local parametrisation the optimiser searches over; both deltas are expressed
        in the camera frame, so bounds on them read as "so many cm / deg of camera motion".
        """
        R = Rotation.from_rotvec(delta_rotvec) * Rotation.from_rotvec(self.rotvec)
        return Extrinsic(R.as_rotvec(), self.translation + np.asarray(delta_translation, float))

    def delta_to(self, other: "Extrinsic") -> tuple[np.ndarray, np.ndarray]:
        """The (delta_translation, delta_rotvec) with ``self.perturbed(*d) == other``."""
        dR = Rotation.from_rotvec(other.rotvec) * Rotation.from_rotvec(self.rotvec).inv()
        return other.translation - self.translation, dR.as_rotvec()

    def error_to(self, other: "Extrinsic") -> tuple[float, float]:
        """(rotation error in degrees, translation error in metres) between two extrinsics."""
        dt, dr = self.delta_to(other)
        return float(np.degrees(np.linalg.norm(dr))), float(np.linalg.norm(dt))

    def transform(self, points: np.ndarray) -> np.ndarray:
        """Map (N, 3) lidar points into the camera frame (keeps float32 inputs float32).

        Written out per coordinate: every operation is one correctly rounded numpy pass, so the
        result is the same to the bit in any process. numpy's ``(N, 3) @ (3, 3)`` went through
        BLAS, whose threads took 14-28 ms for 75k points on a loaded 2-core host (this: ~1.5 ms);
        OpenCV's ``transform`` is faster still but its float32 result depends on where the
        array sits in memory (a last-bit difference that moved optimiser runs apart)."""
        P = np.asarray(points)
        dtype = P.dtype if P.dtype in (np.float32, np.float64) else np.float64
        R, t = self.R.astype(dtype), self.translation.astype(dtype)
        if P.ndim != 2 or P.shape[1] != 3:
            return P @ R.T + t
        P = P.astype(dtype, copy=False)
        x, y, z = P[:, 0], P[:, 1], P[:, 2]
        out = np.empty(P.shape, dtype)
        for i in range(3):
            o = out[:, i]
            np.multiply(x, R[i, 0], out=o)
            o += R[i, 1] * y
            o += R[i, 2] * z
            o += t[i]
        return out


def left_jacobian(rotvec: np.ndarray) -> np.ndarray:
    """Left Jacobian of SO(3): ``exp(w + dw) ~= exp(J(w) dw) exp(w)``."""
    w = np.asarray(rotvec, dtype=np.float64)
    theta = float(np.linalg.norm(w))
    W = skew(w)
    if theta < 1e-8:
        return np.eye(3) + 0.5 * W
    return (
        np.eye(3)
        + (1.0 - np.cos(theta)) / theta**2 * W
        + (theta - np.sin(theta)) / theta**3 * (W @ W)
    )


def skew(w: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


# --- projection --------------------------------------------------------------------------------


def distort(x: np.ndarray, y: np.ndarray, camera: CameraModel, jacobian: bool = False):
    """Apply lens distortion to normalised image coordinates ``(x, y) = (X/Z, Y/Z)``.

    Returns ``(xd, yd, J)`` where J, with ``jacobian``, is the 2x2 Jacobian
    ``d(xd, yd)/d(x, y)`` as four arrays ``(dxd/dx, dxd/dy, dyd/dx, dyd/dy)``, else None.
    """
    D = camera.D
    if not camera.is_distorted:
        if not jacobian:
            return x, y, None
        one = np.ones_like(x)
        zero = np.zeros_like(x)
        return x, y, (one, zero, zero, one)
    # far outside the lens's field of view the polynomial overflows: such points come out
    # non-finite, and in_image() rejects them
    with np.errstate(over="ignore", invalid="ignore"):
        if camera.model == "equidistant":
            return _distort_equidistant(x, y, D.astype(x.dtype), jacobian)
        return _distort_radtan(x, y, D.astype(x.dtype), jacobian)


def undistort_normalised(uv: np.ndarray, camera: CameraModel, iterations: int = 30) -> np.ndarray:
    """(N, 2) pixels -> normalised undistorted coordinates (X/Z, Y/Z): Newton's method on the
    project's own lens model (:func:`distort`, radtan or equidistant), so a board pose or a
    pixel's ray comes from exactly the model the lidar points are projected with."""
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    K = camera.K
    yd = (uv[:, 1] - K[1, 2]) / K[1, 1]
    xd = (uv[:, 0] - K[0, 2] - K[0, 1] * yd) / K[0, 0]
    x, y = xd.copy(), yd.copy()
    for _ in range(iterations):
        fx, fy, (a, b, c, d) = distort(x, y, camera, jacobian=True)
        ex, ey = fx - xd, fy - yd
        det = a * d - b * c
        det = np.where(np.abs(det) < 1e-12, 1e-12, det)
        dx, dy = (d * ex - b * ey) / det, (a * ey - c * ex) / det
        x, y = x - dx, y - dy
        if np.max(np.abs(dx) + np.abs(dy)) < 1e-12:
            break
    return np.column_stack([x, y])


def project_points(points_cam: np.ndarray, camera: CameraModel) -> tuple[np.ndarray, np.ndarray]:
    """Project camera-frame points to pixels.

    Returns ``(uv, in_front)``: (N, 2) pixel coordinates (x right, y down; pixel centres at
    integers, as OpenCV) and a mask of points with positive depth within the lens's field of
    view. Points behind the camera, or so far off axis that the lens model folds back
    (:attr:`CameraModel.max_r2`), get NaN pixel coordinates.
    """
    uv, in_front, _ = project_with_jacobian(points_cam, camera, jacobian=False)
    return uv, in_front


def in_image(uv: np.ndarray, camera: CameraModel, margin: float = 0.0) -> np.ndarray:
    """Mask of pixel coordinates inside the image (``margin`` pixels inside the border)."""
    u, v = uv[:, 0], uv[:, 1]
    with np.errstate(invalid="ignore"):
        return (
            (u >= -0.5 + margin)
            & (u <= camera.width - 0.5 - margin)
            & (v >= -0.5 + margin)
            & (v <= camera.height - 0.5 - margin)
        )


def project_with_jacobian(
    points_cam: np.ndarray, camera: CameraModel, jacobian: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Project camera-frame points and, optionally, return d(u, v)/d(X, Y, Z).

    The Jacobian has shape (N, 2, 3). It is what the MI gradient chains through.
    """
    P = np.asarray(points_cam)
    X, Y, Z = P[:, 0], P[:, 1], P[:, 2]
    in_front = Z > 1e-6
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_z = np.reciprocal(Z, dtype=P.dtype)
    inv_z[~in_front] = np.nan
    x = X * inv_z
    y = Y * inv_z
    if np.isfinite(camera.max_r2):  # past the fold the polynomial puts unseen points in the image
        with np.errstate(invalid="ignore"):
            beyond = x * x + y * y > camera.max_r2
        in_front &= ~beyond
        inv_z[beyond] = np.nan
        x[beyond] = np.nan
        y[beyond] = np.nan
    xd, yd, Jd = distort(x, y, camera, jacobian)
    K = camera.K.astype(P.dtype)
    fx, fy, s, cx, cy = K[0, 0], K[1, 1], K[0, 1], K[0, 2], K[1, 2]
    uv = np.empty((P.shape[0], 2), dtype=P.dtype)
    with np.errstate(over="ignore", invalid="ignore"):
        np.multiply(xd, fx, out=uv[:, 0])
        if s != 0:
            uv[:, 0] += s * yd
        uv[:, 0] += cx
        np.multiply(yd, fy, out=uv[:, 1])
        uv[:, 1] += cy
    if not jacobian:
        return uv, in_front, None
    # d(xd, yd)/d(x, y) from Jd, then d(x, y)/d(X, Y, Z) = [[1/Z, 0, -x/Z], [0, 1/Z, -y/Z]].
    dxd_dx, dxd_dy, dyd_dx, dyd_dy = Jd
    du_dx = fx * dxd_dx + s * dyd_dx
    du_dy = fx * dxd_dy + s * dyd_dy
    dv_dx = fy * dyd_dx
    dv_dy = fy * dyd_dy
    J = np.empty((P.shape[0], 2, 3), dtype=P.dtype)
    J[:, 0, 0] = du_dx * inv_z
    J[:, 0, 1] = du_dy * inv_z
    J[:, 0, 2] = -(du_dx * x + du_dy * y) * inv_z
    J[:, 1, 0] = dv_dx * inv_z
    J[:, 1, 1] = dv_dy * inv_z
    J[:, 1, 2] = -(dv_dx * x + dv_dy * y) * inv_z
    return uv, in_front, J


def _distort_radtan(x, y, D, jacobian):
    d = np.zeros(8, dtype=D.dtype)
    d[: D.size] = D
    k1, k2, p1, p2, k3, k4, k5, k6 = d
    r2 = x * x
    r2 += y * y
    a = r2 * k3  # a = 1 + k1 r2 + k2 r2^2 + k3 r2^3, evaluated in place (hot path)
    a += k2
    a *= r2
    a += k1
    a *= r2
    a += 1
    rational = bool(k4 or k5 or k6)
    b = 1 + r2 * (k4 + r2 * (k5 + r2 * k6)) if rational else 1.0
    radial = a / b if rational else a
    xy = x * y
    xd = x * radial
    yd = y * radial
    if p1 or p2:
        xd += 2 * p1 * xy + p2 * (r2 + 2 * x * x)
        yd += p1 * (r2 + 2 * y * y) + 2 * p2 * xy
    if not jacobian:
        return xd, yd, None
    da = k1 + r2 * (2 * k2 + r2 * 3 * k3)
    if rational:
        db = k4 + r2 * (2 * k5 + r2 * 3 * k6)
        drad = (da * b - a * db) / (b * b)
    else:
        drad = da
    dxd_dx = radial + 2 * x * x * drad + 2 * p1 * y + 6 * p2 * x
    dxd_dy = 2 * xy * drad + 2 * p1 * x + 2 * p2 * y
    dyd_dx = 2 * xy * drad + 2 * p1 * x + 2 * p2 * y
    dyd_dy = radial + 2 * y * y * drad + 6 * p1 * y + 2 * p2 * x
    return xd, yd, (dxd_dx, dxd_dy, dyd_dx, dyd_dy)


def _distort_equidistant(x, y, D, jacobian):
    k1, k2, k3, k4 = D
    r = np.sqrt(x * x + y * y)
    th = np.arctan(r)
    th2 = th * th
    thd = th * (1 + th2 * (k1 + th2 * (k2 + th2 * (k3 + th2 * k4))))
    small = r < 1e-8
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(small, 1.0, thd / np.where(small, 1.0, r)).astype(x.dtype, copy=False)
    xd = x * scale
    yd = y * scale
    if not jacobian:
        return xd, yd, None
    dthd_dth = 1 + th2 * (3 * k1 + th2 * (5 * k2 + th2 * (7 * k3 + th2 * 9 * k4)))
    dth_dr = 1.0 / (1.0 + r * r)
    with np.errstate(divide="ignore", invalid="ignore"):
        rs = np.where(small, 1.0, r)
        # d(scale)/dr divided by r, so that d(scale)/dx = x * ds_r
        ds_r = np.where(small, 0.0, (dthd_dth * dth_dr * rs - thd) / (rs * rs * rs)).astype(x.dtype, copy=False)
    dxd_dx = scale + x * x * ds_r
    dxd_dy = x * y * ds_r
    dyd_dy = scale + y * y * ds_r
    return xd, yd, (dxd_dx, dxd_dy, dxd_dy, dyd_dy)
