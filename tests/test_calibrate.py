"""Calibration on small synthetic scenes with a known answer: recovery, bounds, progress, cancel."""

import threading
import time

import numpy as np
import pytest

from l2e_studio.calibrate import CalibrationSettings, Progress, calibrate
from l2e_studio.geometry import Extrinsic


def seed_near(truth: Extrinsic, deg: float, m: float, k: int = 0) -> Extrinsic:
    rng = np.random.default_rng(100 + k)
    axis, step = rng.normal(size=3), rng.normal(size=3)
    return truth.perturbed(step / np.linalg.norm(step) * m, axis / np.linalg.norm(axis) * np.radians(deg))


@pytest.mark.parametrize("k", range(3))
def test_recovers_the_true_extrinsic_from_a_perturbed_seed(small_synth, k):
    scenes, camera, truth = small_synth
    seed = Extrinsic(truth.rotvec + np.random.default_rng(k).uniform(-0.1, 0.1, 3),
                     truth.translation + np.random.default_rng(k + 50).uniform(-0.1, 0.1, 3))
    res = calibrate(scenes, camera, seed)
    deg, m = res.extrinsic.error_to(truth)
    # on these four small scenes about 1 seed in 10 stops on a lower second peak 3.0-3.1 cm off
    # (measured over 20 seeds: 2 of 20, which ones moving with the last bits of the arithmetic)
    assert deg < 0.2 and m < 0.035, (deg, m)
    assert res.score_result > res.score_seed
    assert len(res.score_result_per_scene) == len(scenes)
    assert np.all(res.score_result_per_scene > res.score_seed_per_scene)
    assert res.evaluations == len(res.history) > 10
    assert not res.cancelled


@pytest.mark.parametrize("method", ["L-BFGS-B", "Powell"])
def test_other_optimisers_also_converge(small_synth, method):
    """Four seeds 2 deg / 5 cm off: typically within 0.25 deg and 3 cm (the median), never far
    (a quasi-Newton method may stop a little early on one seed: L-BFGS-B's relative-reduction test)."""
    scenes, camera, truth = small_synth
    errors = np.array([calibrate(scenes, camera, seed_near(truth, 2.0, 0.05, k), CalibrationSettings(method=method))
                       .extrinsic.error_to(truth) for k in range(4)])
    deg, m = np.median(errors, axis=0)
    assert deg < 0.25 and m < 0.03, (method, errors)
    assert errors[:, 0].max() < 0.4 and errors[:, 1].max() < 0.045, (method, errors)


def test_rotation_only_keeps_the_seed_translation(small_synth):
    scenes, camera, truth = small_synth
    seed = Extrinsic(truth.perturbed([0, 0, 0], np.radians([1.5, -1.0, 1.0])).rotvec, truth.translation)
    res = calibrate(scenes, camera, seed, CalibrationSettings(rotation_only=True))
    assert np.array_equal(res.extrinsic.translation, seed.translation)
    assert res.extrinsic.error_to(truth)[0] < 0.2


def test_result_stays_inside_the_bounds(small_synth):
    scenes, camera, truth = small_synth
    seed = seed_near(truth, 3.0, 0.08, k=1)
    settings = CalibrationSettings(translation_bound=0.01, rotation_bound_deg=0.5)
    res = calibrate(scenes, camera, seed, settings)
    dt, dw = seed.delta_to(res.extrinsic)
    assert np.all(np.abs(dt) <= 0.01 + 1e-9)
    assert np.all(np.abs(np.degrees(dw)) <= 0.5 + 1e-6)
    assert res.extrinsic.error_to(truth)[0] > 1.0  # the truth is out of reach


def test_progress_reports_every_evaluation_with_a_best_extrinsic(small_synth):
    scenes, camera, truth = small_synth
    seen: list[Progress] = []
    res = calibrate(scenes, camera, seed_near(truth, 2.0, 0.05), on_progress=seen.append)
    assert [p.evaluations for p in seen] == list(range(1, res.evaluations + 1))
    assert all(0.0 <= p.fraction <= 1.0 for p in seen)
    assert [p.stage for p in seen] == sorted(p.stage for p in seen)
    assert seen[-1].stage == seen[-1].stages - 1
    for stage in range(seen[-1].stages):
        best = [p.best_mi for p in seen if p.stage == stage]
        assert best == sorted(best)  # the best so far never gets worse within a stage
    assert seen[-1].best.error_to(truth)[0] < 0.2


def test_cancel_from_another_thread_stops_within_a_second(small_synth):
    scenes, camera, truth = small_synth
    cancel = threading.Event()
    started = threading.Event()
    out = {}

    def run():
        out["res"] = calibrate(scenes, camera, seed_near(truth, 3.0, 0.05),
                               CalibrationSettings(method="Powell", max_iterations=10_000),
                               on_progress=lambda p: started.set(), cancel=cancel)

    worker = threading.Thread(target=run)
    worker.start()
    assert started.wait(30)
    t0 = time.perf_counter()
    cancel.set()
    worker.join(5)
    assert not worker.is_alive()
    assert time.perf_counter() - t0 < 1.0
    res = out["res"]
    assert res.cancelled and res.message == "cancelled"
    assert res.evaluations >= 1
    assert np.isfinite(res.score_result)


def test_unknown_optimiser_and_bad_bounds_are_rejected():
    with pytest.raises(ValueError, match="unknown optimiser"):
        CalibrationSettings(method="BFGS")
    with pytest.raises(ValueError):
        CalibrationSettings(rotation_bound_deg=0)
