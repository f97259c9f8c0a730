"""The edge score reads the image gradient across the lidar's scan lines (issue 16): the lines'
direction comes from the rings as the seed and the lens project them, so any mount and any lens
reads the edges the scan can match, and horizontal clutter does not pull the score."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from l2e_studio.camera import CameraModel
from l2e_studio.geometry import Extrinsic, in_image, project_points
from l2e_studio.objective import SceneStack
from l2e_studio.scenes import Scene
from l2e_studio.score_maps import scan_directions
from l2e_studio.scoring import edges
from l2e_studio.synth.lidars import LIDARS, ring_directions

#: lidar (x forward, y left, z up) to camera (x right, y down, z forward), upright, 10 cm apart
UPRIGHT = np.array([[0.0, -1, 0], [0, 0, -1], [1, 0, 0]])
#: camera to the same camera turned on its side (90 deg about its optical axis): x' = y, y' = -x
ON_ITS_SIDE = np.array([[0.0, 1, 0], [-1, 0, 0], [0, 0, 1]])


def _extrinsic(R: np.ndarray, t=(0.0, -0.1, 0.05)) -> Extrinsic:
    M = np.eye(4)
    M[:3, :3], M[:3, 3] = R, t
    return Extrinsic.from_matrix(M)


def _angle_between_lines(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle (deg) between undirected 2D directions, 0..90."""
    cos = np.abs(np.sum(a * b, axis=1)) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
    return np.degrees(np.arccos(np.clip(cos, 0.0, 1.0)))


PINHOLE = CameraModel(np.array([[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]]), 640, 480)
BARREL = CameraModel(np.array([[450.0, 0, 330], [0, 450.0, 235], [0, 0, 1]]), 640, 480, np.array([-0.3, 0.09, 0.001, -0.001, 0.0]))
FISHEYE = CameraModel(np.array([[260.0, 0, 320], [0, 260.0, 240], [0, 0, 1]]), 640, 480,
                      np.array([0.05, -0.01, 0.002, 0.0]), "equidistant")
MOUNTS = {
    "upright": UPRIGHT,
    "on its side": ON_ITS_SIDE @ UPRIGHT,
    "lidar pitched 25 deg": UPRIGHT @ Rotation.from_euler("y", 25, degrees=True).as_matrix(),
    "rolled 30 deg, yawed 40 deg": Rotation.from_euler("z", 30, degrees=True).as_matrix() @ UPRIGHT
    @ Rotation.from_euler("z", 40, degrees=True).as_matrix(),
}


@pytest.mark.parametrize("camera", [PINHOLE, BARREL, FISHEYE], ids=["pinhole", "barrel", "fisheye"])
@pytest.mark.parametrize("mount", list(MOUNTS))
def test_the_scan_direction_is_where_the_rings_run_in_the_image(camera: CameraModel, mount: str) -> None:
    """Consecutive returns of one ring, projected through the mount and the lens, step along the
    field at their pixel: a 32-beam lidar's rings against the field, for every pixel they reach."""
    ext = _extrinsic(MOUNTS[mount])
    field = scan_directions(camera, ext)
    assert field.shape == (camera.height, camera.width, 2) and field.dtype == np.float32
    dirs, ring = ring_directions(LIDARS["hdl32"]["elevations_deg"], 0.16, np.random.default_rng(0))
    P = 15.0 * dirs  # 15 m away: the 10 cm lever arm barely bends the rings
    uv, front = project_points(ext.transform(P), camera)
    nxt = np.roll(np.arange(len(P)), -1)  # the next return along the ring
    same_ring = ring == ring[nxt]
    ok = front & front[nxt] & same_ring & in_image(uv, camera, margin=2) & in_image(uv[nxt], camera, margin=2)
    step = uv[nxt] - uv
    ok &= (np.linalg.norm(step, axis=1) > 0.3) & (np.linalg.norm(step, axis=1) < 20)
    assert ok.sum() > 1000, "the rings must cross the image"
    px = np.rint(uv[ok]).astype(int)
    u = field[px[:, 1], px[:, 0]]
    off = _angle_between_lines(step[ok], u)
    assert np.median(off) < 0.5 and np.percentile(off, 95) < 2.0, (np.median(off), np.percentile(off, 95))
    assert np.allclose(np.linalg.norm(field, axis=2), 1.0, atol=1e-3)


def test_a_lens_folding_past_its_fitted_range_gets_a_sane_field() -> None:
    """A strong barrel polynomial turns back before the image corners (as on a real 1280x720
    camera of the dev rigs): there the field takes the nearest good direction, never NaN, never
    a direction the fold spun round."""
    cam = CameraModel(np.array([[897.5, 0, 635.4], [0, 896.8, 375.3], [0, 0, 1]]), 1280, 720,
                      np.array([-0.44, 0.233, -0.0011, 0.0002, -0.073]))
    field = scan_directions(cam, _extrinsic(UPRIGHT))
    assert np.isfinite(field).all()
    coarse = field[::8, ::8]
    jumps = [_angle_between_lines(a.reshape(-1, 2), b.reshape(-1, 2)).max()
             for a, b in ((coarse[1:], coarse[:-1]), (coarse[:, 1:], coarse[:, :-1]))]
    assert max(jumps) < 10.0, jumps  # the fold spun it by 30-50 deg between grid points 16 px apart
    angle = _angle_between_lines(field.reshape(-1, 2), np.array([[1.0, 0.0]]))
    assert angle.max() < 30.0, angle.max()  # rings tilt toward the corners, no more


def _stripes(first_vertical: bool, split_rows: bool, shape=(480, 640), period=24) -> np.ndarray:
    """Vertical stripes in one half of the image (left, or top with ``split_rows``), horizontal
    ones in the other (``first_vertical`` false: the other way round)."""
    h, w = shape
    v = np.where((np.arange(w) // (period // 2)) % 2 == 0, 60.0, 190.0)[None, :] * np.ones((h, 1))
    hz = np.where((np.arange(h) // (period // 2)) % 2 == 0, 60.0, 190.0)[:, None] * np.ones((1, w))
    first = (np.arange(h)[:, None] < h // 2) if split_rows else (np.arange(w)[None, :] < w // 2)
    return np.where(first == first_vertical, v, hz).astype(np.float32)


def test_the_edge_map_reads_only_edges_that_cross_the_scan_lines() -> None:
    """Upright, horizontal edges (a horizon, shelves, kerbs) are no edge at all; turned on its
    side, the same camera reads them and drops the vertical ones."""
    upright = scan_directions(PINHOLE, _extrinsic(UPRIGHT))
    side = scan_directions(PINHOLE, _extrinsic(ON_ITS_SIDE @ UPRIGHT))

    def spread(image: np.ndarray, scan: np.ndarray, split_rows: bool) -> tuple[float, float]:
        """Spread of the band-passed map in each half, near the centre row (halves left and right)
        or the centre column (halves top and bottom): where the rings run straight."""
        m = edges.edge_map(image, 1.5, scan=scan) - edges.OFFSET
        if split_rows:
            return float(np.std(m[40:200, 280:360])), float(np.std(m[280:440, 280:360]))
        return float(np.std(m[200:280, 40:280])), float(np.std(m[200:280, 360:600]))

    for scan, split_rows, crossing in ((upright, False, True), (side, True, False)):
        # ``crossing``: the vertical stripes cross the scan lines
        a, b = spread(_stripes(True, split_rows), scan, split_rows)
        c, d = spread(_stripes(False, split_rows), scan, split_rows)
        read, ignored = ((a, d), (b, c)) if crossing else ((b, c), (a, d))
        assert min(read) > 20.0, read
        assert max(ignored) < 0.02 * min(read), (read, ignored)


def _scene(rng: np.random.Generator) -> tuple[Scene, np.ndarray]:
    """Points with depth steps (boxes before a wall) and an image with edges of every orientation."""
    dirs, _ = ring_directions(LIDARS["vlp16"]["elevations_deg"], 0.2, rng, hfov_deg=90.0)
    r = np.full(len(dirs), 12.0)
    az, el = np.degrees(np.arctan2(dirs[:, 1], dirs[:, 0])), np.degrees(np.arcsin(dirs[:, 2]))
    for a0, a1, e0, e1, depth in ((-30, -12, -10, 6, 5.0), (4, 14, -14, 12, 7.0), (20, 34, -6, 3, 4.0)):
        r[(az > a0) & (az < a1) & (el > e0) & (el < e1)] = depth
    img = cv2.GaussianBlur(rng.uniform(0, 255, (48, 64)).astype(np.float32), (0, 0), 1.0)
    img = cv2.resize(img, (640, 480), interpolation=cv2.INTER_CUBIC)
    cv2.rectangle(img, (100, 90), (260, 330), 240.0, -1)
    cv2.circle(img, (450, 200), 70, 20.0, -1)
    return Scene("boxes", (r[:, None] * dirs).astype(np.float32), (r < 10) * 150.0 + 50.0, img, "image"), img


def test_a_camera_on_its_side_scores_as_the_same_camera_upright() -> None:
    """Turn the camera 90 deg about its axis and its image with it: the stack's edge map turns
    with it and the score at every extrinsic is the upright one's. Reading the image rows
    instead (no seed to project the rings) gives the side camera another score altogether."""
    scene, img = _scene(np.random.default_rng(4))
    K = PINHOLE.K
    side_cam = CameraModel(np.array([[K[1, 1], 0, K[1, 2]], [0, K[0, 0], PINHOLE.width - 1 - K[0, 2]], [0, 0, 1]]),
                           PINHOLE.height, PINHOLE.width)
    side_img = np.ascontiguousarray(np.rot90(img))  # upright pixel (u, v) is the side camera's (v, W-1-u)
    side_scene = Scene(scene.name, scene.points, scene.intensity, side_img, "image")
    truth = _extrinsic(UPRIGHT)
    side_truth = _extrinsic(ON_ITS_SIDE @ UPRIGHT, ON_ITS_SIDE @ truth.translation)
    up = SceneStack.build([scene], PINHOLE, 4.0, truth, objective="edges", gradient="scan-lines")
    side = SceneStack.build([side_scene], side_cam, 4.0, side_truth, objective="edges", gradient="scan-lines")
    assert np.abs(np.rot90(up.maps[0]) - side.maps[0]).max() < 0.05 * edges.SCALE
    rng = np.random.default_rng(5)
    turn = np.eye(4)
    turn[:3, :3] = ON_ITS_SIDE
    for _ in range(5):
        a = truth.perturbed(rng.normal(0, 0.03, 3), rng.normal(0, np.radians(1.0), 3))
        b = Extrinsic.from_matrix(turn @ a.matrix)
        assert up.score(a, per_scene=False)[0] == pytest.approx(side.score(b, per_scene=False)[0], rel=0.02, abs=1e-4)
    rows = SceneStack.build([side_scene], side_cam, 4.0, None, objective="edges", gradient="scan-lines")
    assert abs(rows.score(side_truth, per_scene=False)[0] - up.score(truth, per_scene=False)[0]) > \
        0.2 * abs(up.score(truth, per_scene=False)[0])


def test_a_seed_turned_far_from_the_stacks_prepares_the_edge_maps_again() -> None:
    """The app's readout (and the optimiser it hands its stack to) reads across the scan lines of
    the extrinsic in hand: within 3 deg of the one the maps were prepared for they are kept; a
    seed turned on its side gets the maps a stack built there has."""
    from l2e_studio.app.readout import MiReadout

    scene, _ = _scene(np.random.default_rng(6))
    truth = _extrinsic(UPRIGHT)
    stack = SceneStack.build([scene], PINHOLE, 4.0, truth, objective="edges", gradient="scan-lines")
    near = truth.perturbed(np.zeros(3), np.radians([1.5, -1.0, 1.0]))
    assert stack.aimed_at(near) is stack
    turned = _extrinsic(Rotation.from_euler("z", 20, degrees=True).as_matrix() @ UPRIGHT)
    aimed = stack.aimed_at(turned)
    fresh = SceneStack.build([scene], PINHOLE, 4.0, turned, objective="edges", gradient="scan-lines")
    assert aimed is not stack and np.array_equal(aimed.maps, fresh.maps)
    assert np.array_equal(aimed.points, stack.points)  # the same points: only the maps follow the seed
    assert aimed.aimed_at(turned) is aimed

    readout = MiReadout([scene], PINHOLE, truth, 4.0, gradient="scan-lines")
    before = readout.generation
    readout.read(near, [True])
    assert readout.generation == before
    reading = readout.read(turned, [True])
    assert readout.generation == before + 1
    assert reading.total == pytest.approx(fresh.score(turned, per_scene=False)[0])


def test_the_default_edge_map_reads_every_orientation_and_the_scan_lines_are_opted_into() -> None:
    """The gradient across the scan lines is a setting (``edge_gradient="scan-lines"``): by
    default the map reads the gradient magnitude, whatever the seed, and nothing is re-aimed."""
    from l2e_studio.calibrate import CalibrationSettings, stack_scenes

    scene, img = _scene(np.random.default_rng(7))
    truth = _extrinsic(UPRIGHT)
    default = stack_scenes([scene], PINHOLE, truth)
    assert default.gradient == "magnitude" and default.scan is None
    assert default.aimed_at(_extrinsic(ON_ITS_SIDE @ UPRIGHT)) is default
    expected = edges.edge_map(img, default.sigma)
    assert np.array_equal(default.maps[0, 1:-1, 1:-1], expected)
    opted = stack_scenes([scene], PINHOLE, truth, CalibrationSettings(edge_gradient="scan-lines"))
    assert opted.gradient == "scan-lines" and opted.scan is not None
    assert not np.array_equal(opted.maps, default.maps)
    with pytest.raises(ValueError, match="edge gradient"):
        CalibrationSettings(edge_gradient="sobel")
