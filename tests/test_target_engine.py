"""The checkerboard method: board files, detection, lidar board, solver and CLI on real arrays and files."""

from __future__ import annotations

import os
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from l2e_studio.camera import CameraModel
from l2e_studio.errors import InputError
from l2e_studio.geometry import Extrinsic, project_points
from l2e_studio.target import (Board, TargetFrame, closed_form, crop_board, detect_board, load_target,
                               observability, search_board, solve)
from l2e_studio.geometry import undistort_normalised

from conftest import REALDATA

BOARD = Board("checkerboard", (9, 7), 0.07, (0.767, 0.626))
CAM = CameraModel(np.array([[900.0, 0, 640], [0, 900, 360], [0, 0, 1]]), 1280, 720, np.array([-0.3, 0.1, 0.001, 0.0005, 0.0]))
TRUTH = Extrinsic.from_rpy([-90.0, 0.5, -91.0], [0.05, -0.07, -0.09])  # lidar x forward -> camera z forward


def _realdata() -> Path | None:
    for base in (REALDATA, Path(os.environ.get("L2E_REALDATA", "/nonexistent"))):
        if (base / "lcecalib_rlfs01").is_dir():
            return base
    return None


def board_poses(n: int, rng) -> list[Extrinsic]:
    """Boards 1.5-3 m ahead of the camera, turned up to 30 deg about each in-plane axis."""
    out = []
    for _ in range(n):
        rpy = np.concatenate([rng.uniform(-30, 30, 2), rng.uniform(-20, 20, 1)])
        t = np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.3, 0.3), rng.uniform(1.5, 3.0)])
        out.append(Extrinsic.from_rpy(rpy, t))
    return out


def lidar_board(pose: Extrinsic, truth: Extrinsic, rng, noise: float = 0.01, rows: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Points on the board (lidar frame) sampled along ``rows`` horizontal lines, with range noise; and the ring ends."""
    w, h = BOARD.size_m[0] / 2, BOARD.size_m[1] / 2
    pts, edges = [], []
    to_lidar = truth.inverse().compose(pose)  # board -> lidar
    for y in np.linspace(-0.85 * h, 0.85 * h, rows):
        x = np.linspace(-w, w, 60)
        q = np.column_stack([x, np.full_like(x, y), np.zeros_like(x)])
        p = to_lidar.transform(q)
        p += noise * rng.standard_normal(len(p))[:, None] * p / np.linalg.norm(p, axis=1, keepdims=True)
        pts.append(p)
        edges.extend([p[0], p[-1]])
    return np.vstack(pts), np.array(edges)


def test_board_file_good_and_bad(tmp_path):
    good = tmp_path / "target.yaml"
    good.write_text("target:\n  kind: checkerboard\n  squares: [10, 7]\n  square_m: 0.068\n  size_m: [0.8, 0.6]\n")
    b = load_target(good)
    assert b.inner == (9, 6) and b.size_m == (0.8, 0.6)
    assert np.allclose(b.corners().mean(axis=0), 0) and b.corners().shape == (54, 3)
    for text, words in [("target:\n  kind: circles\n  squares: [4, 5]\n  square_m: 0.1\n", "kind"),
                        ("target:\n  kind: checkerboard\n  squares: [10]\n  square_m: 0.1\n", "squares"),
                        ("target:\n  kind: checkerboard\n  squares: [10, 7]\n  square_m: -1\n", "square_m"),
                        ("target:\n  kind: checkerboard\n  squares: [10, 7]\n  square_m: 0.1\n  size_m: [0.5, 0.5]\n",
                         "smaller than the printed grid"),
                        ("target: [unclosed\n", "YAML")]:
        bad = tmp_path / "bad.yaml"
        bad.write_text(text)
        with pytest.raises(InputError) as exc:
            load_target(bad)
        msg = str(exc.value)
        assert str(bad) in msg and words in msg and "\n" not in msg


def render_board(pose: Extrinsic, camera: CameraModel, board: Board) -> np.ndarray:
    """A grey image of the board at ``pose`` through the camera's lens (white margin, black squares)."""
    h, w = camera.height, camera.width
    img = np.full((h, w), 90, np.uint8)
    s = 0.005
    xs = np.arange(-board.size_m[0] / 2, board.size_m[0] / 2, s) + s / 2
    ys = np.arange(-board.size_m[1] / 2, board.size_m[1] / 2, s) + s / 2
    X, Y = np.meshgrid(xs, ys)
    gx = np.floor((X + board.squares[0] * board.square_m / 2) / board.square_m)
    gy = np.floor((Y + board.squares[1] * board.square_m / 2) / board.square_m)
    inside = (gx >= 0) & (gx < board.squares[0]) & (gy >= 0) & (gy < board.squares[1])
    val = np.where(inside & ((gx + gy) % 2 == 0), 20, 235).astype(np.uint8)
    uv, _ = project_points(pose.transform(np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])), camera)
    # splat at 4x and average down: a sharp but anti-aliased board
    big = np.zeros((h * 4, w * 4), np.float32)
    cnt = np.zeros_like(big)
    ui, vi = np.round(uv[:, 0] * 4 + 1.5).astype(int), np.round(uv[:, 1] * 4 + 1.5).astype(int)
    ok = (ui >= 0) & (ui < w * 4) & (vi >= 0) & (vi < h * 4)
    np.add.at(big, (vi[ok], ui[ok]), val.ravel()[ok])
    np.add.at(cnt, (vi[ok], ui[ok]), 1)
    big = cv2.dilate(big, np.ones((5, 5))), cv2.dilate(cnt, np.ones((5, 5)))
    sm = cv2.resize(big[0], (w, h), interpolation=cv2.INTER_AREA) / np.maximum(cv2.resize(big[1], (w, h), interpolation=cv2.INTER_AREA), 1e-6)
    mask = cv2.resize(big[1], (w, h), interpolation=cv2.INTER_AREA) > 0
    img[mask] = np.clip(sm[mask], 0, 255).astype(np.uint8)
    return img


def test_undistort_inverts_the_lens_model():
    for cam in (CAM, CameraModel(CAM.K, 1280, 720, np.array([0.05, -0.01, 0.002, -0.001]), "equidistant")):
        xy = np.random.default_rng(0).uniform(-0.6, 0.4, (200, 2))
        uv, _ = project_points(np.column_stack([xy, np.ones(len(xy))]), cam)
        assert np.abs(undistort_normalised(uv, cam) - xy).max() < 1e-9


def test_detects_a_rendered_board_and_recovers_its_pose():
    pose = Extrinsic.from_rpy([15.0, -20.0, 5.0], [0.1, -0.05, 2.0])
    det = detect_board(render_board(pose, CAM, BOARD), BOARD, CAM, "f0")
    assert det.found, det.reason
    assert det.reprojection_px < 0.5
    # the plane (normal, offset) does not depend on the 180 deg ordering ambiguity
    n_true = -pose.R[:, 2]
    assert np.degrees(np.arccos(abs(det.normal @ n_true))) < 0.5
    assert abs(det.plane[1] - n_true @ pose.translation) < 0.01


def test_frame_without_board_is_listed_with_reason():
    blank = np.random.default_rng(1).integers(0, 255, (CAM.height, CAM.width)).astype(np.uint8)
    det = detect_board(blank, BOARD, CAM, "empty")
    assert not det.found and "no 8x6 inner-corner grid" in det.reason and det.pose is None


def test_solver_recovers_a_known_extrinsic_from_any_seed():
    rng = np.random.default_rng(3)
    frames = []
    for i, pose in enumerate(board_poses(12, rng)):
        pts, edges = lidar_board(pose, TRUTH, rng)
        frames.append(TargetFrame(f"f{i}", pose, pts, edges))
    ends = []
    for k in range(4):
        seed = TRUTH.perturbed(rng.uniform(-1, 1, 3) * 0.2 / np.sqrt(3), np.radians(rng.uniform(-1, 1, 3) * 5 / np.sqrt(3)))
        start = closed_form(frames, seed)
        assert TRUTH.error_to(start)[0] < 2.0
        ends.append(solve(frames, BOARD, start).extrinsic)
    for e in ends:
        deg, m = TRUTH.error_to(e)
        assert deg < 0.2 and m < 0.005, (deg, m)
        assert ends[0].error_to(e)[0] < 1e-4 and ends[0].error_to(e)[1] < 1e-5
    sol = solve(frames, BOARD, ends[0])
    assert np.all(sol.sigma_m > 0) and np.all(sol.sigma_m < 0.01) and np.all(sol.sigma_deg < 0.2)
    assert observability(frames).observed


def test_parallel_boards_name_the_unobserved_direction():
    rng = np.random.default_rng(4)
    frames = []
    for i in range(6):
        pose = Extrinsic.from_rpy([0, 0, 0], [rng.uniform(-0.5, 0.5), rng.uniform(-0.3, 0.3), rng.uniform(1.5, 3)])
        pts, edges = lidar_board(pose, TRUTH, rng)
        frames.append(TargetFrame(f"f{i}", pose, pts, edges))
    obs = observability(frames)
    assert not obs.observed and "nearly parallel" in obs.advice and "add a pose" in obs.advice


def test_lidar_board_found_beside_a_wall_and_a_floor_from_an_offset_seed():
    rng = np.random.default_rng(5)
    pose = Extrinsic.from_rpy([10.0, 25.0, 0.0], [0.2, 0.0, 2.2])
    pts, _ = lidar_board(pose, TRUTH, rng, rows=10)
    wall = np.column_stack([np.full(6000, 4.5), rng.uniform(-3, 3, 6000), rng.uniform(-1.5, 1.5, 6000)])
    floor = np.column_stack([rng.uniform(0.5, 4.5, 6000), rng.uniform(-3, 3, 6000), np.full(6000, -1.2)])
    person = np.column_stack([rng.normal(2.5, 0.1, 800), rng.normal(-0.2, 0.1, 800), rng.uniform(-1.2, 0.6, 800)])
    scan = np.vstack([pts, wall, floor, person])
    rings = np.concatenate([np.repeat(np.arange(10), 60), np.full(len(scan) - len(pts), 99)])
    from l2e_studio.target import Detection

    det = Detection("f", True, "", np.zeros((48, 2)), pose, 0.1, "test")
    seed = TRUTH.perturbed([0.12, -0.1, 0.12], np.radians([3.0, -3.0, 2.0]))
    found = search_board(scan, rings, det, BOARD, seed)
    assert found.found, found.reason
    assert set(found.indices) <= set(range(len(pts))) and found.n_points > 0.9 * len(pts)
    cropped = crop_board(scan, rings, det, BOARD, TRUTH)
    assert cropped.found and set(cropped.indices) <= set(range(len(pts)))
    assert len(found.edges) == 2 * 10


def test_a_hand_on_the_boards_rim_is_cropped_off_once_the_extrinsic_is_refined():
    """A hand holding the board's bottom edge: points 2.5-6 cm beyond the outline, 4 cm in front
    of the board (within the lidar's plane tolerance). The first crop's 5 cm margin takes them
    and their rings end on the hand; the refined crop's 2 cm margin (TargetSettings) leaves them
    out, so the rings end on the board."""
    from l2e_studio.target import Detection, TargetSettings

    rng = np.random.default_rng(8)
    pose = Extrinsic.from_rpy([5.0, 20.0, 0.0], [0.1, 0.0, 2.0])
    pts, _ = lidar_board(pose, TRUTH, rng, noise=0.005, rows=10)
    h = BOARD.size_m[1] / 2
    hand_board = np.column_stack([rng.uniform(-0.2, 0.2, 300), rng.uniform(h + 0.025, h + 0.06, 300),
                                  np.full(300, -0.04)])  # board frame: z into the board, so in front of it
    hand = TRUTH.inverse().compose(pose).transform(hand_board)
    scan = np.vstack([pts, hand])
    rings = np.concatenate([np.repeat(np.arange(10), 60), np.full(len(hand), 9)])  # the hand on the bottom ring
    det = Detection("f", True, "", np.zeros((48, 2)), pose, 0.1, "test")
    settings = TargetSettings()
    loose = crop_board(scan, rings, det, BOARD, TRUTH, settings.margin(0))
    tight = crop_board(scan, rings, det, BOARD, TRUTH, settings.margin(1))
    assert settings.margin(0) == 0.05 and settings.margin(1) == settings.margin(5) == 0.02
    assert np.sum(loose.indices >= len(pts)) > 100  # the hand is in the first crop
    assert tight.found and np.all(tight.indices < len(pts)), np.sum(tight.indices >= len(pts))
    to_board = pose.inverse().compose(TRUTH)
    for found, on_board in ((loose, False), (tight, True)):
        q = to_board.transform(found.edges)
        assert bool(np.all(np.abs(q[:, 1]) <= h + 0.005)) is on_board


def test_a_board_seen_on_a_few_rings_has_a_loose_tilt_across_them():
    """The lidar plane's own tilt uncertainty (TargetFrame.normal_spread): a whole board crossed
    by ten rings fixes its tilt to a fraction of a degree; the same board seen on its two bottom
    rings only (its top above the lidar's highest beam) is a sliver, loose across the rings by
    degrees (the solve then weighs that tilt less), and the same along them."""
    rng = np.random.default_rng(4)
    pose = Extrinsic.from_rpy([0.0, 15.0, 0.0], [0.0, 0.0, 2.5])
    pts, edges = lidar_board(pose, TRUTH, rng, noise=0.015, rows=10)
    whole = TargetFrame("whole", pose, pts, edges)
    sliver = TargetFrame("sliver", pose, pts[-120:], edges[-4:])  # the last two rows: 2 rings, 7 cm apart
    sd = {f.name: np.degrees(np.sqrt(np.linalg.eigvalsh(f.normal_spread[1]))) for f in (whole, sliver)}
    assert np.all(sd["whole"] < 0.3), sd
    assert sd["sliver"].max() > 1.5 and sd["sliver"].min() < 0.4, sd
    # analytic: the points' scatter off their plane over the root of the sum of squared offsets
    # across the rings (two rows 1.7 h / 9 apart: each point half that off the middle)
    across = sliver.lidar_rms / np.sqrt(120 * (0.85 * BOARD.size_m[1] / 9) ** 2 / 4)
    assert sd["sliver"].max() == pytest.approx(np.degrees(across), rel=0.1)


def test_rings_are_told_from_the_elevations_of_a_dense_lidar_without_a_ring_field():
    """A board 2.5 m away crossed by 12 rings 0.35 deg apart (an OS1-128; an HDL-64E's upper
    block is 0.33 deg), range noise 1.5 cm, and no ring field (KITTI .bin, PLY, many bag
    exports): every ring is told apart from the board points' elevations, and the board is found
    with two edge points per ring (a 0.4 deg gap over the whole scan made them one ring and the
    board was refused)."""
    from l2e_studio.target import Detection
    from l2e_studio.target.lidar import ring_ids

    rng = np.random.default_rng(2)
    el = np.radians(np.arange(12) * 0.35 - 2.0)[:, None]
    az = np.radians(np.linspace(-8.0, 8.0, 150))[None, :]
    rays = np.stack(np.broadcast_arrays(np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)), axis=-1).reshape(-1, 3)
    rng_m = 2.5 / rays[:, 0] + rng.normal(0, 0.015, len(rays))  # a wall-like board 2.5 m ahead (lidar x forward)
    pts = rays * rng_m[:, None]
    truth_rings = np.repeat(np.arange(12), 150)
    found = ring_ids(pts)
    assert len(np.unique(found)) == 12
    assert all(len(np.unique(found[truth_rings == r])) == 1 for r in range(12))
    # the same points as a board in the scan, found without a ring field
    board = Board("checkerboard", (9, 7), 0.07, (0.70, 0.22))  # 16 deg x 2.5 m wide, 12 rings high
    to_cam = Extrinsic.from_rpy([-90.0, 0.0, -90.0], [0.0, 0.0, 0.0])  # lidar x forward -> camera z forward
    centre = to_cam.transform(pts.mean(axis=0)[None])[0]
    pose = Extrinsic(np.zeros(3), centre)
    det = Detection("f", True, "", np.zeros((48, 2)), pose, 0.1, "test")
    lb = crop_board(pts, None, det, board, to_cam)
    assert lb.found, lb.reason
    assert len(lb.edges) == 2 * 12


def test_a_solid_state_pattern_without_rings_gets_edges_along_the_boards_outline():
    """A non-repetitive scan (a Livox-like rosette: every ray at its own elevation) of a board
    2 m ahead, no ring field: no rings can be told apart, and the edge points are the points along
    the convex hull of the board's points, all within a point spacing of the true outline."""
    from l2e_studio.target import Detection

    rng = np.random.default_rng(6)
    to_cam = Extrinsic.from_rpy([-90.0, 0.0, -90.0], [0.0, 0.0, 0.0])  # lidar x forward -> camera z forward
    pose = Extrinsic.from_rpy([0.0, 20.0, 10.0], [0.1, -0.05, 2.0])  # T_cam_board
    to_lidar = to_cam.inverse().compose(pose)  # board -> lidar
    w, h = BOARD.size_m[0] / 2, BOARD.size_m[1] / 2
    q = np.column_stack([rng.uniform(-w, w, 3000), rng.uniform(-h, h, 3000), np.zeros(3000)])
    pts = to_lidar.transform(q)
    pts += pts / np.linalg.norm(pts, axis=1, keepdims=True) * rng.normal(0, 0.01, (len(pts), 1))
    det = Detection("f", True, "", np.zeros((48, 2)), pose, 0.1, "test")
    lb = crop_board(pts, None, det, BOARD, to_cam)
    assert lb.found, lb.reason
    board_xy = to_lidar.inverse().transform(lb.edges)[:, :2]
    from l2e_studio.target.solve import outline_distance

    d = outline_distance(board_xy, BOARD)
    assert len(lb.edges) >= 40 and np.all(d > -0.03) and np.all(d < 0.01), (len(lb.edges), d.min(), d.max())
    assert 0 < lb.azimuth_step_rad < np.radians(1.0)


realdata = pytest.mark.realdata


@realdata
def test_real_checkerboard_sequence_is_calibrated_and_trusted(tmp_path):
    base = _realdata()
    if base is None:
        pytest.skip("../shared/realdata not present")
    from l2e_studio.io.cameras import load_seed
    from l2e_studio.scenes import load_scene_folder
    from l2e_studio.target import calibrate_target
    from l2e_studio.target_verdict import judge_target

    folder = base / "lcecalib_rlfs01"
    ss = load_scene_folder(folder, seed_file=folder / "reference.yaml")
    ref, est = ss.seed, load_seed(folder / "lcecalib_estimate.yaml")
    seed = ref.perturbed([0.1, -0.1, 0.1], np.radians([-3.0, 3.0, -2.0]))
    res = calibrate_target(ss.scenes, ss.camera, seed, load_target(folder / "target.yaml"), exclude={"00003"})
    d = res.target
    assert res.method == "target" and d.detection_rate >= 0.9
    assert [f.reason for f in d.frames if f.name == "00003"] == ["left out by the user"]
    deg, m = ref.error_to(res.extrinsic)
    assert deg < 0.5 and m < 0.03
    assert est.error_to(res.extrinsic)[1] < 0.02
    assert judge_target(res).status == "trusted"


@realdata
def test_one_davis346_two_modalities_both_trusted_and_agreeing():
    """rles01: the DAVIS346's APS frames and E2VID reconstructions of its events see one
    extrinsic. Each is judged on its own, by residuals under the solve's error model (per-board
    offsets as the chi-square over the frames allows), and the two must then agree within what a
    trusted result promises (2 cm / 0.5 deg per axis at 95 %): the sharper test than either
    reference, which sit 4-6 cm from both."""
    base = _realdata()
    if base is None or not (base / "lcecalib_rles01_event").is_dir():
        pytest.skip("../shared/realdata (lcecalib_rles01_*) not present")
    from l2e_studio.scenes import load_scene_folder
    from l2e_studio.target import calibrate_target
    from l2e_studio.target_verdict import judge_target

    out = {}
    for kind in ("frame", "event"):
        folder = base / f"lcecalib_rles01_{kind}"
        ss = load_scene_folder(folder, seed_file=folder / "reference.yaml")
        seed = ss.seed.perturbed([0.1, -0.1, 0.05], np.radians([2.0, -2.0, 1.0]))
        res = calibrate_target(ss.scenes, ss.camera, seed, load_target(folder / "target.yaml"))
        v = judge_target(res)
        assert v.status == "trusted", v.lines()
        residual = next(c for c in v.checks if c.name == "residuals within sensor noise")
        assert "per board" in residual.detail
        out[kind] = v.extrinsic
    deg, m = out["frame"].error_to(out["event"])
    assert deg < 0.5 and m < 0.02, (deg, m)


@realdata
def test_every_seed_gets_one_answer_on_the_davis346_frames():
    """rles01's APS frames from seven seeds 2 deg / 10 cm off: before the final solve also
    started from the planes' closed form, two of them stopped in a shallow dent of the edge cost
    0.027 deg beside the others (the issue asks 0.02 deg / 2 mm between any two seeds)."""
    base = _realdata()
    if base is None or not (base / "lcecalib_rles01_frame").is_dir():
        pytest.skip("../shared/realdata (lcecalib_rles01_frame) not present")
    from l2e_studio.scenes import load_scene_folder
    from l2e_studio.target import calibrate_target, detect_frames

    folder = base / "lcecalib_rles01_frame"
    ss = load_scene_folder(folder, seed_file=folder / "reference.yaml")
    board = load_target(folder / "target.yaml")
    dets = detect_frames(ss.scenes, ss.camera, board)
    rng = np.random.default_rng(0)
    ends = []
    for _ in range(7):
        a, b = rng.standard_normal(3), rng.standard_normal(3)
        seed = ss.seed.perturbed(0.1 * a / np.linalg.norm(a), np.radians(2.0) * b / np.linalg.norm(b))
        ends.append(calibrate_target(ss.scenes, ss.camera, seed, board, detections=dets).extrinsic)
    for e in ends:  # the issue's own bound between any two seeds' results
        deg, m = ends[0].error_to(e)
        assert deg < 0.02 and m < 0.002, (deg, m)


@realdata
def test_cli_target_writes_the_target_section(tmp_path):
    base = _realdata()
    if base is None:
        pytest.skip("../shared/realdata not present")
    import yaml

    from l2e_studio.cli import main

    folder = base / "lcecalib_rles01_frame"
    out = tmp_path / "r.yaml"
    assert main(["calibrate", "--scenes", str(folder), "--seed", str(folder / "lcecalib_estimate.yaml"),
                 "--out", str(out), "--quiet"]) == 0
    doc = yaml.safe_load(out.read_text())
    assert doc["method"] == "target" and doc["target"]["frames_total"] == 19
    assert set(doc["target"]["sigma"]) == {"x_m", "y_m", "z_m", "rx_deg", "ry_deg", "rz_deg"}
    assert {"detected", "reprojection_px", "lidar_points", "plane_rms_m", "edge_rms_m", "used", "reason"} <= set(
        doc["target"]["frames"][0])


def test_cli_bad_target_is_one_line(tmp_path, small_synth_dir, capsys):
    from l2e_studio.cli import main

    bad = tmp_path / "target.yaml"
    bad.write_text("kind: checkerboard\nsquares: [9]\nsquare_m: 0.07\n")
    assert main(["calibrate", "--scenes", str(small_synth_dir), "--target", str(bad), "--out", str(tmp_path / "r.yaml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(bad) in err[0] and "squares" in err[0]
    assert not (tmp_path / "r.yaml").exists()


@pytest.fixture(scope="module")
def synth_boards(tmp_path_factory) -> Path:
    """A synthetic checkerboard sequence with a known answer (``l2e-studio synth --target checkerboard``)."""
    from l2e_studio.cli import main

    out = tmp_path_factory.mktemp("boards") / "seq"
    assert main(["synth", "--target", "checkerboard", "--seed", "2", "--out", str(out), "--quiet"]) == 0
    return out


def test_synthetic_sequence_end_to_end_with_exclusion_progress_and_cancel(synth_boards):
    import threading

    from l2e_studio.io.cameras import load_seed
    from l2e_studio.scenes import load_scene_folder
    from l2e_studio.target import calibrate_target, find_target
    from l2e_studio.target_verdict import judge_target

    ss = load_scene_folder(synth_boards)
    truth, board = load_seed(synth_boards / "truth.yaml"), load_target(find_target(synth_boards))
    seen = []
    res = calibrate_target(ss.scenes, ss.camera, ss.seed, board, on_progress=seen.append)
    deg, m = truth.error_to(res.extrinsic)
    assert deg < 0.3 and m < 0.01, (deg, m)
    assert ss.seed.error_to(truth)[0] > deg  # better than the seed it started from
    assert {p.stage for p in seen} == {0, 1, 2} and seen[-1].fraction == 1.0
    assert judge_target(res).status == "trusted"
    # the reported sigma covers the true error on every axis (3 sigma)
    dt, dw = res.extrinsic.delta_to(truth)
    z = np.concatenate([dt, dw]) / np.concatenate([res.target.sigma_m, np.radians(res.target.sigma_deg)])
    assert np.all(np.abs(z) < 3), z
    # a frame left out by the user: reported, not used, and the answer changes
    name = ss.scenes[0].name
    res2 = calibrate_target(ss.scenes, ss.camera, ss.seed, board, exclude={name})
    rec = next(f for f in res2.target.frames if f.name == name)
    assert not rec.used and rec.reason == "left out by the user" and rec.detected
    assert res2.extrinsic.error_to(res.extrinsic)[1] > 1e-6
    # cancelled before anything: the seed, marked cancelled
    stop = threading.Event()
    stop.set()
    res3 = calibrate_target(ss.scenes, ss.camera, ss.seed, board, cancel=stop)
    assert res3.cancelled and res3.extrinsic is ss.seed and judge_target(res3).status == "not-trusted"


def test_boards_overrule_a_trusted_targetless_verdict_that_disagrees(synth_boards):
    """with_boards: a trusted (or trusted-rotation) result the boards contradict is not trusted,
    the seed handed back; one they agree with keeps its status, the check listed; a result
    already not trusted keeps its status."""
    from l2e_studio.io.cameras import load_seed
    from l2e_studio.scenes import load_scene_folder
    from l2e_studio.target import detect_frames, find_target
    from l2e_studio.target_verdict import with_boards
    from l2e_studio.verdict import Verdict

    ss = load_scene_folder(synth_boards)
    truth, board = load_seed(synth_boards / "truth.yaml"), load_target(find_target(synth_boards))
    dets = detect_frames(ss.scenes, ss.camera, board)

    def verdict(status, ext):
        return Verdict(status, ext, False, (), (), 0.0)

    wrong = truth.perturbed([0, 0, 0], np.radians([0, 1.5, 0]))
    for status in ("trusted", "trusted-rotation"):
        kept = with_boards(verdict(status, truth), ss.seed, ss.scenes, ss.camera, board, dets)
        assert kept.status == status and kept.checks[-1].name == "boards agree" and kept.checks[-1].passed
        out = with_boards(verdict(status, wrong), ss.seed, ss.scenes, ss.camera, board, dets)
        assert out.status == "not-trusted" and out.kept_seed and out.extrinsic is ss.seed
        said = re.search(r"put the rotation ([0-9.]+) deg", out.reasons[-1])
        assert out.reasons[-1].startswith("boards agree") and 1.1 < float(said.group(1)) < 1.9, out.reasons
    shifted = truth.perturbed([0.08, 0, 0], [0, 0, 0])  # 8 cm off: fails trusted, passes on rotation alone
    assert with_boards(verdict("trusted", shifted), ss.seed, ss.scenes, ss.camera, board, dets).status == "not-trusted"
    assert with_boards(verdict("trusted-rotation", shifted), ss.seed, ss.scenes, ss.camera, board, dets).status \
        == "trusted-rotation"
    seed_kept = with_boards(verdict("not-trusted", ss.seed), ss.seed, ss.scenes, ss.camera, board, dets)
    assert seed_kept.status == "not-trusted" and seed_kept.checks[-1].name == "boards agree"  # listed, for the user
    # under the 0.5 deg floor but past 3.76 of the boards' sigmas: passes from a seed further off (the boards'
    # bias, shared by the seed, is what the floor forgives), fails from a seed at the truth (it moved away)
    near = truth.perturbed([0, 0, 0], np.radians([0.45, 0, 0]))
    far_seed = truth.perturbed([0, 0, 0], np.radians([0, 1.0, 0]))
    assert with_boards(verdict("trusted-rotation", near), far_seed, ss.scenes, ss.camera, board, dets).status \
        == "trusted-rotation"
    away = with_boards(verdict("trusted-rotation", near), truth, ss.scenes, ss.camera, board, dets)
    assert away.status == "not-trusted" and away.extrinsic is truth and "moved away from the boards" in away.reasons[-1], away.checks[-1].detail


def test_calibrate_targetless_with_a_board_in_view_checks_the_boards(synth_boards, tmp_path, capsys):
    """`calibrate --targetless` climbs the score on a board sequence and writes the boards'
    check into the verdict of the result file."""
    import yaml

    from l2e_studio.cli import main

    out = tmp_path / "r.yaml"
    assert main(["calibrate", "--scenes", str(synth_boards), "--targetless", "--out", str(out), "--quiet"]) == 0
    assert "checked against the board" in capsys.readouterr().err
    doc = yaml.safe_load(out.read_text())
    assert doc.get("method", "targetless") != "target" and "target" not in doc
    status, checks = doc["verdict"]["status"], doc["verdict"]["checks"]
    if status != "not-trusted":  # trusted results have met the boards
        assert checks["boards agree"]["passed"] and "the boards alone" in checks["boards agree"]["detail"]


def test_flashing_board_event_maps_are_found_at_the_true_corners():
    """Event maps of a flashing board (bright, speckled, ~100 px wide on a 346x260 sensor):
    the detector finds the board in every frame, the far ones on the board's region upscaled
    (the whole image defeats the detectors there), with corners at the true ones to within the
    speckle's noise (7-8 px squares: ~0.5-1 px RMS, no bias), which the reprojection error reports."""
    from l2e_studio.synth import TargetConfig, make_target_rig, make_target_scene
    from l2e_studio.synth.board import pixel_rays

    config = TargetConfig(n_scenes=20, modality="events", seed=3)
    camera, truth, _ = make_target_rig(config)
    rays = pixel_rays(camera)
    board = Board("checkerboard", config.board.squares, config.board.square_m, config.board.size_m)
    methods, errors = [], []
    for i in range(10, 16):  # far boards of the sequence: the whole-image detectors missed all of them
        image, *_, scene = make_target_scene(config, i, camera, truth, rays)
        det = detect_board(image, board, camera, f"f{i}")
        assert det.found, det.reason
        methods.append(det.method)
        truth_uv, _ = project_points(scene.pose_cam.transform(config.board.inner_corners()), camera)
        d = np.linalg.norm(det.corners[:, None] - truth_uv[None], axis=2).min(axis=1)
        assert det.reprojection_px == pytest.approx(np.sqrt(np.mean(d**2)), rel=0.5)
        errors.append(d)
    assert any("board region" in m for m in methods), methods
    assert np.median(np.concatenate(errors)) < 0.8


def test_reported_sigma_is_not_overconfident_over_many_sequences():
    """30 synthetic sequences of 10 boards (1.5 cm lidar range noise, ring ends known to a 0.2 deg
    step, and each board's camera pose off by its own small error, which the frames share no more
    than real boards do): the solution's error against the truth, per axis, over the sigma it
    reports, must lie within 2 sigma about 92 % of the time (at least 86 % here) and within 3
    sigma nearly always, as Student's t for 9 dof allows. The clustered sandwich alone, over 10
    frames, is narrower."""
    from l2e_studio.target.solve import clustered_covariance

    rng = np.random.default_rng(11)
    z_new, z_cluster = [], []
    for _ in range(30):
        frames = []
        for i, pose in enumerate(board_poses(10, rng)):
            pts, edges = lidar_board(pose, TRUTH, rng, noise=0.015, rows=7)
            seen = pose.perturbed(rng.normal(0, 0.002, 3), np.radians(rng.normal(0, 0.1, 3)))  # the camera's pose error
            frames.append(TargetFrame(f"f{i}", seen, pts, edges, np.radians(0.2)))
        sol = solve(frames, BOARD, closed_form(frames, TRUTH))
        dt, dw = sol.extrinsic.delta_to(TRUTH)
        err = np.concatenate([dt, dw])
        z_new.append(err / np.concatenate([sol.sigma_m, np.radians(sol.sigma_deg)]))
        z_cluster.append(err / np.sqrt(np.diag(clustered_covariance(sol.extrinsic, frames, BOARD))))
    within = lambda z, q: float(np.mean(np.abs(np.array(z)) < q))  # noqa: E731
    # measured: 62 / 89 / 98 % within 1 / 2 / 3 sigma (Student's t with 9 dof: 66 / 92 / 98.5, which
    # the verdict's bound uses); the clustered sandwich alone 53 / 84 / 96 %
    assert within(z_new, 2) >= 0.86 and within(z_new, 3) >= 0.96, (within(z_new, 1), within(z_new, 2), within(z_new, 3))
    assert within(z_new, 1) <= 0.85  # and not so wide that it says nothing
    assert within(z_new, 2) > within(z_cluster, 2) + 0.03


def test_uncertainty_check_holds_the_error_bound_to_the_limits():
    from l2e_studio.target_verdict import ACCURACY_DEG, ACCURACY_M, uncertainty_check

    ok = uncertainty_check(np.full(3, ACCURACY_M / 3), np.full(3, ACCURACY_DEG / 3), 10)
    assert ok.passed and "t with 9 dof" in ok.detail
    # the same sigma from 4 frames: t with 3 dof is 3.18, the bound exceeds the limit
    assert not uncertainty_check(np.full(3, ACCURACY_M / 3), np.full(3, ACCURACY_DEG / 3), 4).passed
    assert not uncertainty_check(np.array([0.001, 0.001, ACCURACY_M]), np.full(3, 0.01), 20).passed
    assert not uncertainty_check(np.full(3, np.nan), np.full(3, 0.01), 20).passed


def test_edge_points_are_the_ring_ends_and_their_step_is_measured():
    """A ring crossing a board 3 m ahead (edges at y = +-0.4 m) at 0.2 deg azimuth steps of random
    phase, with a dropped point: the edge points are each ring's first and last hit (on average
    half a step inside the outline) and the step is the median one, not the gap."""
    from l2e_studio.target.lidar import edge_points

    rng = np.random.default_rng(2)
    step = np.radians(0.2)
    inside = []
    for _ in range(100):
        az = rng.uniform(0, step) + np.arange(-200, 200) * step
        pts = np.column_stack([3.0 * np.ones_like(az), 3.0 * np.tan(az), np.zeros_like(az)])
        pts = pts[np.abs(pts[:, 1]) <= 0.4]
        pts = np.delete(pts, len(pts) // 2, axis=0)  # a dropout
        pts = np.vstack([pts, pts + [0, 0, 0.1]])  # two rings
        rings = np.repeat([0, 1], len(pts) // 2)
        edges, measured = edge_points(pts, rings)
        assert edges.shape == (4, 3) and measured == pytest.approx(step, rel=0.01)
        assert np.allclose(np.sort(edges[:, 1]), np.sort(pts[[0, len(pts) // 2 - 1, len(pts) // 2, -1], 1]))
        inside.append(np.abs(edges[:, 1]).mean() - 0.4)
    assert np.mean(inside) == pytest.approx(-1.5 * step, abs=0.001)  # 3 m x half a step
