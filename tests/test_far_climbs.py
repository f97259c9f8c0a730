"""The verdict's climbs from the far field run two at a time: the same ends as one after the
other, taken in rank order up to the first missed peak, with progress from the calling thread."""

from __future__ import annotations

import threading
from dataclasses import replace

import numpy as np
import pytest

import l2e_studio.peaks as peaks
from l2e_studio.calibrate import CalibrationSettings, calibrate, stack_scenes

SETTINGS = CalibrationSettings(global_search=True)


@pytest.fixture(scope="module")
def run(small_synth):
    scenes, camera, truth = small_synth
    stack = stack_scenes(scenes, camera, truth, SETTINGS)
    result = calibrate(stack, None, truth.perturbed([0.02, -0.01, 0.02], np.radians([1.5, -1.0, 1.0])), SETTINGS)
    assert len(result.ends) >= 2  # a global search ran
    return stack, result, truth


def climbs(stack, result, climbers, monkeypatch, on_progress=None):
    monkeypatch.setattr(peaks, "CLIMBERS", climbers)
    return peaks.far_climbs(stack, result, SETTINGS, on_progress=on_progress)


def same(a, b) -> bool:
    return len(a) == len(b) and all(np.array_equal(x.matrix, y.matrix) and s == t for (x, s), (y, t) in zip(a, b))


def test_two_climbs_at_a_time_end_where_one_after_the_other_do(run, monkeypatch):
    stack, result, _ = run
    seen = []
    together = climbs(stack, result, 2, monkeypatch, lambda p: seen.append((threading.current_thread(), p.fraction)))
    alone = climbs(stack, result, 1, monkeypatch)
    assert len(together) == peaks.FAR_CLIMBS and same(together, alone)
    assert seen and {t for t, _ in seen} == {threading.current_thread()}  # reported where it was asked
    assert all(0.0 <= f <= 1.0 for _, f in seen) and seen[-1][1] > 0.5


def test_the_climbs_stop_at_the_first_missed_peak(run, monkeypatch):
    """A result 1.5 deg off the peak: a climb from its far field finds the higher peak, the ends
    stop there (in rank order, as one after the other), and the rival check says so."""
    stack, result, truth = run
    beside = replace(result, extrinsic=truth.perturbed(np.zeros(3), np.radians([1.5, 0.0, 0.0])),
                     score_result=stack.with_sigma(SETTINGS.sigma).score(truth, per_scene=False)[0] * 0.9)
    together = climbs(stack, beside, 2, monkeypatch)
    alone = climbs(stack, beside, 1, monkeypatch)
    assert same(together, alone) and len(together) < peaks.FAR_CLIMBS
    assert peaks.missed_peak(beside, *together[-1]) and not any(peaks.missed_peak(beside, *e) for e in together[:-1])
    assert not peaks.rival_check(beside, together).passed
