"""The quality checks: sharp and stable on good data, warnings on flat or thin data."""

import numpy as np
import yaml

from l2e_studio.calibrate import calibrate
from l2e_studio.evaluate import AXES, FLAT_NATS, assess, sharpness
from l2e_studio.objective import SceneStack
from l2e_studio.samples import sample_scenes_dir
from l2e_studio.scenes import Scene, load_scene_folder
from test_cli_calibrate import run_cli


def test_good_synthetic_data_is_sharp_and_stable():
    sample = load_scene_folder(sample_scenes_dir())  # six scenes: halves of three are still enough
    stack = SceneStack.build(sample.scenes, sample.camera, sigma=2.0)
    result = calibrate(stack, None, sample.seed)
    report = assess(stack, result.extrinsic, sample.seed, subsets=2)
    assert report.warnings == []
    assert np.all(report.sharpness > FLAT_NATS)
    assert report.subset_rotation_deg < 0.2 and report.subset_translation_m < 0.02
    assert set(report.to_dict()["sharpness_nats"]) == set(AXES)


def test_subsets_of_few_small_scenes_are_flagged_unstable(small_synth):
    scenes, camera, truth = small_synth  # four 640x360 scenes: halves of two disagree
    stack = SceneStack.build(scenes, camera, sigma=2.0)
    seed = truth.perturbed([0.05, -0.03, 0.02], np.radians([2.0, -1.5, 1.0]))
    result = calibrate(stack, None, seed)
    report = assess(stack, result.extrinsic, seed, subsets=3)
    assert any(w.startswith("unstable:") for w in report.warnings)


def test_uninformative_intensities_are_flat_and_a_single_scene_is_flagged(small_synth):
    scenes, camera, truth = small_synth
    sc = scenes[0]
    flat = Scene("flat", sc.points, np.full_like(sc.intensity, 100.0), sc.event_map)
    stack = SceneStack.build([flat], camera, sigma=2.0)
    assert np.all(np.abs(sharpness(stack, truth)) < FLAT_NATS)
    report = assess(stack, truth, truth)
    assert any(w.startswith("flat along") for w in report.warnings)
    assert any("single scene" in w for w in report.warnings)
    assert report.subsets == 0


def test_cli_check_writes_the_quality_section(tmp_path):
    out = tmp_path / "r.yaml"
    proc = run_cli("calibrate", "--out", out, "--check", "--quiet")  # the embedded sample
    assert proc.returncode == 0, proc.stderr
    quality = yaml.safe_load(out.read_text())["quality"]
    assert quality["subsets"] == 3 and quality["warnings"] == []
    assert min(quality["sharpness_nats"].values()) > FLAT_NATS
