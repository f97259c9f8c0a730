"""Synthetic scenes: geometry, sensor models, the written folder, the CLI and the embedded sample."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from l2e_studio.cli import main as cli_main
from l2e_studio.errors import InputError
from l2e_studio.geometry import LIDAR_TO_CAMERA_AXES, Extrinsic, in_image, project_points
from l2e_studio.scenes import load_scene_folder
from l2e_studio.synth import (
    SAMPLE_CONFIG,
    SynthConfig,
    lidar_directions,
    make_rig,
    make_scene,
    read_truth,
    write_dataset,
)
from l2e_studio.synth.world import Box, Decal, cast, surface

ASSETS = Path(__file__).resolve().parents[1] / "assets" / "sample"
SMALL = SynthConfig(n_scenes=3, width=320, height=180, points_per_scan=6000, seed=3)
MEDIUM = SynthConfig(n_scenes=4, width=640, height=360, points_per_scan=20_000, seed=11)


@pytest.fixture(scope="module")
def small_dataset(tmp_path_factory) -> Path:
    return write_dataset(tmp_path_factory.mktemp("synth") / "ds", SMALL)


@pytest.fixture(scope="module")
def medium_scenes():
    camera, truth, seed = make_rig(MEDIUM)
    scenes = [make_scene(MEDIUM, i, truth, camera) for i in range(MEDIUM.n_scenes)]
    return camera, truth, seed, scenes


# --- the world -------------------------------------------------------------------------------------


def test_cast_hits_a_box_at_the_analytic_distance():
    box = Box((5.0, 0.0, 0.0), np.eye(3), (0.5, 1.0, 1.0), base=0.5)
    dirs = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [np.cos(0.1), np.sin(0.1), 0.0]])
    hits = cast([box], np.zeros(3), dirs)
    assert hits.index.tolist() == [0, -1, 0]
    assert hits.t[0] == pytest.approx(4.5)
    assert hits.t[2] == pytest.approx(4.5 / np.cos(0.1))
    assert np.isinf(hits.t[1])


def test_cast_from_inside_the_room_and_occlusion_test():
    room = Box((0, 0, 1.5), np.eye(3), (10, 5, 1.5), base=0.3, inside=True)
    pillar = Box((4, 0, 1.5), np.eye(3), (0.3, 0.3, 1.5), base=0.5)
    origin = np.array([0.0, 0.0, 1.0])
    dirs = np.array([[1.0, 0, 0], [-1.0, 0, 0], [0, 0, -1.0]])
    hits = cast([room, pillar], origin, dirs)
    assert hits.index.tolist() == [1, 0, 0]
    assert hits.t == pytest.approx([3.7, 10.0, 1.0])
    # visibility: something lies before 9 m along +x (the pillar), nothing before 3.5 m
    assert cast([room, pillar], origin, dirs[:1], np.array([9.0])).index[0] == 1
    assert cast([room, pillar], origin, dirs[:1], np.array([3.5])).index[0] == -1


def test_surface_normals_face_the_ray_and_decals_paint_reflectance():
    checker = Decal((0, -1), "checker", (0.0, 0.0), (0.5, 0.5), 0.9, rho2=0.05, period=0.25)
    board = Box((3.0, 0.0, 0.0), np.eye(3), (0.01, 0.5, 0.5), base=0.3, decals=[checker])
    ys = np.linspace(-0.45, 0.45, 37) + 0.0123
    dirs = np.column_stack([np.full(ys.size, 2.99), ys, np.full(ys.size, 0.1)])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    hits = cast([board], np.zeros(3), dirs)
    surf = surface([board], np.zeros(3), dirs, hits)
    assert np.allclose(surf.normals, [-1, 0, 0])
    expected = np.where((np.floor((ys + 0.5) / 0.25) + np.floor(0.6 / 0.25)) % 2 == 0, 0.9, 0.05)
    assert np.allclose(surf.rho, expected)


# --- sensors and scenes ----------------------------------------------------------------------------


def test_rig_is_a_plausible_camera_beside_the_lidar():
    camera, truth, seed = make_rig(SynthConfig())
    assert (camera.width, camera.height) == (1280, 720)
    assert camera.K[0, 0] == pytest.approx(1045, abs=2)
    assert camera.is_distorted
    assert not make_rig(SynthConfig(distortion=False))[0].is_distorted
    # a few degrees of mounting error around the axis swap, camera 5-15 cm from the lidar
    off_deg, _ = truth.error_to(Extrinsic.from_matrix(np.block([[LIDAR_TO_CAMERA_AXES, np.zeros((3, 1))], [0, 0, 0, 1]])))
    assert 0.1 < off_deg < 6.0
    assert 0.05 <= np.linalg.norm(truth.inverse().translation) <= 0.15
    deg, m = seed.error_to(truth)
    assert deg == pytest.approx(2.0) and m == pytest.approx(0.05)


def test_lidar_pattern_covers_the_field_of_view():
    d = lidar_directions(SynthConfig(), np.random.default_rng(0))
    assert abs(d.shape[0] - 75_000) < 500
    az = np.degrees(np.arctan2(d[:, 1], d[:, 0]))
    el = np.degrees(np.arcsin(d[:, 2]))
    assert az.min() < -59 and az.max() > 59 and np.all(np.abs(az) <= 60.1)
    assert el.min() < -12 and el.max() > 12 and np.all(np.abs(el) <= 12.6)


def test_a_spinning_lidar_sees_the_garage_in_its_rings(tmp_path, capsys):
    """``--lidar vlp16``: the scans are 16 rings 2 deg apart over the 120 deg view, 0.2 deg apart
    along a ring; the scenes load and the truth projects them into the camera image."""
    d = lidar_directions(SynthConfig(lidar="vlp16"), np.random.default_rng(0))
    el = np.degrees(np.arcsin(d[:, 2]))
    az = np.degrees(np.arctan2(d[:, 1], d[:, 0]))
    assert np.allclose(np.unique(np.round(el, 6)), np.arange(-15.0, 15.1, 2.0))
    assert az.min() < -59.8 and az.max() > 59.8 and np.all(np.abs(az) <= 60.0)
    assert len(d) == 16 * 600
    out = tmp_path / "vlp"
    args = ["synth", "--out", str(out), "--scenes", "2", "--width", "320", "--camera-image", "--lidar", "vlp16", "--quiet"]
    assert cli_main(args) == 0
    ss = load_scene_folder(out, use_cache=False)
    truth = read_truth(out / "truth.yaml")
    pts = ss.scenes[0].points
    el = np.degrees(np.arctan2(pts[:, 2], np.hypot(pts[:, 0], pts[:, 1])))
    assert len(np.unique(np.round(el))) <= 17 and len(pts) < 9600  # (range noise blurs a ring by a hair)
    uv, front = project_points(truth.transform(pts), ss.camera)
    assert (front & in_image(uv, ss.camera)).sum() > 1000
    assert cli_main(args[:-3] + ["--force", "--lidar", "hdl32", "--points", "5000", "--quiet"]) == 2
    assert "--points" in capsys.readouterr().err


def test_scene_arrays_have_the_documented_shapes_and_ranges(medium_scenes):
    camera, truth, _, scenes = medium_scenes
    for points, intensity, event_map in scenes:
        assert points.dtype == np.float32 and points.shape[1] == 3
        assert intensity.dtype == np.float32 and intensity.shape == (points.shape[0],)
        assert 0.9 * MEDIUM.points_per_scan < points.shape[0] <= MEDIUM.points_per_scan * 1.01
        assert np.all(np.isfinite(points))
        r = np.linalg.norm(points, axis=1)
        assert r.min() > 0.3 and r.max() < MEDIUM.max_range_m
        assert intensity.min() >= 0 and intensity.max() <= 255
        assert np.array_equal(intensity, np.round(intensity))
        assert intensity.std() > 20  # real reflectance contrast, not a constant
        assert event_map.dtype == np.uint8 and event_map.shape == (camera.height, camera.width)
        assert 50 < np.count_nonzero(event_map == 255) < 0.05 * event_map.size  # hot pixels, not a saturated map


def test_events_concentrate_where_the_truth_projects_the_points(medium_scenes):
    camera, truth, seed, scenes = medium_scenes
    rng = np.random.default_rng(0)
    for points, intensity, event_map in scenes:
        m = np.clip(event_map.astype(np.float64), 0, 127)

        def mean_at(ext, shift=0.0):
            uv, front = project_points(ext.transform(points.astype(np.float64)), camera)
            ok = front & in_image(uv, camera, margin=3)
            ij = np.rint(uv[ok] + shift).astype(int)
            return m[ij[:, 1], ij[:, 0]].mean()

        at_truth = mean_at(truth)
        at_random = m[rng.integers(0, camera.height, 5000), rng.integers(0, camera.width, 5000)].mean()
        # the spots are ~3.5 px apart: 2 px off the truth falls between them
        assert at_truth > 1.7 * at_random
        assert at_truth > 1.25 * mean_at(truth, shift=2.0)
        assert at_truth > 1.25 * mean_at(seed)


def test_bright_returns_make_more_events(medium_scenes):
    camera, truth, _, scenes = medium_scenes
    points, intensity, event_map = scenes[0]
    uv, front = project_points(truth.transform(points.astype(np.float64)), camera)
    ok = front & in_image(uv, camera) & (np.linalg.norm(points, axis=1) < 10)
    ij = np.rint(uv[ok]).astype(int)
    blurred = cv2.GaussianBlur(np.clip(event_map, 0, 127).astype(np.float32), (0, 0), 1.5)
    e = blurred[ij[:, 1], ij[:, 0]]
    li = intensity[ok]
    assert e[li > np.percentile(li, 80)].mean() > 1.5 * e[li < np.percentile(li, 20)].mean()


def test_scenes_are_deterministic_and_differ_by_index():
    camera, truth, _ = make_rig(SMALL)
    a = make_scene(SMALL, 1, truth, camera)
    b = make_scene(SMALL, 1, truth, camera)
    c = make_scene(SMALL, 2, truth, camera)
    for x, y in zip(a, b):
        assert np.array_equal(x, y)
    assert a[0].shape != c[0].shape or not np.array_equal(a[0], c[0])
    assert not np.array_equal(a[2], c[2])
    other_truth = make_rig(SynthConfig(seed=SMALL.seed + 1))[1]
    assert other_truth.error_to(truth)[0] > 0.01


def test_mi_is_higher_at_the_truth_than_at_the_seed(medium_scenes):
    from l2e_studio.objective import SceneStack
    from l2e_studio.scenes import Scene

    camera, truth, seed, scenes = medium_scenes
    stack = SceneStack.build([Scene(f"s{i}", p, l, m.astype(np.float32)) for i, (p, l, m) in enumerate(scenes)],
                             camera, 5.0, truth, 0.5, 20.0)
    mi_truth, _ = stack.mi(truth, per_scene=False)
    assert mi_truth > stack.mi(seed, per_scene=False)[0] + 0.05
    for d in ([0.02, 0, 0, 0, 0, 0], [0, 0, 0, 0, np.radians(0.5), 0]):
        assert mi_truth > stack.mi(truth.perturbed(np.array(d[:3]), np.array(d[3:])), per_scene=False)[0]


# --- the written folder -----------------------------------------------------------------------------


def test_written_folder_round_trips_through_the_reference_format(small_dataset):
    camera, truth, seed = make_rig(SMALL)
    names = [f"scene_{i:03d}" for i in range(SMALL.n_scenes)]
    assert sorted(p.stem for p in (small_dataset / "event").glob("*.png")) == names
    assert sorted(p.stem for p in (small_dataset / "lidar").glob("*.txt")) == names
    for rig_file in ("config/config.json", "camera.yaml"):
        ss = load_scene_folder(small_dataset, camera_file=small_dataset / rig_file, use_cache=False)
        assert ss.names == names and not ss.failures
        assert np.allclose(ss.camera.K, camera.K) and np.allclose(ss.camera.D[:5], camera.D[:5])
        assert (ss.camera.width, ss.camera.height) == (SMALL.width, SMALL.height)
        deg, m = ss.seed.error_to(seed)
        assert deg < 1e-6 and m < 1e-9
        for i, scene in enumerate(ss.scenes):
            points, intensity, event_map = make_scene(SMALL, i, truth, camera)
            assert np.allclose(scene.points, points, atol=6e-5)
            assert np.array_equal(scene.intensity, intensity)
            assert np.array_equal(scene.event_map, event_map.astype(np.float32))


def test_config_json_has_the_reference_keys(small_dataset):
    cam = json.loads((small_dataset / "config" / "config.json").read_text())["cam"]
    assert set(cam) >= {"K", "D", "x", "y", "z", "Rodrigues", "rx", "ry", "rz"}
    assert np.asarray(cam["K"]).shape == (3, 3) and len(cam["D"]) == 5
    seed = make_rig(SMALL)[2]
    assert np.allclose(Extrinsic.from_rpy([cam["rx"], cam["ry"], cam["rz"]], [0, 0, 0]).R, seed.R, atol=1e-9)


def test_truth_yaml_matches_the_rig(small_dataset):
    _, truth, seed = make_rig(SMALL)
    data = yaml.safe_load((small_dataset / "truth.yaml").read_text())
    assert np.allclose(data["T_cam_lidar"], truth.matrix)
    assert np.allclose(data["translation"], truth.translation)
    assert np.allclose(data["rotvec"], truth.rotvec)
    read = read_truth(small_dataset / "truth.yaml")
    assert read.error_to(truth)[0] < 1e-9 and read.error_to(truth)[1] < 1e-12
    assert data["seed_error"]["rotation_deg"] == pytest.approx(SMALL.seed_error_deg)


def test_read_truth_rejects_bad_files(tmp_path):
    with pytest.raises(InputError, match="no truth file"):
        read_truth(tmp_path / "missing.yaml")
    bad = tmp_path / "truth.yaml"
    bad.write_text("T_cam_lidar: [[1, 2], [3, 4]]\n")
    with pytest.raises(InputError, match="truth.yaml"):
        read_truth(bad)


def test_write_dataset_refuses_a_non_empty_folder(tmp_path):
    (tmp_path / "keep.txt").write_text("mine")
    with pytest.raises(InputError, match="not empty"):
        write_dataset(tmp_path, SMALL)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.txt"]


# --- the command ----------------------------------------------------------------------------------------


def test_cli_refuses_non_empty_dir_then_force_replaces_old_scenes(tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("keep me")
    args = ["synth", "--out", str(out), "--scenes", "2", "--width", "160", "--points", "2000", "--quiet"]
    assert cli_main(args) == 2
    assert "not empty" in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]

    assert cli_main(args + ["--force", "--scenes", "3"]) == 0
    assert len(list((out / "event").glob("*.png"))) == 3
    assert cli_main(args + ["--force", "--seed-error-deg", "1", "--seed-error-m", "0.02"]) == 0
    assert sorted(p.name for p in (out / "lidar").iterdir()) == ["scene_000.txt", "scene_001.txt"]
    assert (out / "notes.txt").read_text() == "keep me"
    assert cv2.imread(str(out / "event" / "scene_000.png"), cv2.IMREAD_UNCHANGED).shape == (90, 160)
    ss = load_scene_folder(out, use_cache=False)
    deg, m = ss.seed.error_to(read_truth(out / "truth.yaml"))
    assert deg == pytest.approx(1.0) and m == pytest.approx(0.02)


def test_cli_rejects_impossible_sizes(tmp_path, capsys):
    assert cli_main(["synth", "--out", str(tmp_path / "x"), "--scenes", "0", "--quiet"]) == 2
    assert "error" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


# --- the embedded sample -----------------------------------------------------------------------------------


def test_embedded_sample_loads_and_is_small():
    if not (ASSETS / "truth.yaml").is_file():
        pytest.skip("assets/sample not generated")
    files = [p for p in ASSETS.rglob("*") if p.is_file() and not any(part.startswith(".") for part in p.relative_to(ASSETS).parts)]
    size = sum(p.stat().st_size for p in files)
    assert size < 15e6
    ss = load_scene_folder(ASSETS, use_cache=False)
    assert len(ss.scenes) == SAMPLE_CONFIG.n_scenes and not ss.failures
    assert (ss.camera.width, ss.camera.height) == (SAMPLE_CONFIG.width, SAMPLE_CONFIG.height)
    deg, m = ss.seed.error_to(read_truth(ASSETS / "truth.yaml"))
    assert deg == pytest.approx(SAMPLE_CONFIG.seed_error_deg, abs=1e-6)
    assert m == pytest.approx(SAMPLE_CONFIG.seed_error_m, abs=1e-9)
