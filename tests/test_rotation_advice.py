"""A rotation the verdict does not trust comes with what it means and what to record or do
(issue 16: a user of an unseen rig gets the seed back and needs to know why, and what next), in
the terminal, the result file, the app and the report."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from l2e_studio.calibrate import CalibrationSettings, calibrate, stack_scenes
from l2e_studio.geometry import Extrinsic
from l2e_studio.verdict import ROTATION_ADVICE, Check, Verdict, judge, translation_axes

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from realdata_rigs import load_rigs, perturbations  # noqa: E402

EXT = Extrinsic(np.zeros(3), np.zeros(3))


def _verdict(status: str, failed: list[str], passed: list[str] = ()) -> Verdict:
    checks = tuple(Check(n, False, "measured") for n in failed) + tuple(Check(n, True, "measured") for n in passed)
    axes = translation_axes(np.array([0.2, 0.22, 0.05]), "edges", 2, np.array([np.nan, np.nan, 0.04]))
    return Verdict(status, EXT, status == "not-trusted", tuple(f"{n}: measured" for n in failed), checks, 0.0, axes)


def test_each_failed_family_of_rotation_checks_gets_one_line_and_translation_checks_none() -> None:
    v = _verdict("not-trusted", ["a single peak", "second start (rotation)", "second start (translation)",
                                 "halves agree (rotation) (rotation only)", "both halves prefer the result",
                                 "translation observable (translation)"], passed=["a significant peak"])
    # a single peak and the second start share a line (several peaks); the re-fit's check and the
    # halves' preference share the halves' line; translation checks and passed checks give none
    assert v.rotation_advice() == [f"rotation: {ROTATION_ADVICE['a single peak']}",
                                   f"rotation: {ROTATION_ADVICE['halves agree (rotation)']}"]
    assert "Target tab" in v.rotation_advice()[0] and "time sync" in v.rotation_advice()[1]
    # then the translation: one line per unpinned axis (z here)
    assert v.advice() == v.rotation_advice() + [a.line() for a in v.translation if not a.pinned]
    assert v.advice()[-1].startswith("z is not pinned")


def test_a_trusted_rotation_has_no_rotation_advice() -> None:
    for status in ("trusted", "trusted-rotation"):
        v = _verdict(status, ["translation observable (translation)"] if status != "trusted" else [])
        assert v.rotation_advice() == [] and "rotation_advice" not in v.to_dict()
    # a check no advice is written for (a failed translation check) adds nothing
    assert _verdict("not-trusted", ["second start (translation)"]).rotation_advice() == []


def test_the_advice_reaches_the_terminal_the_app_the_file_and_the_report() -> None:
    from l2e_studio.app.panels.results import verdict_text
    from l2e_studio.qa.report import verdict_html

    v = _verdict("not-trusted", ["a significant peak (rotation only)"])
    line = f"rotation: {ROTATION_ADVICE['a significant peak']}"
    assert v.rotation_advice() == [line]
    assert f"  > {line}" in v.lines()
    assert f"→ {line}" in verdict_text(v)
    d = v.to_dict()
    assert d["rotation_advice"] == [line]
    html = verdict_html(d)
    assert "<h3>Rotation: what to record or do</h3>" in html and "hardly stands above its own noise" in html
    # a result file written before this field existed still renders
    assert "Rotation: what to record" not in verdict_html({k: x for k, x in d.items() if k != "rotation_advice"})


def test_a_pulled_result_on_a_real_16_beam_rig_says_what_failed_and_what_to_do() -> None:
    """HITSZ's VLP-16 street rig (8 scenes, narrow lens): the score's peak is not the reference's,
    the verdict keeps the seed, and each rotation line names a family whose check failed."""
    rigs = load_rigs(["hitsz_vlp16"])
    if not rigs:
        pytest.skip("realdata hitsz_vlp16 not present")
    rig = rigs[0]
    settings = CalibrationSettings()
    dt, dr = perturbations(1, 2.0, 0.10, 1001)[0]
    seed = rig.reference.perturbed(dt, dr)
    stack = stack_scenes(rig.scenes, rig.camera, seed, settings)
    v = judge(stack, calibrate(stack, None, seed, settings), settings)
    assert v.status == "not-trusted" and v.kept_seed, v.lines()
    advice = v.rotation_advice()
    assert advice, v.lines()
    failed = {c.name.removesuffix(" (rotation only)") for c in v.checks if not c.passed}
    for line in advice:
        assert any(line == f"rotation: {ROTATION_ADVICE[f]}" for f in failed if f in ROTATION_ADVICE), (line, failed)
    assert v.to_dict()["rotation_advice"] == advice
