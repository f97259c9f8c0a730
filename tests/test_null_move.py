"""A calibration started at the truth, whose optimiser moves no further than the data can tell,
is confirmed: "both halves prefer the result" asks which of two poses that alike each half scores
higher, a coin toss there (stop 43: the synthetic 16- to 128-beam rigs from their truth ended
`not-trusted` on it alone, the truth kept all the same). A real move still needs both halves."""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from l2e_studio.calibrate import CalibrationSettings, calibrate, stack_scenes
from l2e_studio.evidence import Spread
from l2e_studio.geometry import Extrinsic
from l2e_studio.verdict import SIGNIFICANT, Check, judge, null_move

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from realdata_rigs import synthetic_rigs  # noqa: E402

SEED = Extrinsic(np.array([1.2, -1.2, 1.2]), np.array([0.05, -0.3, -0.1]))
CHECKS = (Check("score", True, "up"), Check("both halves prefer the result", False, "0.0107 -> 0.0106"),
          Check("halves agree (rotation)", False, "moves 1.2 deg"))


def _turned(deg: float, cm: float = 0.0) -> Extrinsic:
    return SEED.perturbed(np.array([cm / 100, 0.0, 0.0]), np.radians([deg, 0.0, 0.0]))


def _halves(checks) -> Check:
    return next(c for c in checks if c.name == "both halves prefer the result")


def test_a_move_within_the_spread_or_under_the_noise_is_no_move_for_the_halves() -> None:
    spread = Spread(0.1, 0.004, rise=5.0)
    # within SIGNIFICANT x the spread, rotation and translation: the halves' preference passes,
    # and only it (the halves' disagreement on the rotation stays a failure)
    out = null_move(CHECKS, SEED, _turned(0.15, 0.5), spread)
    assert _halves(out).passed and "no move the data can tell" in _halves(out).detail
    assert [c.passed for c in out if c.name != "both halves prefer the result"] == [True, False]
    # beyond it in rotation, or along one translation axis: a real move, both halves must prefer it
    for res in (_turned(SIGNIFICANT * 0.1 + 0.05), _turned(0.05, 100 * SIGNIFICANT * 0.004 + 0.2)):
        assert not _halves(null_move(CHECKS, SEED, res, spread)).passed
    # a real move whose score hardly rose above the seed's noise is none either
    quiet = null_move(CHECKS, SEED, _turned(0.5, 2.0), replace(spread, rise=0.4))
    assert _halves(quiet).passed and "0.4 standard deviations" in _halves(quiet).detail
    # a rise not measured (nan) is never under
    assert not _halves(null_move(CHECKS, SEED, _turned(0.5), replace(spread, rise=float("nan")))).passed
    # rotation only (nan translation spread): the translation must be the seed's
    rot = Spread(0.1, rise=5.0)
    assert _halves(null_move(CHECKS, SEED, _turned(0.1), rot)).passed
    assert not _halves(null_move(CHECKS, SEED, _turned(0.1, 0.1), rot)).passed


def test_the_synthetic_vlp16_started_at_its_truth_is_confirmed() -> None:
    rig = synthetic_rigs(["vlp16"], [8])[0]
    settings = CalibrationSettings()
    stack = stack_scenes(rig.scenes, rig.camera, rig.reference,
                         replace(settings, translation_bound=0.5, rotation_bound_deg=20.0)).aimed_at(rig.reference)
    result = calibrate(stack, None, rig.reference, settings)
    assert 0 < result.extrinsic.error_to(rig.reference)[0] < 0.2  # the optimiser moved, a little
    v = judge(stack, result, settings)
    assert v.status == "trusted" and v.seed_stands and v.summary().startswith("the seed stands, confirmed")
    assert np.allclose(v.extrinsic.matrix, rig.reference.matrix)
    halves = _halves(v.checks)
    assert halves.passed and "no move the data can tell" in halves.detail
