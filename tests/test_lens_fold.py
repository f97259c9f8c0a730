"""A strong lens model turns back past the field it was fitted on: points the camera cannot see
(50-90 deg off axis) would land inside the image. Every projection leaves them out."""

import cv2
import numpy as np
import pytest

from l2e_studio import compiled
from l2e_studio.camera import CameraModel, fold_r2
from l2e_studio.geometry import Extrinsic, in_image, project_points
from l2e_studio.objective import SceneStack
from l2e_studio.objective.smooth import MIN_DEPTH
from l2e_studio.scenes import Scene

K = np.array([[897.5, 0.0, 635.4], [0.0, 896.8, 375.3], [0.0, 0.0, 1.0]])
#: LCECalib rlfs01's 1280x720 lens (k1 -0.44, k3 -0.07): it folds 50 deg off axis
WIDE = CameraModel(K, 1280, 720, [-0.4398, 0.2329, -0.0011, 0.00021, -0.073])


def rays(deg: np.ndarray, azimuth_deg: float = 0.0, dist: float = 10.0) -> np.ndarray:
    th, ph = np.radians(deg), np.radians(azimuth_deg)
    return dist * np.column_stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)])


def test_the_fold_is_where_the_distorted_radius_stops_growing():
    r = np.sqrt(WIDE.max_r2)
    assert 49.5 < np.degrees(np.arctan(r)) < 50.5
    k1, k2, _, _, k3 = WIDE.D

    def slope(x):  # d r_d / d r of the radial polynomial
        return 1 + 3 * k1 * x**2 + 5 * k2 * x**4 + 7 * k3 * x**6

    assert slope(0.98 * r) > 0 > slope(1.02 * r)
    assert fold_r2("radtan", np.zeros(5)) == np.inf
    assert fold_r2("radtan", [-0.365, 0.184, 0.001, 0.0, 0.0]) == np.inf  # the DAVIS346's lens never turns back
    assert fold_r2("equidistant", [-0.01, 0.002, 0.0, 0.0]) == np.inf
    assert 0 < fold_r2("equidistant", [0.0, -0.2, 0.0, 0.0]) < np.inf


def test_points_past_the_fold_land_in_opencvs_image_and_in_none_of_ours():
    deg = np.arange(20.0, 89.0, 1.0)
    P = np.vstack([rays(deg, az) for az in (0.0, 15.0, 180.0)])
    seen = np.tile(np.tan(np.radians(deg)) ** 2 <= WIDE.max_r2, 3)
    ref, _ = cv2.projectPoints(P, np.zeros(3), np.zeros(3), WIDE.K, WIDE.D)
    ref = ref.reshape(-1, 2)
    assert in_image(ref[~seen], WIDE).sum() >= 15  # the ghosts (53-60 deg off axis) OpenCV's projection puts in the image

    uv, front = project_points(P, WIDE)
    assert np.array_equal(front, seen)
    assert np.isnan(uv[~seen]).all()
    assert np.abs(uv[seen] - ref[seen]).max() < 1e-6

    pix = compiled.pixel_index(P.T.astype(np.float32), np.eye(3), np.zeros(3), WIDE, MIN_DEPTH)
    assert (pix[~seen] == -1).all()
    inside = seen & in_image(uv, WIDE)
    col, row = np.rint(uv[inside]).astype(int).T
    assert np.mean(pix[inside] == row * WIDE.width + col) > 0.99  # float32: a rare point rounds the other way


@pytest.mark.parametrize("azimuth", [0.0, 180.0])
def test_the_objective_reads_nothing_past_the_fold(azimuth):
    deg = np.arange(35.0, 43.0, 0.5)  # in view, near the image's side
    P = rays(deg, azimuth)
    scene = Scene("wide", P.astype(np.float32), np.full(len(P), 100.0, np.float32),
                  np.full((WIDE.height, WIDE.width), 50.0, np.float32))
    stack = SceneStack.build([scene], WIDE, sigma=0.0)
    at = Extrinsic(np.zeros(3), np.zeros(3))
    obj = stack.objective(at)
    assert obj.stack.n_points == len(P)
    e, _ = obj._sample(obj._pose(np.zeros(6)))
    assert (e > 0).all()
    # 18 deg further off axis: 53-61 deg, past the fold (OpenCV: still in the image)
    turn = np.radians(18.0) * (1 if azimuth == 0.0 else -1)
    delta = np.array([0.0, 0.0, 0.0, 0.0, turn, 0.0])
    moved = obj.extrinsic(delta).transform(P)
    assert np.all(np.degrees(np.arctan2(np.hypot(moved[:, 0], moved[:, 1]), moved[:, 2])) > 52)
    ref, _ = cv2.projectPoints(moved, np.zeros(3), np.zeros(3), WIDE.K, WIDE.D)
    assert in_image(ref.reshape(-1, 2), WIDE).sum() >= 12  # OpenCV: most back in the image, some across it
    e, (de_du, de_dv) = obj._sample(obj._pose(delta), derivatives=True)
    assert (e == 0).all() and (de_du == 0).all() and (de_dv == 0).all()
    assert (obj.value_and_grad(delta)[1] == 0).all()
    assert (stack.pixels(obj.extrinsic(delta)) == -1).all()
