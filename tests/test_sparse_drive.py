"""A sparse lidar fails on the dev rigs for their static scenes, not for its rings (stop 40).

Every 16-beam dev rig is static, its scenes one place. KITTI's drive (ten scans, ten places) with
its 64-beam scans thinned to rings 2 deg apart, as a VLP-16 spaces them
(``benchmarks/realdata_rigs.sparse``), has its rotation trusted near the reference.
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import pytest

from l2e_studio.calibrate import CalibrationSettings, calibrate, stack_scenes
from l2e_studio.verdict import SIGNIFICANT, SPARSE_SCAN_DEG, judge, scan_line_spacing

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from realdata_rigs import cropped, load_rigs, perturbations, sparse, split  # noqa: E402


def test_a_drive_thinned_to_a_16_beam_lidars_rings_has_its_rotation_trusted() -> None:
    rigs = load_rigs(["kitti_odometry_00"])
    if not rigs:
        pytest.skip("../shared/realdata is absent")
    rig = sparse(rigs, 2.0)[0]
    full = sum(len(sc.points) for sc in rigs[0].scenes)
    assert 0.1 < sum(len(sc.points) for sc in rig.scenes) / full < 0.25  # 12 of 64 rings in view
    settings = CalibrationSettings()
    dt, dr = perturbations(1, 2.0, 0.10, 1001)[0]
    seed = rig.reference.perturbed(dt, dr)
    stack = stack_scenes(rig.scenes, rig.camera, seed, settings)
    # sparse as the verdict measures it: the rings 2 deg apart, past the advice's threshold
    spacing = scan_line_spacing(stack, rig.reference)[0]
    assert spacing == pytest.approx(2.0, abs=0.2) and spacing > SPARSE_SCAN_DEG
    verdict = judge(stack, calibrate(stack, None, seed, settings), settings)
    assert verdict.trusted and verdict.places >= 2, verdict.lines()
    deg, _ = verdict.extrinsic.error_to(rig.reference)
    assert deg < 0.3, (deg, verdict.lines())


def test_a_thinned_scan_alone_whose_second_start_finds_a_rival_peak_is_not_trusted() -> None:
    """One of those scans alone (001483), from a 2 deg / 10 cm seed: the search ends on a peak
    5.5 deg off, whose 6-DoF second start ends 8.5 deg away on another peak scoring 89 % of it.
    The rotation re-fitted to the seed's translation (within 1 deg of the result) came back to the
    result and passed every check of its own: `trusted-rotation`, 5.4 deg off. A re-fit cannot
    choose between two peaks, so none is tried where the second start found a rival.

    Since stop 42 the search reaches that peak from both starts (it scores 2.2 times the
    reference's, 9.6 deviations high) and the second start agrees with it; what refuses it is
    the scan itself: a sparse lidar's one place (`places for a sparse lidar`)."""
    rigs = load_rigs(["kitti_odometry_00"])
    if not rigs:
        pytest.skip("../shared/realdata is absent")
    rig = next(r for r in sparse(split(rigs, 1), 2.0) if r.scenes[0].name == "001483")
    settings = CalibrationSettings()
    dt, dr = perturbations(5, 2.0, 0.10, 1001)[1]  # bench_realdata.py's second 2 deg / 10 cm seed
    seed = rig.reference.perturbed(dt, dr)
    stack = stack_scenes(rig.scenes, rig.camera, rig.reference,
                         replace(settings, translation_bound=0.5, rotation_bound_deg=20.0)).aimed_at(seed)
    result = calibrate(stack, None, seed, settings)
    verdict = judge(stack, result, settings)
    seed_deg, end_deg = seed.error_to(rig.reference)[0], verdict.extrinsic.error_to(rig.reference)[0]
    assert not (verdict.trusted and end_deg > seed_deg + 0.1), verdict.lines()
    if result.extrinsic.error_to(rig.reference)[0] > 4.0:  # the far peak (on this host's arithmetic, every time)
        assert verdict.status == "not-trusted", verdict.lines()
        assert not any(c.name.endswith("(rotation only)") for c in verdict.checks)  # no re-fit was tried
        assert [c.passed for c in verdict.checks if c.name == "places for a sparse lidar"] == [False]
        assert any("show one place" in line for line in verdict.rotation_advice()), verdict.rotation_advice()


def test_started_at_the_reference_a_shared_bias_that_barely_beats_it_leaves_the_seed() -> None:
    """The thinned drive through a lens as narrow as HITSZ's (34 deg), started at its reference:
    every scene shares a bias, and the search climbs 0.6 deg / 13 cm away to a peak its halves and
    second start confirm (0.14 deg), `trusted-rotation`, handed back 0.6 deg / 6 cm from the seed.
    That peak scores about one standard deviation of the landscape's own fluctuations above the
    seed: the data cannot tell it from the seed, and the seed stands."""
    rigs = load_rigs(["kitti_odometry_00"])
    if not rigs:
        pytest.skip("../shared/realdata is absent")
    rig = cropped(sparse(rigs, 2.0), 34.0)[0]
    settings = CalibrationSettings()
    seed = rig.reference
    stack = stack_scenes(rig.scenes, rig.camera, seed, replace(settings, translation_bound=0.5, rotation_bound_deg=20.0))
    result = calibrate(stack, None, seed, settings)
    verdict = judge(stack, result, settings)
    assert result.extrinsic.error_to(seed)[0] > 0.3  # the shared bias, found
    deg, m = verdict.extrinsic.error_to(seed)
    assert deg <= 0.2 and m <= 0.02, verdict.lines()  # started at the reference, it stays
    if verdict.trusted:  # its checks all passed (on this host, every time): the rise alone leaves the seed
        assert verdict.seed_stands and verdict.spread.rise < SIGNIFICANT, verdict.lines()
        assert "standard deviations" in verdict.summary() and not verdict.pinned()
