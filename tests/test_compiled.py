"""The compiled nearest-pixel lookup and pair counting, against the numpy projection (which the
geometry tests check against OpenCV) and a loop-by-loop count."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from l2e_studio.camera import CameraModel
from l2e_studio.geometry import in_image, project_points
from l2e_studio.compiled import (Lookup, count_events, count_pairs, count_pairs_at_poses, e_bins, edge_sum,
                                 edge_sums_at_poses, pixel_index, separable, soft_histogram)
from l2e_studio.scoring.mi import kernel_matrix, kernel_taps

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


def test_edge_sum_is_numpys_weighted_bincount_to_the_last_bit():
    """The edge score's sum at the points' pixels, the border where a point is off the image, in
    float64 in the points' order: ``np.bincount``'s, bit for bit (the far field's scores must be
    the score's own)."""
    rng = np.random.default_rng(5)
    padded = rng.uniform(0.0, 255.0, (H + 2, W + 2)).astype(np.float32)
    padded[0, 0] = 128.0 + 7.0  # a border that is not "no edge", so that a wrong read shows
    pix = rng.integers(-1, W * H, 50_000).astype(np.int32)
    pix[::7] = -1
    weights = rng.uniform(0.1, 2.0, pix.size).astype(np.float32)
    row, col = np.divmod(pix.astype(np.int64), W)
    e = np.where(pix >= 0, padded[row + 1, col + 1], padded[0, 0]).astype(np.float64)
    want = np.bincount(np.zeros(pix.size, np.int64), weights=weights * (e - 128.0) / 127.0)[0]
    assert edge_sum(pix, weights, padded, 128.0, 127.0) == want
    assert edge_sum(pix[:0], weights[:0], padded, 128.0, 127.0) == 0.0


@pytest.mark.parametrize("name", ["rational", "equidistant"])
def test_counts_and_edge_sums_at_many_poses_are_those_of_one_pose_after_the_other(name):
    """The far field's poses, scene by scene: every point at every pose on the pixel
    :func:`pixel_index` gives, so the counts :func:`count_pairs` makes and the sums of
    :func:`edge_sum`, to the last bit."""
    camera = CAMERAS[name]
    rng = np.random.default_rng(5)
    pts = np.ascontiguousarray(cloud(30_000).T)
    starts = np.array([0, 7_000, 7_000, 19_000, 30_000])  # four scenes, one without points
    l_bins = rng.integers(0, 256, pts.shape[1]).astype(np.int32)
    weights = rng.uniform(0.1, 2.0, pts.shape[1]).astype(np.float32)
    maps = rng.uniform(0.0, 255.0, (4, H + 2, W + 2)).astype(np.float32)
    bins = rng.integers(0, 256, (4, W * H)).astype(np.uint8)
    Rs = Rotation.from_rotvec(rng.normal(0.0, 0.05, (5, 3))).as_matrix().astype(np.float32)
    ts = rng.normal(0.0, 0.1, (5, 3)).astype(np.float32)
    hists = np.zeros((5, 65536), np.int32)
    sums = np.zeros((5, 4))
    count_pairs_at_poses(pts, l_bins, starts, Rs, ts, camera, MIN_DEPTH, bins, hists)
    edge_sums_at_poses(pts, weights, starts, Rs, ts, camera, MIN_DEPTH, maps, 128.0, 127.0, sums)
    for k in range(5):
        want = np.zeros(65536, np.int32)
        for s in range(4):
            a, b = starts[s], starts[s + 1]
            pix = pixel_index(pts[:, a:b], Rs[k], ts[k], camera, MIN_DEPTH)
            assert b == a or 0.05 < np.mean(pix >= 0) < 0.9
            count_pairs(pix, l_bins[a:b], bins[s], want)
            assert sums[k, s] == edge_sum(pix, weights[a:b], maps[s], 128.0, 127.0)
        np.testing.assert_array_equal(hists[k], want)


def test_e_bins_are_the_nearest_bins_of_the_padded_map():
    rng = np.random.default_rng(1)
    m = rng.gamma(1.0, 40.0, (30, 50)).astype(np.float32)
    m[0, :] = 0.0  # the zero padding
    m[3, 4], m[5, 6] = 300.0, 127.5  # over the clip; a tie that rounds to even
    bins = np.empty((28, 48), np.uint8)
    e_bins(m, bins)
    assert np.array_equal(bins, np.clip(np.rint(m[1:-1, 1:-1]), 0, 255).astype(np.uint8))



def lookup_rig(camera, n_scenes=3, seed=5):
    """Padded maps of ``camera``'s size, each a bilinear function of the pixel (which bilinear
    interpolation reproduces exactly: the lookup is then a smooth function of the pose, and
    finite differences test the projection's chain), and a :class:`Lookup` reading them."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    rng = np.random.default_rng(seed)
    maps = np.zeros((n_scenes, H + 2, W + 2), np.float32)
    for s in range(n_scenes):
        a, b, c = rng.uniform(0.05, 0.12, 3)
        maps[s, 1:-1, 1:-1] = 40 + a * u + b * v + c * 2e-3 * (u - 300) * (v - 200)
    scene_base = lambda scene: (scene * (H + 2) * (W + 2)).astype(np.int64)  # noqa: E731
    return maps, scene_base, Lookup(camera, maps.reshape(-1), np.zeros(0, np.int64), W + 2, W + 1 - 1e-3,
                                    H + 1 - 1e-3, MIN_DEPTH, 254.999)


@pytest.mark.parametrize("name", CAMERAS)
def test_lookup_values_are_the_float64_projection_read_bilinearly(name):
    from scipy.ndimage import map_coordinates

    camera = CAMERAS[name]
    maps, scene_base, look = lookup_rig(camera)
    p = cloud(40_000)
    scene = np.random.default_rng(1).integers(0, 3, len(p))
    look._base = scene_base(scene)
    R = Rotation.from_rotvec([0.05, -0.2, 0.03]).as_matrix()
    t = np.array([0.1, -0.05, 0.2])
    e, du, dv = (np.empty(len(p), np.float32) for _ in range(3))
    pts = np.ascontiguousarray(p.T)
    look.values(pts, 0, len(p), R.astype(np.float32), t.astype(np.float32), e, du, dv)
    uv, seen = project_points(p.astype(np.float64) @ R.T + t, camera)
    seen &= (p.astype(np.float64) @ R.T + t)[:, 2] > MIN_DEPTH
    u = np.clip(np.nan_to_num(uv[:, 0], nan=-1.0) + 1.0, 0.0, W + 1 - 1e-3)
    v = np.clip(np.nan_to_num(uv[:, 1], nan=-1.0) + 1.0, 0.0, H + 1 - 1e-3)
    u[~seen] = 0.0  # a point the camera does not see reads column 0 (the padding, mostly)
    ref = np.array([map_coordinates(maps[s], [[b], [a]], order=1)[0] for s, a, b in zip(scene, u, v)])
    assert seen.sum() > 3000 and (~seen).sum() > 10000
    assert np.abs(e - ref).max() < 0.05  # float32 projection: a few thousandths of a pixel
    inside = seen & (uv[:, 0] > 2) & (uv[:, 0] < W - 3) & (uv[:, 1] > 2) & (uv[:, 1] < H - 3)
    assert (du[~seen] == 0).all() and (dv[~seen] == 0).all()  # unseen or past the fold: no derivative
    assert np.abs(du[inside]).max() > 0.1 and np.abs(dv[inside]).max() > 0.1


@pytest.mark.parametrize("name", CAMERAS)
def test_lookup_gradient_matches_finite_differences_of_the_weighted_values(name):
    camera = CAMERAS[name]
    maps, scene_base, look = lookup_rig(camera)
    rng = np.random.default_rng(4)
    p = np.column_stack([rng.uniform(-6, 6, 30_000), rng.uniform(-4, 4, 30_000), rng.uniform(4, 15, 30_000)])
    R0 = Rotation.from_rotvec([0.02, 0.05, -0.01])
    t0 = np.array([0.05, 0.02, -0.1])
    # points well inside the image: the border's one-pixel ramp into the zero padding is hundreds
    # of times steeper than the maps, and a finite step across its edge would swamp the sum
    uv, seen = project_points(p @ R0.as_matrix().T + t0, camera)
    keep = seen & (uv[:, 0] > 10) & (uv[:, 0] < W - 10) & (uv[:, 1] > 10) & (uv[:, 1] < H - 10)
    p = p[keep].astype(np.float32)
    assert len(p) > 5000
    scene = rng.integers(0, 3, len(p))
    look._base = scene_base(scene)
    w = rng.uniform(0.2, 1.0, len(p)).astype(np.float32)
    pts = np.ascontiguousarray(p.T)

    def weighted(delta):
        R = (Rotation.from_rotvec(delta[3:]) * R0).as_matrix()
        e = np.empty(len(p), np.float32)
        look.values(pts, 0, len(p), R.astype(np.float32), (t0 + delta[:3]).astype(np.float32), e)
        return float(w.astype(np.float64) @ e)

    e, du, dv = (np.empty(len(p), np.float32) for _ in range(3))
    look.values(pts, 0, len(p), R0.as_matrix().astype(np.float32), t0.astype(np.float32), e, du, dv)
    g = np.zeros(6)
    look.gradient(pts, 0, len(p), R0.as_matrix().astype(np.float32), t0.astype(np.float32), w, du, dv, g)
    steps = np.array([1e-3] * 3 + [1e-4] * 3)
    numeric = np.array([(weighted(np.eye(6)[k] * steps[k]) - weighted(-np.eye(6)[k] * steps[k])) / (2 * steps[k])
                        for k in range(6)])
    assert np.allclose(g, numeric, rtol=1e-3, atol=1e-3 * np.abs(numeric).max())


def test_soft_histogram_splits_each_weight_between_two_bins():
    rng = np.random.default_rng(8)
    e = rng.uniform(0, 254.999, 50_000).astype(np.float32)
    offset = (rng.integers(0, 256, e.size) * 256).astype(np.int32)
    h = soft_histogram(offset, e, 256 * 256)
    b = e.astype(np.int64)
    f = e.astype(np.float64) - b
    ref = np.bincount(offset + b, weights=1 - f, minlength=65537) + np.bincount(offset + b + 1, weights=f, minlength=65537)
    assert np.allclose(h, ref[:65536], rtol=0, atol=1e-9)
    assert h.sum() == pytest.approx(e.size)


@pytest.mark.parametrize("h_l,h_e", [(0.0, 2.5), (1.3, 0.6), (4.0, 3.3), (40.0, 12.0)])
def test_separable_smoothing_is_the_kernel_matrices_product(h_l, h_e):
    x = np.random.default_rng(3).uniform(0, 1, (256, 256))
    ref = kernel_matrix(h_l) @ x @ kernel_matrix(h_e).T
    assert np.abs(separable(x, kernel_taps(h_l), kernel_taps(h_e)) - ref).max() < 1e-13
    row = x[:1]  # one row (a marginal), smoothed along its bins only
    assert np.abs(separable(row, kernel_taps(0.0), kernel_taps(h_e)) - row @ kernel_matrix(h_e).T).max() < 1e-13
    A = kernel_matrix(h_l)
    assert np.array_equal(A, A.T)  # symmetric: the filter is its own adjoint (the MI's gradient)
    with pytest.raises(ValueError):
        separable(row, kernel_taps(2.0), kernel_taps(h_e))  # reaches past the one row


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
