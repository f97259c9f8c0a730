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
    for line in advice[:-1]:
        assert any(line == f"rotation: {ROTATION_ADVICE[f]}" for f in failed if f in ROTATION_ADVICE), (line, failed)
    assert v.to_dict()["rotation_advice"] == advice
    # the family lines, then the lidar's own: a VLP-16's scan lines are 2 deg apart
    from l2e_studio.verdict import sparse_scan_line
    # (its eight scenes show one street from one place: the line asks for places before the board)
    assert v.places == 1 and v.scan_lines[0] == pytest.approx(2.0, abs=0.05)
    assert advice[-1] == sparse_scan_line(*v.scan_lines, one_place=True)
    assert v.to_dict()["scan_line_spacing"]["deg"] == pytest.approx(2.0, abs=0.05)


@pytest.mark.parametrize("name, spacing", [("vlp16", 2.0), ("hdl32", 41.34 / 31), ("hdl64", 26.9 / 63), ("os128", 45.0 / 127)])
def test_the_scan_lines_spacing_is_read_off_the_points_of_any_spinning_lidar(name, spacing) -> None:
    """The points a camera 90 deg wide sees, at ranges that vary point to point, in any scan order."""
    from l2e_studio.scoring.edges import scan_line_spacing_deg
    from l2e_studio.synth.lidars import LIDARS, ring_directions

    rng = np.random.default_rng(5)
    dirs, _ = ring_directions(LIDARS[name]["elevations_deg"], LIDARS[name]["azimuth_step_deg"], rng, hfov_deg=90.0)
    points = dirs * rng.uniform(3.0, 40.0, (len(dirs), 1))
    assert scan_line_spacing_deg(points[rng.permutation(len(points))]) == pytest.approx(spacing, rel=0.03)
    # looking backwards (azimuths about +-180 deg, where they wrap) reads the same
    assert scan_line_spacing_deg(points * [-1.0, -1.0, 1.0]) == pytest.approx(spacing, rel=0.03)
    assert np.isnan(scan_line_spacing_deg(points[:3]))


def test_a_sparse_lidar_adds_its_own_line_to_a_refused_rotation_and_only_then() -> None:
    from l2e_studio.verdict import SPARSE_SCAN_DEG, sparse_scan_line

    refused = _verdict("not-trusted", ["a single peak"])
    sparse = Verdict(**{**refused.__dict__, "scan_lines": (2.0, 82.8)})
    assert sparse.rotation_advice() == refused.rotation_advice() + [sparse_scan_line(2.0, 82.8)]
    assert "2.0 deg apart (83 px" in sparse.rotation_advice()[-1] and "Target tab" in sparse.rotation_advice()[-1]
    assert sparse.to_dict()["scan_line_spacing"] == {"deg": 2.0, "px_at_centre": 82.8}
    assert f"  > {sparse_scan_line(2.0, 82.8)}" in sparse.lines()
    dense = Verdict(**{**refused.__dict__, "scan_lines": (0.36, 4.5)})
    assert dense.rotation_advice() == refused.rotation_advice() and "scan_line_spacing" in dense.to_dict()
    assert Verdict(**{**refused.__dict__, "scan_lines": (SPARSE_SCAN_DEG, 60.0)}).rotation_advice()[-1].startswith(
        "rotation: the lidar's scan lines")
    trusted = Verdict(**{**_verdict("trusted", []).__dict__, "scan_lines": (2.0, 82.8)})
    assert trusted.rotation_advice() == []
    assert "scan_line_spacing" not in refused.to_dict()  # not measured


def test_a_sparse_lidar_whose_scenes_show_one_place_is_asked_for_places_first() -> None:
    """Every 16-beam dev rig is static; a drive thinned to their ring spacing calibrates (stop 40):
    the one-place line asks for scenes of many places before the board, the others for the board."""
    from l2e_studio.verdict import sparse_scan_line

    refused = _verdict("not-trusted", ["a single peak"])
    lines = {places: Verdict(**{**refused.__dict__, "scan_lines": (2.0, 82.8), "places": places}).rotation_advice()[-1]
             for places in (0, 1, 4)}
    assert lines[1] == sparse_scan_line(2.0, 82.8, one_place=True) != sparse_scan_line(2.0, 82.8)
    assert "all these scenes show one place" in lines[1] and "many places" in lines[1] and "Target tab" in lines[1]
    for places in (0, 4):  # several places, or not counted (a verdict built by hand): the board's line
        assert lines[places] == sparse_scan_line(2.0, 82.8) and "one place" not in lines[places]


def test_the_real_rigs_scan_lines_as_the_verdict_measures_them() -> None:
    """VLP-16 rigs 2 deg apart (sparse), the 64-beam KITTI drive 0.36 deg (not), at the reference."""
    from l2e_studio.verdict import SPARSE_SCAN_DEG, scan_line_spacing

    rigs = {r.name: r for r in load_rigs(["hitsz_vlp16", "lcecalib_rles01_frame", "kitti_odometry_00"])}
    if len(rigs) < 3:
        pytest.skip("realdata hitsz_vlp16, lcecalib_rles01_frame or kitti_odometry_00 not present")
    settings = CalibrationSettings()
    got = {}
    for name, rig in rigs.items():
        stack = stack_scenes(rig.scenes, rig.camera, rig.reference, settings)
        got[name] = scan_line_spacing(stack, rig.reference)
    assert got["hitsz_vlp16"][0] == pytest.approx(2.0, abs=0.05) and got["hitsz_vlp16"][1] == pytest.approx(83, abs=3)
    assert got["lcecalib_rles01_frame"][0] == pytest.approx(2.0, abs=0.05) and got["lcecalib_rles01_frame"][1] < 15
    assert 0.3 < got["kitti_odometry_00"][0] < 0.45 < SPARSE_SCAN_DEG
