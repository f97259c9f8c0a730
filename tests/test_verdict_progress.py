"""The judging phase reports its own progress (step, label, share done) and stops within a
second of its cancel event, raising JudgingCancelled instead of handing back a half-judged verdict."""

from __future__ import annotations

import threading
import time

import pytest

from app_fixtures import write_small_scenes
from l2e_studio.calibrate import CalibrationSettings, calibrate, stack_scenes
from l2e_studio.scenes import load_scene_folder
from l2e_studio.verdict import JudgeProgress, JudgingCancelled, judge


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    ss = load_scene_folder(write_small_scenes(tmp_path_factory.mktemp("vp") / "s", n_scenes=4))
    seed = ss.seed.perturbed([0.01, -0.01, 0.01], [0.01, -0.01, 0.005])
    settings = CalibrationSettings()
    stack = stack_scenes(ss.scenes, ss.camera, seed, settings)
    return stack, calibrate(stack, None, seed, settings), settings


def test_judging_reports_every_step_in_order_and_ends_done(calibrated):
    stack, result, settings = calibrated
    seen: list[JudgeProgress] = []
    verdict = judge(stack, result, settings, on_progress=seen.append)
    labels = list(dict.fromkeys(p.label for p in seen))
    assert labels[:7] == ["preparing the final smoothing and the second score",
                          "the scores at the seed and at the result",
                          "a significant peak: the score 2-8 deg around the result against its fluctuations",
                          "half 1 of 2: refined on its own", "half 2 of 2: refined on its own",
                          "a second start, mirrored through the result",
                          "translation probes: the result moved 5 cm along x, y, z"]
    steps = [p.step for p in seen]
    assert steps == sorted(steps) and steps[0] == 1 and all(p.step <= p.steps for p in seen)
    fractions = [p.fraction for p in seen]
    assert all(0.0 <= f <= 1.0 for f in fractions) and max(fractions) > 0.8
    # inside the refinements the share moves between steps (the bar does not freeze on one step)
    assert len({round(f, 4) for f in fractions}) > len(labels) + 5
    assert verdict.status in ("trusted", "trusted-rotation", "not-trusted")


@pytest.mark.parametrize("at", ["half 1 of 2", "a second start"])
def test_cancel_during_judging_raises_within_a_second(calibrated, at):
    stack, result, settings = calibrated
    cancel = threading.Event()
    when: list[float] = []

    def on_progress(p: JudgeProgress) -> None:
        if p.label.startswith(at) and p.fraction > (p.step - 1) / p.steps and not cancel.is_set():
            when.append(time.perf_counter())  # inside the refinement, a few evaluations in
            cancel.set()

    with pytest.raises(JudgingCancelled):
        judge(stack, result, settings, cancel=cancel, on_progress=on_progress)
    assert when, f"the judging never reached {at!r} with progress inside it"
    assert time.perf_counter() - when[0] < 1.0
