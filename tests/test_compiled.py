"""The compiled nearest-pixel lookup and pair counting, against the numpy projection (which the
geometry tests check against OpenCV) and a loop-by-loop count."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from l2e_studio.camera import CameraModel
from l2e_studio.geometry import in_image, project_points
from l2e_studio.compiled import bilinear, count_events, count_pairs, e_bins, pixel_index

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


def test_e_bins_are_the_nearest_bins_of_the_padded_map():
    rng = np.random.default_rng(1)
    m = rng.gamma(1.0, 40.0, (30, 50)).astype(np.float32)
    m[0, :] = 0.0  # the zero padding
    m[3, 4], m[5, 6] = 300.0, 127.5  # over the clip; a tie that rounds to even
    bins = np.empty((28, 48), np.uint8)
    e_bins(m, bins)
    assert np.array_equal(bins, np.clip(np.rint(m[1:-1, 1:-1]), 0, 255).astype(np.uint8))



def test_bilinear_lookup_and_its_derivatives_match_scipy_and_finite_differences():
    from scipy.ndimage import map_coordinates

    rng = np.random.default_rng(2)
    maps = rng.uniform(0, 100, (3, 20, 30)).astype(np.float32)
    n = 2000
    scene = rng.integers(0, 3, n)
    uc = rng.uniform(0, 28.999, n).astype(np.float32)
    vc = rng.uniform(0, 18.999, n).astype(np.float32)
    uc[:5] = np.nan  # an overflowed projection reads pixel 0 of its scene, never outside
    e, du, dv = (np.empty(n, np.float32) for _ in range(3))
    bilinear(maps.reshape(-1), (scene * 600).astype(np.int64), 30, uc, vc, e, du, dv)
    u0 = np.nan_to_num(uc, nan=0.0)
    ref = np.array([map_coordinates(maps[s], [[v], [u]], order=1)[0] for s, u, v in zip(scene, u0, vc)])
    assert np.allclose(e, ref, atol=1e-3)
    h = np.float32(1e-2)
    e_u, e_v = np.empty(n, np.float32), np.empty(n, np.float32)
    bilinear(maps.reshape(-1), (scene * 600).astype(np.int64), 30, u0 + h, vc, e_u)
    bilinear(maps.reshape(-1), (scene * 600).astype(np.int64), 30, u0, vc + h, e_v)
    same_cell = (np.floor(u0) == np.floor(u0 + h)) & (np.floor(vc) == np.floor(vc + h))
    assert same_cell.mean() > 0.9
    assert np.allclose(((e_u - e) / h)[same_cell], du[same_cell], atol=0.05)
    assert np.allclose(((e_v - e) / h)[same_cell], dv[same_cell], atol=0.05)


@pytest.mark.parametrize("dtype", [np.uint16, np.int32, np.int64])
def test_count_events_matches_numpy_select_and_add(dtype) -> None:
    """Events in [begin, end) counted at (y, x); those off the grid (negative too) only reported."""
    rng = np.random.default_rng(9)
    n = 50_000
    x = rng.integers(-3 if dtype != np.uint16 else 0, W + 5, n).astype(dtype)
    y = rng.integers(-3 if dtype != np.uint16 else 0, H + 5, n).astype(dtype)
    t = np.sort(rng.integers(0, 1_000_000, n)).astype(np.int64)
    begin, end = 200_000, 700_000
    grid = np.zeros((H, W), np.int64)
    grid[5, 7] = 3  # counts add to what is there
    inside, outside = count_events(x, y, t, begin, end, grid)
    win = (t >= begin) & (t < end)
    on = win & (x >= 0) & (x < W) & (y >= 0) & (y < H)
    expected = np.zeros((H, W), np.int64)
    expected[5, 7] = 3
    np.add.at(expected, (y[on].astype(np.int64), x[on].astype(np.int64)), 1)
    np.testing.assert_array_equal(grid, expected)
    assert (inside, outside) == (int(on.sum()), int((win & ~on).sum()))
    assert 0 < outside < inside
