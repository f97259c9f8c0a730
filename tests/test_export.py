"""Result files: content, formats, atomic writes and backups."""

import json
import os

import numpy as np
import pytest
import yaml

from l2e_studio.calibrate import CalibrationResult, CalibrationSettings, Stage
from l2e_studio.camera import CameraModel
from l2e_studio.atomic import atomic_write_bytes
from l2e_studio.export import result_to_dict, write_result
from l2e_studio.geometry import Extrinsic
from l2e_studio.io.cameras import load_seed


def fake_result() -> CalibrationResult:
    """A result as calibrate() returns it (the numbers are arbitrary but consistent)."""
    seed = Extrinsic([1.2, -1.2, 1.2], [0.05, -0.1, 0.08])
    ext = seed.perturbed([0.01, -0.02, 0.005], np.radians([0.5, -1.0, 0.3]))
    return CalibrationResult(
        extrinsic=ext, seed=seed, settings=CalibrationSettings(), scene_names=["a", "b"],
        score_seed=0.30, score_result=0.41, score_seed_per_scene=np.array([0.25, 0.35]),
        score_result_per_scene=np.array([0.38, np.nan]), evaluations=57, seconds=1.234,
        history=[(1, 0.3, 0)], message="ok", stages=(Stage(20.0, 150_000, 0.25), Stage(2.0)),
    )


CAM = CameraModel(np.array([[500.0, 0, 320], [0, 500, 180], [0, 0, 1]]), 640, 360)


@pytest.mark.parametrize("name", ["result.yaml", "result.json"])
def test_result_file_holds_every_representation_and_reads_back_as_a_seed(tmp_path, name):
    res = fake_result()
    path, backup = write_result(tmp_path / name, res, CAM, tmp_path)
    assert backup is None
    text = path.read_text()
    data = json.loads(text) if name.endswith(".json") else yaml.safe_load(text)
    T = np.array(data["T_cam_lidar"])
    assert np.allclose(T, res.extrinsic.matrix, atol=1e-9)
    assert np.allclose(np.array(data["T_lidar_cam"]) @ T, np.eye(4), atol=1e-9)
    assert np.allclose(Extrinsic.from_quaternion(data["quaternion_xyzw"], data["translation"]).matrix, T, atol=1e-9)
    assert np.allclose(Extrinsic.from_rpy(data["rpy_deg"], data["translation"]).matrix, T, atol=1e-9)
    assert np.allclose(Extrinsic(data["rotvec"], data["translation"]).matrix, T, atol=1e-9)
    assert np.allclose(data["seed"]["T_cam_lidar"], res.seed.matrix, atol=1e-9)
    assert data["bounds"] == {"translation_m": 0.2, "rotation_deg": 10.0}
    assert data["optimiser"]["method"] == "SLSQP" and len(data["optimiser"]["stages"]) == 2
    assert data["score"]["seed"] == 0.30 and data["score"]["result"] == 0.41
    assert data["score"]["per_scene"] == [{"scene": "a", "seed": 0.25, "result": 0.38}, {"scene": "b", "seed": 0.35, "result": None}]
    assert data["evaluations"] == 57 and data["optimisation_seconds"] == pytest.approx(1.234)
    assert data["scenes"] == ["a", "b"] and data["camera"]["width"] == 640
    assert np.allclose(load_seed(path).matrix, T, atol=1e-9)


def test_an_existing_result_is_kept_as_a_backup(tmp_path):
    path = tmp_path / "result.yaml"
    path.write_text("precious: true\n")
    _, backup = write_result(path, fake_result())
    assert backup is not None and backup.read_text() == "precious: true\n"
    assert "T_cam_lidar" in path.read_text()
    _, backup2 = write_result(path, fake_result())
    assert backup2 != backup and backup.exists() and backup2.exists()


def test_written_files_get_the_usual_permissions(tmp_path):
    old = os.umask(0o022)
    try:
        path, _ = write_result(tmp_path / "r.yaml", fake_result())
    finally:
        os.umask(old)
    assert (path.stat().st_mode & 0o777) == 0o644


def test_a_failed_write_leaves_the_old_file_whole(tmp_path, monkeypatch):
    path = tmp_path / "result.yaml"
    path.write_text("old\n")

    def broken_replace(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", broken_replace)
    with pytest.raises(OSError, match="disk full"):
        atomic_write_bytes(path, b"new\n")
    assert path.read_text() == "old\n"
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".result")] == []


def test_result_dict_is_plain_data():
    data = result_to_dict(fake_result())
    yaml.safe_dump(data)  # no numpy types left
    json.dumps(data)
