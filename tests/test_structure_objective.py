"""The structure-aware objective, map kinds from content, and the verdict (issue: trustworthy
calibrations on real recordings)."""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from l2e_studio.calibrate import CalibrationSettings, calibrate, stack_scenes
from l2e_studio.camera import CameraModel
from l2e_studio.geometry import Extrinsic
from l2e_studio.io.maps import load_map, looks_like_photo
from l2e_studio.objective import EdgeObjective, SceneStack
from l2e_studio.scenes import Scene
from l2e_studio.scoring import objective_for
from l2e_studio.verdict import judge

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from realdata_rigs import load_rigs, perturbations  # noqa: E402
from box_world import box_world  # noqa: E402


def test_edge_objective_gradient_matches_finite_differences() -> None:
    scene, cam, truth = box_world(np.random.default_rng(0))
    stack = SceneStack.build([scene], cam, 3.0, objective="edges")
    obj = stack.objective(truth)
    assert isinstance(obj, EdgeObjective)
    delta = np.array([0.01, -0.02, 0.03, 0.004, -0.006, 0.003])
    _, g = obj.value_and_grad(delta)
    for k, h in enumerate([1e-4] * 3 + [1e-5] * 3):
        e = np.zeros(6)
        e[k] = h
        fd = (obj.value(delta + e) - obj.value(delta - e)) / (2 * h)
        assert g[k] == pytest.approx(fd, rel=0.05, abs=2e-3 * max(1.0, abs(fd))), (k, g[k], fd)


def test_edges_objective_moves_towards_the_truth_and_the_verdict_never_hands_back_worse() -> None:
    scene, cam, truth = box_world(np.random.default_rng(1))
    seed = truth.perturbed(np.array([0.03, -0.02, 0.0]), np.radians([1.0, -1.0, 0.5]))
    settings = CalibrationSettings()
    stack = stack_scenes([scene], cam, seed, settings)
    assert stack.objective_name == "edges"
    result = calibrate(stack, None, seed, settings)
    deg, _ = result.extrinsic.error_to(truth)
    # (one scene whose boxes' top and bottom are no lidar edges -- only left and right
    # neighbours are compared -- so the pitch is held by where the vertical edges end: the
    # optimiser gets 1.5 -> 0.87 deg here, where the earlier detector, which marked 99 % of the
    # points as edges, got 0.58)
    assert deg < 0.6 * seed.error_to(truth)[0]
    verdict = judge(stack, result, settings)
    # whatever the verdict, what it hands back is never further from the truth than the seed
    assert verdict.extrinsic.error_to(truth)[0] <= seed.error_to(truth)[0] + 1e-9


def test_objective_follows_the_map_kind() -> None:
    assert objective_for(["events", "events"]) == "mi"
    assert objective_for(["events", "image"]) == "edges"
    assert objective_for(["image"], "mi") == "mi"
    with pytest.raises(ValueError):
        objective_for(["image"], "nope")


def test_a_photo_under_event_is_read_as_an_image(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    ramp = np.linspace(30, 230, 160, dtype=np.float32)[None, :].repeat(120, axis=0)  # shading
    photo = ramp + cv2.GaussianBlur(rng.normal(0, 20, (120, 160)).astype(np.float32), (0, 0), 2)
    events = np.zeros((120, 160), np.float32)
    events[rng.integers(0, 120, 3000), rng.integers(0, 160, 3000)] = rng.integers(1, 60, 3000)
    (tmp_path / "event").mkdir()
    cv2.imwrite(str(tmp_path / "event" / "a.png"), np.clip(photo * 1.0, 0, 255).astype(np.uint8))
    cv2.imwrite(str(tmp_path / "event" / "b.png"), events.astype(np.uint8))
    assert looks_like_photo(photo) and not looks_like_photo(events)
    assert load_map(tmp_path / "event" / "a.png")[1] == "image"
    assert load_map(tmp_path / "event" / "b.png")[1] == "events"
    assert load_map(tmp_path / "event" / "a.png", kind="events")[1] == "events"


@pytest.mark.realdata
def test_real_street_scenes_never_end_worse_than_the_seed() -> None:
    """OpenCalib scene 3 (a real 64-beam lidar and a 1920x1200 camera): from seeds 2 deg / 10 cm
    off, what the tool hands back is never further from the reference than the seed; the
    paper's MI alone, which this replaces, ends degrees away and the verdict catches it."""
    rigs = load_rigs(["3"])
    if not rigs:
        pytest.skip("../shared/realdata is absent")
    rig = rigs[0]
    settings = CalibrationSettings()
    for dt, dr in perturbations(2, 2.0, 0.10, 7):
        seed = rig.reference.perturbed(dt, dr)
        stack = stack_scenes(rig.scenes, rig.camera, seed, settings)
        result = calibrate(stack, None, seed, settings)
        verdict = judge(stack, result, settings)
        s_deg, s_m = seed.error_to(rig.reference)
        e_deg, e_m = verdict.extrinsic.error_to(rig.reference)
        assert e_deg <= s_deg + 0.1 and e_m <= s_m + 0.01, (verdict.status, e_deg, e_m)
    # the MI of intensity against grey is pulled away on this street scene: not trusted, seed kept
    mi = CalibrationSettings(objective="mi", global_search=False)
    stack = stack_scenes(rig.scenes, rig.camera, seed, mi)
    result = calibrate(stack, None, seed, mi)
    verdict = judge(stack, result, mi)
    if result.extrinsic.error_to(rig.reference)[0] > s_deg + 0.1:
        assert verdict.status != "trusted" and verdict.kept_seed, verdict.checks


def test_a_side_peak_the_search_settled_on_meets_the_peak_it_missed() -> None:
    """KITTI 000008 from a seed 5 deg / 20 cm off: every start of the global search ends on
    side peaks, the best 4.6 deg from the reference with 72 % of the reference peak's score, and
    the verdict's other checks all pass there. Climbs from the far field around the result
    reach the missed peak's side: the verdict does not trust it, and says why. (With OpenCV 5.1's
    last-bit rounding the three best climbs end below 80 % of the result: a later one finds an
    end above it; the test holds on 5.0 and 5.1.)"""
    from l2e_studio.peaks import far_climbs

    rigs = load_rigs(["kitti"])
    if not rigs:
        pytest.skip("../shared/realdata is absent")
    rig = rigs[0]
    wide = CalibrationSettings(translation_bound=0.5, rotation_bound_deg=20.0)
    stack = stack_scenes(rig.scenes, rig.camera, rig.reference, wide)
    settings = CalibrationSettings()
    dt, dr = perturbations(5, 5.0, 0.20, 1002)[3]  # bench_realdata.py's seed of that run
    seed = rig.reference.perturbed(dt, dr)
    result = calibrate(stack, None, seed, settings)
    if result.extrinsic.error_to(rig.reference)[0] < 2.0:
        pytest.skip("the search found the reference's peak from this seed on this build")
    climbs = far_climbs(stack, result, settings)
    assert any(e.error_to(result.extrinsic)[0] > 0.6 and s > 0.8 * result.score_result for e, s in climbs)
    verdict = judge(stack, result, settings)
    assert verdict.status == "not-trusted" and verdict.kept_seed
    assert any(r.startswith("a single peak") and "climbs from the far field" in r for r in verdict.reasons)


def test_edge_agreement_and_edge_score_take_points_on_the_image_border():
    """A point projecting exactly onto the far border (u = W - 0.5) rounds to column W with
    numpy's rint: it must count as off the image, not index past the map (a real-data crash)."""
    from l2e_studio.evidence import edge_agreement

    cam = CameraModel(np.array([[64.0, 0, 31.5], [0, 64.0, 23.5], [0, 0, 1]]), 64, 48)
    rng = np.random.default_rng(4)
    pts = np.column_stack([rng.uniform(-0.4, 0.4, 400), rng.uniform(-0.3, 0.3, 400), rng.uniform(1.5, 3.0, 400)])
    pts[:4] = [[1.0, 0.0, 2.0], [1.0, 0.2, 2.0], [0.0, 0.75, 2.0], [-0.9921875, 0.0, 2.0]]  # u = 63.5, v = 47.5, u = -0.5
    img = np.zeros((48, 64), np.float32)
    img[:, 40:] = 200.0
    scene = Scene("border", pts.astype(np.float32), rng.uniform(0, 255, 400).astype(np.float32), img, "image")
    stack = SceneStack.build([scene], cam, 2.0, objective="edges")
    ident = Extrinsic(np.zeros(3), np.zeros(3))
    share = edge_agreement(stack)(ident)
    assert 0.0 <= share <= 1.0
    total, per = stack.edge_scores(ident)
    assert np.isfinite(total) and np.isfinite(per).all()
    pix = stack.pixels(ident)
    assert pix.max() < 64 * 48 and (pix >= -1).all()


def test_a_rival_peak_nearly_as_high_makes_the_answer_ambiguous():
    """Two starts ending far apart with nearly the same score: the data cannot tell them apart,
    whichever the final score picked; ends near the result, or far but clearly lower, are fine."""
    from dataclasses import replace as dc_replace

    from l2e_studio.calibrate import CalibrationResult
    from l2e_studio.peaks import RIVAL_CLIMBS, RIVAL_DEG, rival_check

    res = Extrinsic(np.zeros(3), np.zeros(3))
    far = Extrinsic(np.radians([0.0, 0.0, 2.5 * RIVAL_DEG]), np.zeros(3))
    near = Extrinsic(np.radians([0.0, 0.3, 0.0]), np.zeros(3))
    base = CalibrationResult(res, far, CalibrationSettings(), ["a"], 0.5, 1.0, np.zeros(1), np.zeros(1), 10, 1.0,
                             objective="edges")
    assert rival_check(base) is None  # no global search: nothing to compare
    assert not rival_check(dc_replace(base, ends=((res, 1.0), (far, 0.95)))).passed
    assert rival_check(dc_replace(base, ends=((res, 1.0), (far, 0.6), (near, 0.99)))).passed
    check = rival_check(dc_replace(base, ends=((res, 1.0), (far, 0.93))))
    assert "93 %" in check.detail and f"{2.5 * RIVAL_DEG:.1f} deg" in check.detail
    # a second peak 1.5 deg away at 85 % (OpenCalib's two-scene rig): further apart than two
    # answers may be and still agree, scored alike: not a single answer
    second = Extrinsic(np.radians([1.5, 0.0, 0.0]), np.zeros(3))
    assert not rival_check(dc_replace(base, ends=((res, 1.0), (second, 0.85)))).passed
    # an end of a climb from around the result counts like a start's, and a higher one is named
    climbed = rival_check(dc_replace(base, ends=((res, 1.0), (far, 0.6))), climbs=((second, 1.1),))
    assert not climbed.passed and "a higher peak the search missed" in climbed.detail
    # beyond the first RIVAL_CLIMBS climbs only a higher end counts: many climbs on a rugged
    # landscape find some end nearly as high, a higher one is a peak the search missed
    lower = (far, 0.5)
    late = (lower,) * RIVAL_CLIMBS
    assert rival_check(dc_replace(base, ends=((res, 1.0), (far, 0.6))), climbs=late + ((second, 0.9),)).passed
    assert not rival_check(dc_replace(base, ends=((res, 1.0), (far, 0.6))),
                           climbs=late[:RIVAL_CLIMBS - 1] + ((second, 0.9),)).passed
    beaten = rival_check(dc_replace(base, ends=((res, 1.0), (far, 0.6))), climbs=late + ((near, 1.2), (second, 1.05)))
    assert not beaten.passed and "105 %" in beaten.detail  # (the near one is the result's own peak)


def test_translation_axes_name_what_to_record() -> None:
    from l2e_studio.verdict import AXIS_ADVICE, translation_axes

    axes = translation_axes(np.array([0.4, 0.15, 0.01]), "edges", 3)
    assert [a.pinned for a in axes] == [True, True, False]
    z = axes[2]
    assert z.line().startswith("z is not pinned") and AXIS_ADVICE["z"] in z.line()
    assert "left and right edges" in z.line()
    # one scene pins no axis, however much a move costs: its translation trades against its rotation
    one = translation_axes(np.array([0.4, 0.15, 0.01]), "edges", 1)
    assert not any(a.pinned for a in one) and one[0].drop == 0.4
    assert "one scene cannot pin" in one[0].line() and one[0].line().endswith(AXIS_ADVICE["x"])


def test_the_significance_of_a_peak_separates_a_real_peak_from_noise() -> None:
    """At the truth of the box world the score stands far above its own far field, and far above
    a seed 2 deg off; on an image of pure noise no pose does, nor does the truth rise above that
    seed by more than the noise's own fluctuation."""
    from l2e_studio.peaks import noise_ceiling, significance
    from l2e_studio.verdict import SIGNIFICANT

    scene, cam, truth = box_world(np.random.default_rng(1))
    settings = CalibrationSettings()
    seed = truth.perturbed(np.zeros(3), np.radians([1.2, -1.2, 1.0]))
    stack = stack_scenes([scene], cam, truth, settings).with_sigma(settings.sigma)
    real = significance(stack, truth, settings, seed)
    # 5.7 deviations: above the expected best of noise over the box (5.6), under the level it
    # passes once in a hundred (5.96, since stop 42); this one sparse scan of one place is not
    # trusted for that (nor for its place), but its truth stands clear of the noise's own peak
    assert 5.0 < real.z < real.need, real.check().detail
    assert real.rise > 3 * SIGNIFICANT and real.noise > 0
    assert significance(stack, truth, settings, truth).rise == 0.0 and np.isnan(significance(stack, truth, settings).rise)
    noise = np.random.default_rng(2).uniform(0, 255, scene.event_map.shape).astype(np.float32)
    noisy = stack_scenes([Scene("noise", scene.points, scene.intensity, noise, "image")], cam, truth, settings)
    fake = significance(noisy.with_sigma(settings.sigma), truth, settings, seed)
    assert not fake.check().passed and fake.z < real.z - 2, fake.check().detail
    assert fake.rise < SIGNIFICANT
    assert 5.0 < noise_ceiling(settings) < 6.0  # +-10 deg at 0.1 deg cells


def test_a_verdict_says_which_axes_come_from_the_seed_and_what_to_record() -> None:
    from l2e_studio.verdict import Verdict, translation_axes

    axes = translation_axes(np.array([0.3, 0.2, 0.04]), "edges", 2)
    v = Verdict("trusted-rotation", Extrinsic(np.zeros(3), np.zeros(3)), False, ("r",), (), 0.0, axes, "z")
    assert "translation along x, y trusted" in v.summary() and "along z" in v.summary()
    d = v.to_dict()
    assert d["translation_from_seed"] == ["z"]
    assert d["translation_axes"]["x"] == {"pinned": True, "score_drop": 0.3}
    assert "left and right edges" in d["translation_axes"]["z"]["advice"]
    assert v.lines()[-1].startswith("  > z is not pinned")


def test_outside_evidence_that_fails_hands_back_the_seed() -> None:
    from l2e_studio.verdict import Check, Verdict, with_check

    seed = Extrinsic(np.zeros(3), np.array([0.0, 0.0, 0.1]))
    result = Extrinsic(np.radians([0.0, 1.0, 0.0]), np.zeros(3))
    v = Verdict("trusted", result, False, (), (), 0.0, (), "")
    ok = with_check(v, Check("boards agree", True, "1.0 cm RMS"), seed)
    assert ok.status == "trusted" and ok.extrinsic is result and ok.checks[-1].name == "boards agree"
    bad = with_check(v, Check("boards agree", False, "9.0 cm RMS"), seed)
    assert bad.status == "not-trusted" and bad.kept_seed and bad.extrinsic is seed
    assert bad.reasons == ("boards agree: 9.0 cm RMS",)


def test_one_scene_is_split_into_strips_and_never_hands_back_its_own_translation() -> None:
    """A single scan's halves are alternate vertical strips (each keeps the image's width, no point
    shared), and whatever its checks say, its translation is the seed's: one scene pins no axis."""
    from l2e_studio.evidence import HALF_STRIPS, halves

    scene, cam, truth = box_world(np.random.default_rng(3))
    settings = CalibrationSettings()
    seed = truth.perturbed(np.array([0.03, -0.02, 0.02]), np.radians([1.0, -1.0, 0.5]))
    stack = stack_scenes([scene], cam, seed, settings)
    a, b = halves(stack, truth)
    assert not (a & b).any() and (a | b).all()
    uv, inside = stack.project(truth)
    for half in (a, b):  # both halves reach across the image (a left or right half spans at most its half)
        u = uv[half & inside, 0]
        assert u.max() - u.min() > 0.75 * cam.width
        assert len(np.unique(np.floor(u * HALF_STRIPS / cam.width))) == HALF_STRIPS // 2
    result = calibrate(stack, None, seed, settings)
    assert result.extrinsic.error_to(truth)[0] < 0.6 * seed.error_to(truth)[0]
    verdict = judge(stack, result, settings)
    # the optimiser's translation is 11 cm off here, the seed's 4 cm: one scene pins no axis.
    # Its scan lines lie 1.6 deg apart and it is one place: since stop 42 its rotation is not
    # trusted either (places for a sparse lidar), and the seed is handed back whole
    assert all(a.one_place and not a.pinned for a in verdict.translation)
    assert np.array_equal(verdict.extrinsic.translation, seed.translation)
    assert [c.passed for c in verdict.checks if c.name == "places for a sparse lidar"] == [False]
    assert verdict.status == "not-trusted" and verdict.kept_seed, verdict.reasons
