"""Rotation representations and projection, checked against scipy and OpenCV."""

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from l2e_studio.camera import CameraModel
from l2e_studio.geometry import (LIDAR_TO_CAMERA_AXES, Extrinsic, euler_xyz, left_jacobian, project_points,
                                 project_with_jacobian)

K = np.array([[1045.0, 0.0, 641.3], [0.0, 1043.0, 359.2], [0.0, 0.0, 1.0]])
RNG = np.random.default_rng(7)


def random_extrinsics(n=25):
    for _ in range(n):
        yield Extrinsic(Rotation.random(random_state=RNG.integers(1 << 30)).as_rotvec(), RNG.normal(0, 0.5, 3))


@pytest.mark.parametrize("ext", list(random_extrinsics()))
def test_every_representation_round_trips(ext):
    T = ext.matrix
    assert np.allclose(Extrinsic.from_matrix(T).matrix, T, atol=1e-12)
    assert np.allclose(Extrinsic.from_params(ext.params).matrix, T, atol=1e-12)
    assert np.allclose(Extrinsic.from_quaternion(ext.quaternion_xyzw, ext.translation).matrix, T, atol=1e-12)
    assert np.allclose(Extrinsic.from_rpy(ext.rpy(), ext.translation).matrix, T, atol=1e-10)
    assert np.allclose(Extrinsic.from_rpy(ext.rpy(degrees=False), ext.translation, degrees=False).matrix, T, atol=1e-10)
    assert np.allclose(ext.inverse().matrix, np.linalg.inv(T), atol=1e-12)
    assert np.allclose(ext.compose(ext.inverse()).matrix, np.eye(4), atol=1e-12)
    assert ext.quaternion_xyzw[3] >= 0


def test_rpy_is_the_ros_convention():
    roll, pitch, yaw = 10.0, -20.0, 30.0
    ext = Extrinsic.from_rpy([roll, pitch, yaw], [0, 0, 0])
    r = np.radians
    Rx = np.array([[1, 0, 0], [0, np.cos(r(roll)), -np.sin(r(roll))], [0, np.sin(r(roll)), np.cos(r(roll))]])
    Ry = np.array([[np.cos(r(pitch)), 0, np.sin(r(pitch))], [0, 1, 0], [-np.sin(r(pitch)), 0, np.cos(r(pitch))]])
    Rz = np.array([[np.cos(r(yaw)), -np.sin(r(yaw)), 0], [np.sin(r(yaw)), np.cos(r(yaw)), 0], [0, 0, 1]])
    assert np.allclose(ext.R, Rz @ Ry @ Rx)


@pytest.mark.parametrize("off_lock_deg", [0.0, 1e-7, 2e-5, 0.05])
@pytest.mark.parametrize("lock_deg", [-90.0, 90.0])
def test_rpy_at_and_beside_gimbal_lock_is_exact_and_silent(off_lock_deg, lock_deg):
    """A forward-looking rig's T_cam_lidar sits at pitch = -90 deg: no warning, and the angles
    still give the rotation back (scipy sets yaw = 0 there and warns at the user's terminal)."""
    import warnings

    rotations = [Rotation.from_matrix(LIDAR_TO_CAMERA_AXES)] if lock_deg < 0 and off_lock_deg == 0 else []
    rotations += [Rotation.from_euler("xyz", [roll, lock_deg - np.sign(lock_deg) * off_lock_deg, yaw], degrees=True)
                  for roll, yaw in ((0.0, 0.0), (37.0, -12.0), (-150.0, 100.0))]
    for rot in rotations:
        ext = Extrinsic(rot.as_rotvec(), np.zeros(3))
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # any warning fails the test
            rpy = ext.rpy()
        assert abs(rpy[1] - lock_deg) < 0.1
        np.testing.assert_allclose(Extrinsic.from_rpy(rpy, np.zeros(3)).R, ext.R, atol=2e-6)
    # away from the lock: exactly scipy's answer
    rot = Rotation.from_euler("xyz", [10.0, -20.0, 30.0], degrees=True)
    np.testing.assert_array_equal(euler_xyz(rot, degrees=True), rot.as_euler("xyz", degrees=True))


def test_transform_maps_lidar_points_into_the_camera_frame():
    ext = Extrinsic([0.1, -0.2, 0.3], [1.0, 2.0, 3.0])
    P = RNG.normal(size=(50, 3))
    assert np.allclose(ext.transform(P), (ext.matrix @ np.c_[P, np.ones(50)].T).T[:, :3])
    assert np.allclose(ext.inverse().transform(ext.transform(P)), P)


def test_perturbed_and_delta_to_are_inverse():
    a, b = list(random_extrinsics(2))
    dt, dw = a.delta_to(b)
    assert np.allclose(a.perturbed(dt, dw).matrix, b.matrix, atol=1e-12)
    deg, m = a.error_to(a.perturbed([0.03, 0.0, -0.04], [0.0, np.radians(2.0), 0.0]))
    assert deg == pytest.approx(2.0) and m == pytest.approx(0.05)


def test_bad_matrices_are_rejected():
    with pytest.raises(ValueError):
        Extrinsic.from_matrix(np.eye(3))
    with pytest.raises(ValueError):
        Extrinsic.from_matrix(np.diag([1.0, 1.0, -1.0, 1.0]))
    with pytest.raises(ValueError):
        Extrinsic([np.nan, 0, 0], [0, 0, 0])


def cloud(n=2000):
    return RNG.uniform([-4, -2.5, 1.5], [4, 2.5, 12], (n, 3))


@pytest.mark.parametrize(
    "D", [[0, 0, 0, 0, 0], [-0.28, 0.09, 0.001, -0.002, -0.01], [0.1, -0.05, 0.002, 0.001, 0.0, 0.01, 0.0, 0.001]]
)
def test_radtan_projection_matches_opencv(D):
    cam = CameraModel(K, 1280, 720, D, "radtan")
    P = cloud()
    uv, front = project_points(P, cam)
    ref, _ = cv2.projectPoints(P, np.zeros(3), np.zeros(3), K, np.array(D, float))
    # within the lens's fold the two agree; past it (D1 folds at 65 deg off axis) ours sees nothing
    seen = (P[:, 0] ** 2 + P[:, 1] ** 2) / P[:, 2] ** 2 <= cam.max_r2
    assert seen.mean() > 0.9
    assert np.array_equal(front, seen)
    assert np.abs(uv[seen] - ref.reshape(-1, 2)[seen]).max() < 1e-9
    assert np.isnan(uv[~seen]).all()


def test_equidistant_projection_matches_opencv_fisheye():
    D = [0.05, -0.01, 0.002, -0.0005]
    cam = CameraModel(K, 1280, 720, D, "equidistant")
    P = cloud()
    uv, _ = project_points(P, cam)
    ref, _ = cv2.fisheye.projectPoints(P[:, None, :], np.zeros(3), np.zeros(3), K, np.array(D))
    assert np.abs(uv - ref.reshape(-1, 2)).max() < 1e-9


def test_points_behind_the_camera_are_flagged():
    cam = CameraModel(K, 1280, 720)
    uv, front = project_points(np.array([[0.0, 0.0, 5.0], [0.0, 0.0, -5.0]]), cam)
    assert front.tolist() == [True, False]
    assert np.isnan(uv[1]).all()


@pytest.mark.parametrize("model,D", [("radtan", [-0.2, 0.05, 0.001, -0.002, 0.01]), ("equidistant", [0.1, -0.05, 0.01, -0.002])])
def test_projection_jacobian_matches_finite_differences(model, D):
    cam = CameraModel(K, 1280, 720, D, model)
    P = cloud(300)
    _, _, J = project_with_jacobian(P, cam)
    eps = 1e-6
    for k in range(3):
        d = np.zeros(3)
        d[k] = eps
        num = (project_points(P + d, cam)[0] - project_points(P - d, cam)[0]) / (2 * eps)
        assert np.abs(J[:, :, k] - num).max() < 1e-4


def test_left_jacobian_linearises_the_exponential():
    w = np.array([0.3, -0.2, 0.5])
    dw = 1e-6 * np.array([1.0, 2.0, -1.0])
    lhs = Rotation.from_rotvec(w + dw).as_matrix()
    rhs = (Rotation.from_rotvec(left_jacobian(w) @ dw) * Rotation.from_rotvec(w)).as_matrix()
    assert np.abs(lhs - rhs).max() < 1e-11
