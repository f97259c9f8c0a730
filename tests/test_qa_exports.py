"""Exports of an extrinsic: every format labelled with its direction and read back by load_seed."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from l2e_studio.cli import main as cli_main
from l2e_studio.errors import InputError
from l2e_studio.export import EXPORT_FORMATS, export_text, write_result
from l2e_studio.geometry import Extrinsic
from l2e_studio.io.cameras import load_seed
from test_export import CAM, fake_result

EXTRINSICS = [
    Extrinsic([1.2, -1.2, 1.2], [0.05, -0.1, 0.08]),  # a forward-looking rig (near gimbal lock in rpy)
    Extrinsic([0.3, -2.0, 0.7], [-1.25, 0.4, 2.5]),
]


@pytest.mark.parametrize("fmt", list(EXPORT_FORMATS))
@pytest.mark.parametrize("k", range(len(EXTRINSICS)))
def test_every_export_names_its_direction_and_reads_back_as_a_seed(tmp_path, fmt, k):
    ext = EXTRINSICS[k]
    text = export_text(ext, fmt)
    assert "T_cam_lidar" in text and "camera" in text  # the direction is written in the file
    path = tmp_path / f"T{EXPORT_FORMATS[fmt]}"
    path.write_text(text)
    back = load_seed(path)
    deg, m = ext.error_to(back)
    assert deg < 1e-6 and m < 1e-8
    assert np.allclose(back.matrix, ext.matrix, atol=1e-8)


def test_ros2_line_uses_named_arguments_and_ros1_positional():
    ext = EXTRINSICS[0]
    ros2 = [ln for ln in export_text(ext, "ros2").splitlines() if not ln.startswith("#")][0]
    for flag in ("--x", "--y", "--z", "--qx", "--qy", "--qz", "--qw", "--frame-id camera", "--child-frame-id lidar"):
        assert flag in ros2
    ros1 = [ln for ln in export_text(ext, "ros1").splitlines() if not ln.startswith("#")][0].split()
    nums = [float(v) for v in ros1[3:10]]
    assert np.allclose(nums[:3], ext.translation) and np.allclose(nums[3:], ext.quaternion_xyzw, atol=1e-8)
    assert ros1[10:] == ["camera", "lidar"]


def test_a_transform_published_from_the_lidar_frame_is_inverted(tmp_path):
    ext = EXTRINSICS[1]
    inv = ext.inverse()
    t, q = inv.translation, inv.quaternion_xyzw
    path = tmp_path / "tf.txt"
    path.write_text("rosrun tf2_ros static_transform_publisher " + " ".join(f"{v:.12f}" for v in [*t, *q]) + " velodyne camera\n")
    assert ext.error_to(load_seed(path))[0] < 1e-6
    # tf's older form: x y z yaw pitch roll frame child period
    ypr = ext.rpy(degrees=False)[::-1]
    path.write_text("rosrun tf static_transform_publisher " + " ".join(f"{v:.12f}" for v in [*ext.translation, *ypr]) + " cam lidar 100\n")
    assert ext.error_to(load_seed(path))[0] < 1e-6


def test_a_result_file_quoting_the_ros_line_still_reads_as_a_result(tmp_path):
    path, _ = write_result(tmp_path / "r.yaml", fake_result(), CAM)
    assert "static_transform_publisher" in path.read_text()
    assert np.allclose(load_seed(path).matrix, fake_result().extrinsic.matrix, atol=1e-9)


def test_export_cli_writes_each_format_atomically_and_they_read_back(tmp_path, capsys):
    res_path, _ = write_result(tmp_path / "r.yaml", fake_result(), CAM)
    out = tmp_path / "exports"
    assert cli_main(["export", str(res_path), "--out", str(out)]) == 0
    files = sorted(p.name for p in out.iterdir())
    assert files == sorted(f"T_cam_lidar{s}" for s in EXPORT_FORMATS.values())
    for p in out.iterdir():
        assert fake_result().extrinsic.error_to(load_seed(p))[0] < 1e-6
    full = yaml.safe_load((out / "T_cam_lidar.yaml").read_text())
    assert full["score"]["result"] == 0.41 and "direction" in full  # the yaml export is the whole result


def test_export_cli_unknown_format_is_one_line_exit_2_and_writes_nothing(tmp_path, capsys):
    res_path, _ = write_result(tmp_path / "r.yaml", fake_result(), CAM)
    out = tmp_path / "exports"
    assert cli_main(["export", str(res_path), "--format", "ros2", "--format", "bogus", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown export format 'bogus'" in err[0]
    assert not out.exists()


def test_export_text_rejects_unknown_formats():
    with pytest.raises(ValueError, match="unknown export format"):
        export_text(EXTRINSICS[0], "pdf")


def test_a_broken_urdf_is_an_input_error(tmp_path):
    p = tmp_path / "j.urdf"
    p.write_text('<joint name="x" type="fixed">\n  <origin xyz="1 2" rpy="0 0 0"/>\n</joint>\n')
    with pytest.raises(InputError):
        load_seed(p)
