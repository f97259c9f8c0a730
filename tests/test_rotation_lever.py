"""A rotation paired with the seed's translation is only as good as that translation: the verdict
says how far the rotation turns for each centimetre it is off, and how well to measure it (stop 44:
KITTI 000008 from a 5 deg / 20 cm seed was `trusted-rotation` 1.09 deg off, the rotation fitted to
a translation 13 cm off sideways at a lever of 0.06 deg a cm)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from l2e_studio.calibrate import CalibrationSettings, refine, stack_scenes
from l2e_studio.camera import CameraModel
from l2e_studio.export import export_status
from l2e_studio.geometry import Extrinsic
from l2e_studio.objective import SceneStack
from l2e_studio.pinning import LEVER_TARGET_DEG, rotation_lever
from l2e_studio.scenes import Scene
from l2e_studio.verdict import Check, Verdict, translation_axes


def _wall(depth: float) -> tuple[list[Scene], CameraModel, Extrinsic]:
    """A lidar looking along the camera's axis at a wall ``depth`` m away (identity extrinsic)."""
    camera = CameraModel(np.array([[300.0, 0, 160], [0, 300.0, 120], [0, 0, 1]]), 320, 240)
    g = np.linspace(-0.4, 0.4, 60) * depth
    x, y = np.meshgrid(g, g * 0.7)
    pts = np.stack([x.ravel(), y.ravel(), np.full(x.size, depth)], axis=1).astype(np.float32)
    rng = np.random.default_rng(0)
    scene = Scene("wall", pts, rng.uniform(0, 255, len(pts)).astype(np.float32),
                  rng.uniform(0, 255, (240, 320)).astype(np.float32))
    return [scene], camera, Extrinsic(np.zeros(3), np.zeros(3))


def test_the_lever_is_the_mean_inverse_depth_of_what_the_score_rests_on() -> None:
    for depth in (2.5, 10.0, 40.0):
        scenes, camera, at = _wall(depth)
        stack = SceneStack.build(scenes, camera, sigma=1.0)
        assert np.isclose(rotation_lever(stack, at), np.degrees(0.01 / depth), rtol=1e-4)
    # nothing in view: no lever
    assert np.isnan(rotation_lever(stack, Extrinsic(np.array([0.0, np.pi, 0.0]), np.zeros(3))))


def test_a_rotation_fitted_to_a_shifted_translation_turns_by_the_lever(small_synth) -> None:
    """What the line claims, on the edge score: the rotation re-fitted (rotation only, as the
    verdict re-fits it) to a translation 5 cm off sideways turns by about 5 x the lever."""
    scenes, camera, truth = small_synth
    settings = CalibrationSettings(objective="edges")
    stack = stack_scenes(scenes, camera, truth, settings)
    lever = rotation_lever(stack.with_sigma(settings.sigma), truth)
    assert 0.01 < lever < 1.0
    only = replace(settings, rotation_only=True, global_search=False, coarse_to_fine=False, rotation_bound_deg=3.0)
    for shift in (np.array([0.05, 0.0, 0.0]), np.array([0.0, -0.05, 0.0])):
        fitted = refine(stack, Extrinsic(truth.rotvec, truth.translation + shift), only)
        turn = fitted.error_to(Extrinsic(truth.rotvec, fitted.translation))[0]
        assert 0.5 * 5 * lever < turn < 1.6 * 5 * lever, (turn, lever)


def _trusted_rotation(lever: float, seed_axes: str = "xyz", status: str = "trusted-rotation") -> Verdict:
    axes = translation_axes(np.array([0.25, 0.36, 0.06]), "edges", 1)
    return Verdict(status, Extrinsic(np.zeros(3), np.zeros(3)), False, ("translation observable (translation): m",),
                   (Check("translation observable (translation)", False, "m"),), 0.0, axes, seed_axes, lever=lever)


def test_the_lever_reaches_the_terminal_the_app_the_file_the_exports_and_the_report() -> None:
    from l2e_studio.app.panels.results import verdict_text
    from l2e_studio.qa.report import verdict_html

    v = _trusted_rotation(0.06)
    line = v.lever_line()
    assert "0.06 deg" in line and f"within {LEVER_TARGET_DEG / 0.06:.1f} cm" in line and "along x, y" in line
    assert f"  > {line}" in v.lines()
    assert f"→ {line}" in verdict_text(v)
    d = v.to_dict()
    assert d["rotation_per_cm_of_seed_translation"] == {"deg": 0.06, "note": line}
    assert line in export_status({"verdict": d})[1]
    assert "0.06 deg at these scenes" in verdict_html(d)
    # only the seed's x is kept: only x is named
    assert "along x:" in _trusted_rotation(0.06, seed_axes="xz").lever_line()
    # a trusted result, the seed's z alone, or no lever measured: no line, nothing in the file
    for other in (_trusted_rotation(0.06, status="trusted", seed_axes=""), _trusted_rotation(0.06, seed_axes="z"),
                  _trusted_rotation(float("nan"))):
        assert other.lever_line() == "" and "rotation_per_cm_of_seed_translation" not in other.to_dict()
