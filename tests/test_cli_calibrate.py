"""`l2e-studio calibrate` end to end, and every bad input the issue lists, through the real CLI."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from l2e_studio.io.cameras import load_seed
from l2e_studio.synth import read_truth


def run_cli(*args, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "l2e_studio", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, timeout=300, env={**os.environ, "COLUMNS": "120"})


def only_scene(folder: Path, keep: str = "scene_000") -> Path:
    for sub in ("event", "lidar"):
        for f in (folder / sub).iterdir():
            if not f.name.startswith(keep):
                f.unlink()
    return folder


def assert_one_line_error(proc, *fragments):
    assert proc.returncode == 2, proc.stderr
    lines = [l for l in proc.stderr.strip().splitlines() if l.strip()]
    assert len(lines) == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    for frag in fragments:
        assert frag in lines[0], lines[0]


def test_calibrate_writes_a_result_near_the_truth(small_synth_dir, tmp_path):
    out = tmp_path / "res.json"
    proc = run_cli("calibrate", "--scenes", small_synth_dir, "--out", out)
    assert proc.returncode == 0, proc.stderr
    assert "all scenes" in proc.stdout and f"result written to {out}" in proc.stdout
    data = json.loads(out.read_text())
    assert data["score"]["result"] > data["score"]["seed"]
    assert len(data["scenes"]) == 4 and data["optimisation_seconds"] > 0
    deg, m = load_seed(out).error_to(read_truth(small_synth_dir / "truth.yaml"))
    assert deg < 0.2 and m < 0.025
    # a second run keeps the first result as a backup
    proc = run_cli("calibrate", "--scenes", small_synth_dir, "--out", out, "--quiet")
    assert proc.returncode == 0 and "previous file kept as" in proc.stdout
    assert len(list(tmp_path.glob("res.*.bak.json"))) == 1


def test_seed_override_and_single_stage(small_synth_dir, tmp_path):
    seed = tmp_path / "seed.yaml"
    truth = read_truth(small_synth_dir / "truth.yaml")
    off = truth.perturbed([0.01, 0, 0], [0, np.radians(0.3), 0])
    seed.write_text(yaml.safe_dump({"translation": off.translation.tolist(), "rotvec": off.rotvec.tolist()}))
    out = tmp_path / "r.yaml"
    proc = run_cli("calibrate", "--scenes", small_synth_dir, "--seed", seed, "--out", out, "--single-stage", "--quiet")
    assert proc.returncode == 0, proc.stderr
    data = yaml.safe_load(out.read_text())
    assert np.allclose(data["seed"]["T_cam_lidar"], off.matrix, atol=1e-8)
    assert len(data["optimiser"]["stages"]) == 1
    # each scene's map is on record: PNG maps are read as they are (no accumulation)
    assert set(data["maps"]) == set(data["scenes"])
    assert data["maps"]["scene_000"] == {"file": str(small_synth_dir / "event" / "scene_000.png"), "kind": "events",
                                         "accumulation": None}


def test_a_seed_at_gimbal_lock_prints_no_warning_and_the_correction(small_synth_dir, tmp_path):
    """An ideally mounted rig's seed (lidar x forward -> optical z) sits at pitch = -90 deg."""
    from l2e_studio.geometry import LIDAR_TO_CAMERA_AXES

    truth = read_truth(small_synth_dir / "truth.yaml")
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = LIDAR_TO_CAMERA_AXES, truth.translation
    seed = tmp_path / "seed.yaml"
    seed.write_text(yaml.safe_dump({"T_cam_lidar": T.tolist()}))
    out = tmp_path / "r.yaml"
    proc = run_cli("calibrate", "--scenes", small_synth_dir, "--seed", seed, "--out", out, "--single-stage")
    assert proc.returncode == 0, proc.stderr
    assert "Gimbal lock" not in proc.stderr + proc.stdout and "Warning" not in proc.stderr, proc.stderr
    assert "rotation correction to the seed" in " ".join(proc.stdout.split())  # rich wraps the caption
    data = yaml.safe_load(out.read_text())
    assert np.allclose(data["seed"]["rpy_deg"][1], -90.0)  # the file keeps the absolute angles, exact


def test_missing_folder(tmp_path):
    proc = run_cli("calibrate", "--scenes", tmp_path / "nope", "--out", tmp_path / "r.yaml")
    assert_one_line_error(proc, str(tmp_path / "nope"), "does not exist")
    assert not (tmp_path / "r.yaml").exists()


@pytest.mark.parametrize(
    "damage, fragment",
    [
        (lambda d: (d / "lidar/scene_000.txt").write_text(""), "scene_000.txt"),
        (lambda d: (d / "lidar/scene_000.txt").write_text("nan,nan,nan,nan\n" * 50), "scene_000.txt"),
        (lambda d: (d / "lidar/scene_000.txt").write_text("1.0,2.0,3.0\n" * 50), "no intensity field"),
        (lambda d: (d / "event/scene_000.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage"), "scene_000.png"),
        (lambda d: (d / "event/scene_000.png").write_bytes((d / "event/scene_000.png").read_bytes()[:200]), "scene_000.png"),
    ],
    ids=["empty-cloud", "nan-cloud", "no-intensity", "corrupt-png", "truncated-png"],
)
def test_bad_scene_alone_fails_and_among_others_is_skipped(scene_dir_copy, tmp_path, damage, fragment):
    damage(scene_dir_copy)
    out = tmp_path / "r.yaml"
    proc = run_cli("calibrate", "--scenes", scene_dir_copy, "--out", out, "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert "skipped scene scene_000" in proc.stderr and fragment in proc.stderr
    assert yaml.safe_load(out.read_text())["scenes"] == ["scene_001", "scene_002", "scene_003"]
    only_scene(scene_dir_copy)
    proc = run_cli("calibrate", "--scenes", scene_dir_copy, "--out", tmp_path / "r2.yaml")
    assert_one_line_error(proc, fragment)
    assert not (tmp_path / "r2.yaml").exists()


def test_map_of_the_wrong_size_for_the_camera(scene_dir_copy, tmp_path):
    import cv2

    cv2.imwrite(str(scene_dir_copy / "event/scene_001.png"), np.zeros((100, 200), np.uint8))
    proc = run_cli("calibrate", "--scenes", scene_dir_copy, "--out", tmp_path / "r.yaml", "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert "skipped scene scene_001" in proc.stderr and "200x100" in proc.stderr and "640x360" in proc.stderr
    only_scene(scene_dir_copy, "scene_001")
    assert_one_line_error(run_cli("calibrate", "--scenes", scene_dir_copy, "--out", tmp_path / "r2.yaml"), "scene_001.png")


def test_config_missing_K(scene_dir_copy, tmp_path):
    (scene_dir_copy / "camera.yaml").unlink()
    cfg = scene_dir_copy / "config" / "config.json"
    doc = json.loads(cfg.read_text())
    del doc["cam"]["K"]
    cfg.write_text(json.dumps(doc))
    assert_one_line_error(run_cli("calibrate", "--scenes", scene_dir_copy, "--out", tmp_path / "r.yaml"), str(cfg), "K")


def test_unpaired_files_are_reported(scene_dir_copy, tmp_path):
    (scene_dir_copy / "lidar/scene_002.txt").rename(scene_dir_copy / "lidar/extra_scan.txt")
    proc = run_cli("calibrate", "--scenes", scene_dir_copy, "--out", tmp_path / "r.yaml", "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert "scene_002.png: no lidar scan" in proc.stderr and "extra_scan.txt: no event map" in proc.stderr


def test_bad_settings_and_missing_seed_file(small_synth_dir, tmp_path):
    assert_one_line_error(run_cli("calibrate", "--scenes", small_synth_dir, "--bound-deg", "0", "--out", tmp_path / "r.yaml"),
                          "--bound-deg", "(0, 90]")
    assert_one_line_error(run_cli("calibrate", "--scenes", small_synth_dir, "--seed", tmp_path / "none.yaml",
                                  "--out", tmp_path / "r.yaml"), "none.yaml", "does not exist")
