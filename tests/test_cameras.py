"""Camera/rig files: every sample config parses to the same camera; seeds from every form."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from l2e_studio.errors import InputError
from l2e_studio.geometry import Extrinsic, project_points
from l2e_studio.io.cameras import load_rig, load_seed

SAMPLES = Path(__file__).resolve().parents[1] / "sample_configs"
K_SAMPLE = np.array([[1045.0, 0, 640.5], [0, 1045.0, 360.5], [0, 0, 1]])
D_SAMPLE = np.array([-0.12, 0.08, 0.0005, -0.0003, 0.0])


@pytest.mark.parametrize(
    "name, fmt, size",
    [
        ("camera.yaml", "camera.yaml", (1280, 720)),
        ("config.json", "reference config.json", (None, None)),
        ("opencv_camera.yaml", "OpenCV YAML", (1280, 720)),
        ("kalibr_camchain.yaml", "Kalibr camchain YAML", (1280, 720)),
        ("ros_camera_info.yaml", "ROS camera_info YAML", (1280, 720)),
    ],
)
def test_sample_configs_agree(name: str, fmt: str, size) -> None:
    rig = load_rig(SAMPLES / name)
    assert rig.format == fmt
    assert (rig.width, rig.height) == size
    np.testing.assert_allclose(rig.K, K_SAMPLE)
    np.testing.assert_allclose(rig.D, D_SAMPLE)
    cam = rig.camera(1280, 720)
    assert cam.model == "radtan" and cam.size == (1280, 720)


def test_kalibr_equidistant_projects_like_fisheye() -> None:
    cv2 = pytest.importorskip("cv2")
    rig = load_rig(SAMPLES / "kalibr_camchain_equi.yaml")
    assert rig.model == "equidistant" and rig.D.size == 4
    cam = rig.camera()
    pts = np.array([[0.3, -0.2, 1.0], [-1.0, 0.5, 1.5], [0.1, 0.1, 3.0]])
    uv, front = project_points(pts, cam)
    ref, _ = cv2.fisheye.projectPoints(pts.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), cam.K, cam.D)
    assert front.all()
    np.testing.assert_allclose(uv, ref.reshape(-1, 2), atol=1e-9)


def test_seeds_from_every_sample_agree() -> None:
    ref = load_seed(SAMPLES / "seed_matrix.txt")
    np.testing.assert_allclose(ref.matrix[:3, :3], [[0, -1, 0], [0, 0, -1], [1, 0, 0]], atol=1e-12)
    for name in ("camera.yaml", "config.json", "seed.yaml"):
        deg, m = load_seed(SAMPLES / name).error_to(ref)
        assert deg < 1e-6 and m < 1e-9, name
    assert load_rig(SAMPLES / "camera.yaml").seed is not None


def test_reference_config_rpy_fallback(tmp_path: Path) -> None:
    cfg = json.loads((SAMPLES / "config.json").read_text())
    del cfg["cam"]["Rodrigues"]
    (tmp_path / "config.json").write_text(json.dumps(cfg))
    rig = load_rig(tmp_path / "config.json")
    deg, _ = rig.seed.error_to(load_seed(SAMPLES / "seed_matrix.txt"))
    assert deg < 1e-6
    with pytest.raises(InputError, match="image size"):
        rig.camera()


def test_seed_forms(tmp_path: Path) -> None:
    truth = Extrinsic(np.array([0.1, -0.2, 0.3]), np.array([0.5, -0.1, 0.05]))
    np.save(tmp_path / "T.npy", truth.matrix)
    (tmp_path / "T.json").write_text(json.dumps(truth.matrix.tolist()))
    (tmp_path / "result.yaml").write_text(yaml.safe_dump({"T_cam_lidar": truth.matrix.tolist(), "mi": 1.0}))
    (tmp_path / "q.json").write_text(json.dumps({"translation": truth.translation.tolist(),
                                                 "quaternion_xyzw": truth.quaternion_xyzw.tolist()}))
    (tmp_path / "rpy.yaml").write_text(yaml.safe_dump({"seed": {"translation": truth.translation.tolist(),
                                                                "rpy_deg": truth.rpy().tolist()}}))
    (tmp_path / "T34.txt").write_text("\n".join(" ".join(map(str, r)) for r in truth.matrix[:3]))
    kalibr = yaml.safe_load((SAMPLES / "kalibr_camchain.yaml").read_text())
    kalibr["cam0"]["T_cam_lidar"] = truth.matrix.tolist()
    (tmp_path / "camchain.yaml").write_text(yaml.safe_dump(kalibr))
    for name in ("T.npy", "T.json", "result.yaml", "q.json", "rpy.yaml", "T34.txt", "camchain.yaml"):
        deg, m = load_seed(tmp_path / name).error_to(truth)
        assert deg < 1e-6 and m < 1e-9, name


def test_opencalib_formats(tmp_path: Path) -> None:
    (tmp_path / "calib.txt").write_text(
        "K: 2000 0 960 0 2000 600 0 0 1\nD: -0.1 0.1 0.001 0.002\nT: 0 -1 0 0.1 0 0 -1 0.2 1 0 0 0.3\n")
    rig = load_rig(tmp_path / "calib.txt")
    assert rig.format == "OpenCalib calib.txt" and rig.K[0, 2] == 960 and rig.D.size == 4
    np.testing.assert_allclose(rig.seed.translation, [0.1, 0.2, 0.3])
    np.testing.assert_allclose(load_seed(tmp_path / "calib.txt").translation, [0.1, 0.2, 0.3])


@pytest.mark.parametrize(
    "name, text, message",
    [
        ("nok.json", '{"cam": {"D": [0, 0, 0, 0, 0]}}', "no cam.K"),
        ("shape.json", '{"cam": {"K": [[1, 0], [0, 1]]}}', "must be 3x3"),
        ("nan.yaml", "camera:\n  K: [[.nan, 0, 1], [0, 1, 1], [0, 0, 1]]\n", "NaN"),
        ("neg.yaml", "camera:\n  K: [[-5, 0, 1], [0, 1, 1], [0, 0, 1]]\n", "non-positive"),
        ("model.yaml", "camera:\n  model: omni\n  K: [[5, 0, 1], [0, 5, 1], [0, 0, 1]]\n", "unknown distortion model"),
        ("dist.yaml", "camera:\n  K: [[5, 0, 1], [0, 5, 1], [0, 0, 1]]\n  D: [1, 2, 3]\n", "4, 5 or 8"),
        ("other.yaml", "foo: 1\nbar: [1, 2]\n", "unknown camera file format"),
        ("broken.json", '{"cam": ', "invalid JSON"),
        ("broken.yaml", "camera: [unclosed\n", "invalid YAML"),
        ("missing.yaml", None, "not found"),
    ],
)
def test_bad_rig_files(tmp_path: Path, name: str, text: str | None, message: str) -> None:
    path = tmp_path / name
    if text is not None:
        path.write_text(text)
    with pytest.raises(InputError, match=message) as info:
        load_rig(path)
    assert str(path) in str(info.value)


def test_bad_seed_files(tmp_path: Path) -> None:
    (tmp_path / "five.txt").write_text("1 2 3 4 5")
    with pytest.raises(InputError, match="12 or 16 numbers"):
        load_seed(tmp_path / "five.txt")
    (tmp_path / "scaled.txt").write_text("2 0 0 0  0 2 0 0  0 0 2 0  0 0 0 1")
    with pytest.raises(InputError, match="determinant"):
        load_seed(tmp_path / "scaled.txt")
    (tmp_path / "norot.yaml").write_text("translation: [0, 0, 0]\n")
    with pytest.raises(InputError, match="no rotvec"):
        load_seed(tmp_path / "norot.yaml")
    with pytest.raises(InputError, match="no seed"):
        load_seed(SAMPLES / "ros_camera_info.yaml")


def _kitti_numbers(rng):
    """Made-up KITTI-like matrices: rectified P0..P3 (a stereo baseline in the 4th column),
    a lidar -> camera-0 transform and a small rectifying rotation."""
    from scipy.spatial.transform import Rotation

    K = np.array([[707.0, 0, 601.9], [0, 707.0, 183.1], [0, 0, 1]])
    P = {f"P{i}": K @ np.hstack([np.eye(3), np.array([[b], [0.002 * i], [0.001 * i]])])
         for i, b in enumerate((0.0, -0.54, 0.06, -0.47))}
    axes = np.array([[0.0, -1, 0], [0, 0, -1], [1, 0, 0]])  # lidar x forward, y left, z up -> camera z, -x, -y
    R_lc = Rotation.from_rotvec(rng.normal(0, 0.01, 3)).as_matrix() @ axes
    Tr = np.hstack([R_lc, np.array([[-0.004], [-0.076], [-0.27]])])
    R0 = Rotation.from_rotvec(rng.normal(0, 0.005, 3)).as_matrix()
    return P, Tr, R0


@pytest.mark.parametrize("layout", ["odometry", "object"])
def test_kitti_calib_txt_projects_like_its_matrices(tmp_path, layout):
    """A KITTI calib.txt read as camera and seed projects lidar points exactly where
    P2 (R0_rect) Tr puts them, and names a missing line."""
    from l2e_studio.geometry import project_points
    from l2e_studio.io.cameras import load_rig, load_seed

    rng = np.random.default_rng(7)
    P, Tr, R0 = _kitti_numbers(rng)
    fmt = lambda a: " ".join(f"{v:.12e}" for v in np.ravel(a))  # noqa: E731
    lines = [f"{k}: {fmt(v)}" for k, v in P.items()]
    if layout == "odometry":
        lines.append(f"Tr: {fmt(Tr)}")
        R0 = np.eye(3)
    else:
        lines += [f"R0_rect: {fmt(R0)}", f"Tr_velo_to_cam: {fmt(Tr)}", f"Tr_imu_to_velo: {fmt(Tr)}"]
    path = tmp_path / "calib.txt"
    path.write_text("\n".join(lines) + "\n")
    rig = load_rig(path)
    cam, seed = rig.camera(1242, 375), load_seed(path)
    assert rig.format == "KITTI calib.txt (P2)" and np.allclose(cam.D, 0) and rig.seed is not None
    assert np.allclose(rig.seed.matrix, seed.matrix)
    pts = np.column_stack([rng.uniform(5, 40, 200), rng.uniform(-10, 10, 200), rng.uniform(-2, 1, 200)])
    T = np.eye(4)
    T[:3] = Tr
    R0h = np.eye(4)
    R0h[:3, :3] = R0
    h = P["P2"] @ R0h @ T @ np.vstack([pts.T, np.ones(len(pts))])
    want = (h[:2] / h[2]).T
    got, _ = project_points(seed.transform(pts), cam)
    assert np.isfinite(got).all() and np.abs(got - want).max() < 1e-6
    # another camera by name; a missing line is one clear error
    assert not np.allclose(load_rig(path, camera="P3").seed.translation, seed.translation)
    path.write_text("\n".join(line for line in lines if not line.startswith("P2")) + "\nP1b: 1 2\n")
    with pytest.raises(InputError, match="calib.txt.*no 'P2:' line|no 'P2:' line"):
        load_rig(path)
