"""Synthetic checkerboard sequences: the rendered board, the lidar's board points, the written folder."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from l2e_studio.cli import main as cli_main
from l2e_studio.cli.synth import MODALITIES as CLI_MODALITIES
from l2e_studio.geometry import project_points
from l2e_studio.io.lidar import load_lidar
from l2e_studio.scenes import load_scene_folder
from l2e_studio.synth import (
    Board,
    TargetConfig,
    make_target_rig,
    make_target_scene,
    read_board_poses,
    read_truth,
)
from l2e_studio.synth.board import pixel_rays, render_board
from l2e_studio.synth.board_views import MODALITIES

SB_FLAGS = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY


def _scenes(config: TargetConfig):
    camera, truth, _ = make_target_rig(config)
    rays = pixel_rays(camera)
    return camera, truth, [make_target_scene(config, i, camera, truth, rays) for i in range(config.n_scenes)]


@pytest.fixture(scope="module", params=["radtan", "equidistant"])
def frame_scenes(request):
    return _scenes(TargetConfig(n_scenes=4, modality="frame", lens=request.param, width=800, height=450, seed=5))


def test_board_geometry_matches_target_yaml_conventions():
    board = Board((10, 7), 0.068, (0.8, 0.6))
    corners = board.inner_corners()
    assert corners.shape == (9 * 6, 3)
    assert np.allclose(corners.mean(axis=0), 0.0)  # the pattern is centred on the outline
    assert corners[1, 0] - corners[0, 0] == pytest.approx(0.068)
    assert np.ptp(board.outline()[:, 0]) == pytest.approx(0.8)
    # the top-left square is black, the margin white, off the board NaN
    assert board.albedo(np.array([-0.34 + 0.01]), np.array([-0.238 + 0.01]))[0] < 0.1
    assert board.albedo(np.array([0.39]), np.array([0.0]))[0] > 0.8
    assert np.isnan(board.albedo(np.array([0.41]), np.array([0.0]))[0])
    assert board.to_yaml() == {"target": {"kind": "checkerboard", "squares": [10, 7], "square_m": 0.068,
                                          "size_m": [0.8, 0.6]}}
    with pytest.raises(ValueError, match="smaller than the pattern"):
        Board((10, 7), 0.1, (0.8, 0.6))


def test_pixel_rays_undo_the_lens_exactly():
    for lens in ("radtan", "equidistant"):
        camera, _, _ = make_target_rig(TargetConfig(lens=lens, width=320, height=180))
        rays = pixel_rays(camera)
        uv, _ = project_points(rays.reshape(-1, 3), camera)
        v, u = np.mgrid[0:camera.height, 0:camera.width]
        assert np.max(np.hypot(uv[:, 0] - u.ravel(), uv[:, 1] - v.ravel())) < 1e-6


def test_rendering_is_anti_aliased_partial_coverage_at_the_outline():
    camera, truth, _ = make_target_rig(TargetConfig(width=320, height=180, seed=2))
    from l2e_studio.geometry import Extrinsic

    pose = Extrinsic(np.array([0.0, 0.3, 0.1]), np.array([0.0, 0.0, 2.0]))
    image, cover = render_board(Board(), camera, pixel_rays(camera), pose, np.zeros((180, 320)))
    partial = (cover > 0.05) & (cover < 0.95)
    assert partial.sum() > 50  # the outline's pixels are partly covered, not a hard step
    grey = image[(cover == 1.0)]
    assert np.count_nonzero((grey > 0.1) & (grey < 0.8)) > 100  # square edges blend too


def test_frame_images_hold_a_board_found_by_opencv_at_the_true_corners(frame_scenes):
    camera, _, scenes = frame_scenes
    board = Board()
    errors = []
    for image, *_, scene in scenes:
        ok, corners = cv2.findChessboardCornersSB(image, (9, 6), flags=SB_FLAGS)
        assert ok
        truth_uv, _ = project_points(scene.pose_cam.transform(board.inner_corners()), camera)
        d = np.linalg.norm(corners.reshape(-1, 2)[:, None] - truth_uv[None], axis=2).min(axis=1)
        errors.append(d)
    errors = np.concatenate(errors)
    # sub-pixel agreement with the true corners, with the noise the rendering leaves (not zero)
    assert np.median(errors) < 0.25
    assert np.max(errors) < 1.0
    assert np.median(errors) > 0.005


def test_board_orientations_fan_out_so_every_axis_is_pinned():
    config = TargetConfig(n_scenes=10, modality="e2vid", seed=1)
    camera, truth, scenes = _scenes(config)
    normals = np.array([s.pose_cam.R[:, 2] for *_, s in scenes])
    # normals spread around the view axis: the scatter matrix of their directions has no thin axis
    spread = np.linalg.svd(normals - normals.mean(axis=0), compute_uv=False)
    assert spread[1] > 0.4 * spread[0]  # tilted about two independent in-plane axes
    tilts = np.degrees(np.arccos([abs(n @ (s.pose_cam.translation / np.linalg.norm(s.pose_cam.translation)))
                                  for n, (*_, s) in zip(normals, scenes)]))
    assert tilts.min() > 5 and tilts.max() < 55
    distances = [np.linalg.norm(s.pose_cam.translation) for *_, s in scenes]
    assert 1.5 <= min(distances) and max(distances) <= 4.0 and np.ptp(distances) > 1.5
    # E2VID-like images: most boards still found by OpenCV (blur, noise, low contrast cost some)
    found = sum(bool(cv2.findChessboardCornersSB(img, (9, 6), flags=SB_FLAGS)[0]) for img, *_ in scenes)
    assert found >= 5


def test_lidar_board_points_lie_on_the_true_plane_within_the_range_noise():
    config = TargetConfig(n_scenes=3, modality="e2vid", seed=4, range_noise_m=0.015)
    camera, truth, scenes = _scenes(config)
    board = config.board
    for _, points, _, ring, on_board, scene in scenes:
        local = (points[on_board].astype(np.float64) - scene.pose_lidar.translation) @ scene.pose_lidar.R
        assert on_board.sum() > 40 and np.unique(ring[on_board]).size >= 3
        assert 0.4 * 0.015 < np.std(local[:, 2]) < 1.2 * 0.015  # range noise, seen along the normal
        assert abs(np.mean(local[:, 2])) < 0.006
        assert np.all(np.abs(local[:, 0]) < board.size_m[0] / 2 + 0.05)
        assert np.all(np.abs(local[:, 1]) < board.size_m[1] / 2 + 0.05)
        # the rest of the scan (room, holder) is off the plane's patch
        others = (points[~on_board].astype(np.float64) - scene.pose_lidar.translation) @ scene.pose_lidar.R
        patch = (np.abs(others[:, 0]) < 0.3) & (np.abs(others[:, 1]) < 0.2)
        assert np.count_nonzero(patch & (np.abs(others[:, 2]) < 0.005)) < 0.1 * on_board.sum()


@pytest.mark.parametrize("lidar, rings, spacing_deg", [("hdl32", 32, 1.33), ("hdl64", 64, 0.43), ("os128", 128, 0.35)])
def test_other_lidars_cross_the_board_with_their_own_rings(lidar, rings, spacing_deg):
    """``TargetConfig(lidar=...)``: the board is crossed by that lidar's rings, as many as its
    beam spacing gives over the board's height at its distance (within a factor of two: the board
    is tilted and may stand partly above an HDL-64E's top beam), never the VLP-16's 16."""
    config = TargetConfig(n_scenes=2, modality="e2vid", seed=4, lidar=lidar)
    camera, truth, scenes = _scenes(config)
    for _, points, _, ring, on_board, scene in scenes:
        assert ring.max() < rings and np.unique(ring).size > 16
        crossing = np.unique(ring[on_board]).size
        expected = np.degrees(config.board.size_m[1] / np.linalg.norm(scene.pose_lidar.translation)) / spacing_deg
        assert 3 <= crossing <= 2 * expected + 2, (crossing, expected)
    with pytest.raises(ValueError, match="lidar must be one of"):
        TargetConfig(lidar="hdl16")


@pytest.mark.parametrize("modality", ["events", "events-moving"])
def test_event_maps_fire_on_the_board_and_stay_quiet_elsewhere(modality):
    config = TargetConfig(n_scenes=1, modality=modality, seed=6)
    camera, truth, [(image, *_, scene)] = _scenes(config)
    rays = pixel_rays(camera)
    _, cover = render_board(config.board, camera, rays, scene.pose_cam, np.zeros((camera.height, camera.width)))
    inside = cover > 0.99
    outside = cv2.dilate((cover > 0).astype(np.uint8), np.ones((9, 9), np.uint8)) == 0
    assert image.dtype == np.uint8 and image.shape == (260, 346)
    assert np.mean(image[inside]) > 5 * np.median(image[outside]) + 5


def test_cli_writes_a_loadable_board_folder(tmp_path: Path, capsys):
    out = tmp_path / "boards"
    assert cli_main(["synth", "--target", "checkerboard", "--modality", "e2vid", "--scenes", "2", "--seed", "3",
                     "--out", str(out), "--quiet"]) == 0
    scene_set = load_scene_folder(out)
    assert scene_set.names == ["scene_000", "scene_001"] and not scene_set.failures
    assert scene_set.camera.width == 346 and scene_set.camera.height == 260
    assert all(len(s.points) > 20_000 for s in scene_set.scenes)  # a full VLP-16 revolution
    config = TargetConfig(n_scenes=2, modality="e2vid", seed=3)
    camera, truth, seed = make_target_rig(config)
    assert read_truth(out / "truth.yaml").error_to(truth)[1] < 1e-9
    deg, m = scene_set.seed.error_to(truth)
    assert deg == pytest.approx(2.0, abs=1e-6) and m == pytest.approx(0.05, abs=1e-6)
    assert yaml.safe_load((out / "target.yaml").read_text())["target"]["squares"] == [10, 7]
    poses = read_board_poses(out / "truth.yaml")
    assert sorted(poses) == ["scene_000", "scene_001"]
    header = (out / "lidar" / "scene_000.pcd").read_bytes()[:400].decode("ascii", "replace")
    assert "FIELDS x y z intensity ring" in header
    scan = load_lidar(out / "lidar" / "scene_000.pcd")
    # the written board points sit on the written board pose
    pose_lidar = truth.inverse().compose(poses["scene_000"])
    local = (scan.points.astype(np.float64) - pose_lidar.translation) @ pose_lidar.R
    on = (np.abs(local[:, 2]) < 0.05) & (np.abs(local[:, 0]) < 0.4) & (np.abs(local[:, 1]) < 0.3)
    assert on.sum() > 40


def test_cli_refuses_garage_options_with_target(tmp_path: Path, capsys):
    assert cli_main(["synth", "--target", "checkerboard", "--realism", "--out", str(tmp_path / "x")]) == 2
    assert "--realism shapes the garage scenes" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()
    assert cli_main(["synth", "--modality", "e2vid", "--out", str(tmp_path / "y")]) == 2
    assert "--modality needs --target checkerboard" in capsys.readouterr().err
    assert CLI_MODALITIES == MODALITIES
