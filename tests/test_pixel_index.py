"""The compiled nearest-pixel lookup and pair counting, against the numpy projection (which the
geometry tests check against OpenCV) and a loop-by-loop count."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from l2e_studio.camera import CameraModel
from l2e_studio.geometry import in_image, project_points
from l2e_studio.pixel_index import count_pairs, pixel_index

K = np.array([[610.0, 0.0, 322.5], [0.0, 612.0, 241.0], [0.0, 0.0, 1.0]])
W, H = 640, 480
CAMERAS = {
    "pinhole": CameraModel(K, W, H),
    "radtan": CameraModel(K, W, H, D=np.array([-0.3, 0.1, 0.001, -0.002, -0.02])),
    "rational": CameraModel(K, W, H, D=np.array([0.2, -0.1, 0.001, 0.001, 0.01, 0.5, -0.05, 0.02])),
    "equidistant": CameraModel(K, W, H, D=np.array([0.05, -0.01, 0.002, -0.001]), model="equidistant"),
}
MIN_DEPTH = 0.05


def cloud(n=60_000, seed=3):
    """Points all around the sensor (many behind the camera, many far outside its view)."""
    rng = np.random.default_rng(seed)
    p = rng.normal(0.0, 1.0, (n, 3)) * np.array([8.0, 3.0, 8.0])
    p[: n // 10] *= 1e-3  # some at the origin, closer than the minimum depth
    return p.astype(np.float32)


def reference_index(points, R, t, camera):
    """Nearest pixel by the numpy projection: -1 behind MIN_DEPTH or off [-0.5, W - 0.5)."""
    cam = (points.astype(np.float64) @ R.T + t)
    uv, front = project_points(cam, camera)
    ok = front & (cam[:, 2] > MIN_DEPTH) & in_image(uv, camera)
    ok &= (uv[:, 0] < camera.width - 0.5) & (uv[:, 1] < camera.height - 0.5)
    col = np.floor(np.where(ok, uv[:, 0], 0) + 0.5).astype(np.int64)
    row = np.floor(np.where(ok, uv[:, 1], 0) + 0.5).astype(np.int64)
    return np.where(ok, row * camera.width + col, -1)


@pytest.mark.parametrize("name", list(CAMERAS))
def test_pixel_index_matches_the_numpy_projection(name):
    camera = CAMERAS[name]
    pts = cloud()
    R = Rotation.from_rotvec([0.1, -0.2, 0.05]).as_matrix()
    t = np.array([0.05, -0.1, 0.2])
    got = pixel_index(np.ascontiguousarray(pts.T), R, t, camera, MIN_DEPTH)
    ref = reference_index(pts, R, t, camera)
    assert got.dtype == np.int32 and got.shape == (len(pts),)
    inside = ref >= 0
    assert 0.05 < inside.mean() < 0.9  # the cloud really has points on and off the image
    # float32 arithmetic: a point within ~1e-4 px of a pixel border may round the other way
    assert np.mean(got != ref) < 1e-3
    differ = (got != ref) & (got >= 0) & (ref >= 0)
    assert np.all(np.abs(got[differ] % W - ref[differ] % W) <= 1)
    assert np.all((got >= -1) & (got < W * H))


def test_points_behind_the_camera_never_land_in_the_image():
    camera = CAMERAS["radtan"]
    pts = np.array([[0.1, 0.1, -2.0], [0.0, 0.0, 0.01], [0.0, 0.0, 3.0], [1e6, 1e6, 1.0]], np.float32)
    got = pixel_index(np.ascontiguousarray(pts.T), np.eye(3), np.zeros(3), camera, MIN_DEPTH)
    assert got[0] == -1 and got[1] == -1  # behind, and closer than the minimum depth
    assert got[2] == 241 * W + 323  # the principal point (322.5, 241.0); halves round up
    assert got[3] == -1  # far outside the lens's view: the polynomial overflows, still "off"


def test_count_pairs_is_a_loop_by_loop_count():
    rng = np.random.default_rng(0)
    n = 50_000
    pix = rng.integers(-1, W * H, n).astype(np.int32)
    l_bins = rng.integers(0, 256, n).astype(np.int32)
    e_bins = rng.integers(0, 256, W * H).astype(np.uint8)
    hist = np.zeros(65536, np.int32)
    count_pairs(pix, l_bins, e_bins, hist)
    ref = np.zeros(65536, np.int64)
    for p, lb in zip(pix, l_bins):
        if p >= 0:
            ref[lb * 256 + e_bins[p]] += 1
    assert np.array_equal(hist, ref)
    assert hist.sum() == np.count_nonzero(pix >= 0)
