"""A static rig's cloud is often several revolutions of its lidar accumulated: a phase-locked lidar
fires at the same azimuths each time, a free-running one at phases of its own, so its sweeps
interleave. Before stop 44 the edge weights compared each return with its own copies: three
revolutions of the synthetic VLP-16 calibrated 0.3-6.6 deg off (phase-locked) and 2-4 deg off
(free-running), none trusted, where one revolution ends 0.07 deg off, and up to 60 % of a KITTI
scan's points read as silhouettes against the sky."""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from l2e_studio.calibrate import CalibrationSettings, calibrate, stack_scenes
from l2e_studio.scoring import edges
from l2e_studio.synth.dataset import SynthConfig, lidar_directions
from l2e_studio.verdict import judge
from test_silhouettes import ring_scan

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from realdata_rigs import perturbations, synthetic_rigs  # noqa: E402

RNG = np.random.default_rng(5)


def _street(az: np.ndarray) -> np.ndarray:
    """Ranges of a wall at 20 m with a post at 8 m (-5..5 deg), the sky above 60 deg."""
    ranges = np.full(az.shape, 20.0)
    ranges[np.abs(az) <= 5.0] = 8.0
    ranges[az > 60.0] = np.nan
    return ranges


def _noisy(points: np.ndarray, m: float = 0.015) -> np.ndarray:
    r = np.linalg.norm(points, axis=1, keepdims=True)
    return points * (1 + RNG.normal(0, m, r.shape) / r)


def test_a_phase_locked_accumulation_weighs_as_one_revolution() -> None:
    az = np.arange(-180.0, 180.0, 0.2)
    one = ring_scan(az, _street(az))
    w1 = edges.lidar_edge_weights(one.astype(np.float32), np.full(len(one), 100.0, np.float32))
    three = np.concatenate([_noisy(one) for _ in range(3)])
    w3 = edges.lidar_edge_weights(three.astype(np.float32), np.full(len(three), 100.0, np.float32))
    # every copy of a return weighs what the return weighs alone: the post's sides, the sky's edge
    assert np.array_equal(np.tile(w1 > 0.5, 3), w3 > 0.5)
    assert (w1 > 0.5).sum() >= 8  # (something to compare: the post's two sides and the skyline, per ring)


def test_a_later_return_behind_the_first_is_no_edge() -> None:
    """A dual-return lidar's second return of a beam lies behind the first: the camera sees it
    elsewhere, so it takes none of the first return's weight."""
    az = np.arange(-180.0, 180.0, 0.2)
    first = ring_scan(az, _street(az))
    behind = first * 1.5  # every beam's second return, 50 % further
    pts = np.concatenate([first, behind]).astype(np.float32)
    w = edges.lidar_edge_weights(pts, np.full(len(pts), 100.0, np.float32))
    w1 = edges.lidar_edge_weights(first.astype(np.float32), np.full(len(first), 100.0, np.float32))
    assert np.array_equal(w[:len(first)], w1) and not w[len(first):].any()


def test_free_running_sweeps_do_not_turn_the_scan_into_silhouettes() -> None:
    """Interleaved revolutions put a point's neighbours a fraction of a step away on one side and
    most of one on the other: no gap of missing returns (their share stays that of one sweep)."""
    az = np.arange(-180.0, 180.0, 0.2)
    one = ring_scan(az, _street(az))
    sweeps = [one] + [ring_scan(az + RNG.uniform(0, 0.2), _street(az + 0.1)) for _ in range(2)]
    three = np.concatenate([_noisy(p) for p in sweeps]).astype(np.float32)
    share = lambda p: float(np.isclose(edges.lidar_edge_weights(p, np.full(len(p), 100.0, np.float32)),  # noqa: E731
                                       edges.SILHOUETTE_WEIGHT).mean())
    assert share(three) <= 2 * share(one.astype(np.float32)) + 0.002


def test_the_synthetic_lidar_accumulates_revolutions() -> None:
    rng = np.random.default_rng(0)
    one = lidar_directions(SynthConfig(lidar="vlp16", lidar_hfov_deg=120.0), rng)
    locked = lidar_directions(SynthConfig(lidar="vlp16", lidar_hfov_deg=120.0, lidar_sweeps=3, lidar_phase_locked=True),
                              np.random.default_rng(0))
    free = lidar_directions(SynthConfig(lidar="vlp16", lidar_hfov_deg=120.0, lidar_sweeps=3), np.random.default_rng(0))
    assert np.array_equal(locked, np.tile(one, (3, 1))) and np.array_equal(free[:len(one)], one)
    assert len(free) >= 3 * len(one) - 32 and not np.allclose(free[len(one):2 * len(one)], one[:len(one)])


def test_three_phase_locked_revolutions_of_the_synthetic_vlp16_calibrate_as_one() -> None:
    rig = synthetic_rigs(["vlp16"], [8], revolutions=3, phase_locked=True)[0]
    settings = CalibrationSettings()
    stack = stack_scenes(rig.scenes, rig.camera, rig.reference, replace(settings, translation_bound=0.5,
                                                                         rotation_bound_deg=20.0))
    dt, dr = perturbations(20, 1.0, 0.05, 1000)[0]
    seed = rig.reference.perturbed(dt, dr)
    aimed = stack.aimed_at(seed)
    v = judge(aimed, calibrate(aimed, None, seed, settings), settings)
    deg, m = v.extrinsic.error_to(rig.reference)
    assert v.status == "trusted" and deg < 0.1 and m < 0.01, (v.status, deg, m)
