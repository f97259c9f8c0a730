"""QA engine on small synthetic scenes with a known answer: held-out tables, landscapes,
uncertainty, guardrails, and studies through local processes and a real Dask LocalCluster."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from l2e_studio.calibrate import CalibrationSettings, calibrate, stack_scenes
from l2e_studio.errors import InputError
from l2e_studio.geometry import Extrinsic
from l2e_studio.scoring.mi import mi_from_joint_histogram
from l2e_studio.qa import AXES, guardrails
from l2e_studio.qa.heldout import Candidate, difference, group_masks, score, split_scenes
from l2e_studio.qa.landscape import sweep1d, sweep2d, sweeps
from l2e_studio.qa.studies import (
    StackSource, check_study_args, correction, open_executor, repeatability_specs, scene_count_specs, study,
)
from l2e_studio.qa.uncertainty import curvature, from_half_samples, half_sample_specs
from l2e_studio.scenes import Scene
from l2e_studio.synth import SynthConfig, make_rig, make_scene, write_dataset

TINY = SynthConfig(n_scenes=6, width=320, height=180, points_per_scan=5000, seed=3)


@pytest.fixture(scope="module")
def tiny():
    camera, truth, seed = make_rig(TINY)
    scenes = []
    for i in range(TINY.n_scenes):
        p, it, m = make_scene(TINY, i, truth, camera)
        scenes.append(Scene(("checker_" if i < 2 else "street_") + f"{i:02d}", p, it, m.astype(np.float32)))
    stack = stack_scenes(scenes, camera, seed, CalibrationSettings())
    return stack, camera, truth, seed


@pytest.fixture(scope="module")
def tiny_dir(tmp_path_factory):
    return write_dataset(tmp_path_factory.mktemp("qa") / "tiny", SynthConfig(n_scenes=4, width=320, height=180,
                                                                             points_per_scan=5000, seed=3))


# --- held-out tables -----------------------------------------------------------------------------

def test_score_table_numbers_are_the_papers_mi_per_scene_per_group_and_held_out(tiny):
    stack, _, truth, seed = tiny
    held = split_scenes(stack.names, ["street_05"])
    res = calibrate(stack.subset(np.flatnonzero(~held)), None, seed, CalibrationSettings())
    cands = [Candidate("seed", seed), Candidate("result", res.extrinsic), Candidate("truth", truth)]
    table = score(stack, cands, {"checker": ["checker_*"]}, held)
    for i, c in enumerate(cands):
        total, per = stack.mi(c.extrinsic)
        assert np.allclose(table.per_scene[i], per)
        assert table.pooled["all"][i] == pytest.approx(total)
        assert table.pooled["checker"][i] == pytest.approx(stack.mi(c.extrinsic, pooled=np.arange(6) < 2)[0])
        assert table.pooled["rest"][i] == pytest.approx(stack.mi(c.extrinsic, pooled=np.arange(6) >= 2)[0])
        assert table.pooled["held out"][i] == pytest.approx(per[5])  # one held-out scene: its own MI
        joints = stack.joint_histograms(c.extrinsic)
        assert table.points_in_image[i].tolist() == joints.sum(axis=(1, 2)).astype(int).tolist()
        assert mi_from_joint_histogram(joints[5]) == pytest.approx(table.per_scene[i, 5])
    # calibrated without it, the result still beats the seed on the held-out scene and is near the truth
    assert table.pooled["held out"][1] > table.pooled["held out"][0] + 0.05
    assert table.pooled["held out"][1] == pytest.approx(table.pooled["held out"][2], abs=0.01)
    d = table.differences[("result", "truth")]
    deg, m = res.extrinsic.error_to(truth)
    assert d["rotation_deg"] == pytest.approx(deg) and d["translation_mm"] == pytest.approx(1000 * m)
    assert d["rotation_deg"] < 0.3 and d["translation_mm"] < 30
    assert table.differences[("seed", "truth")]["rotation_deg"] == pytest.approx(2.0, abs=1e-6)  # the synth seed error
    assert table.best("held out") in ("result", "truth")
    assert guardrails.held_out_below_seed(table) == []
    d = table.to_dict()
    assert d["scenes"][5]["held_out"] is True and d["groups"]["checker"]["scenes"] == 2


def test_held_out_below_the_seed_is_flagged(tiny):
    stack, _, truth, seed = tiny
    bad = truth.perturbed([0.1, 0, 0], np.radians([3, 0, 0]))
    table = score(stack, [Candidate("seed", truth), Candidate("result", bad)], None, split_scenes(stack.names, ["street_*"]))
    codes = [w.code for w in guardrails.held_out_below_seed(table)]
    assert codes == ["held_out_below_seed", "scenes_below_seed"]


def test_groups_and_splits():
    names = ["checker_a", "checker_b", "street_a"]
    m = group_masks(names, {"c": ["checker*"]})
    assert m["c"].tolist() == [True, True, False] and m["rest"].tolist() == [False, False, True] and m["all"].all()
    assert split_scenes(names, fraction=0.34, rng_seed=1).sum() == 1
    with pytest.raises(InputError, match="every scene is held out"):
        split_scenes(names, ["*"])
    with pytest.raises(InputError, match="no scene matches"):
        split_scenes(names, ["nothing*"])


def test_difference_between_two_candidates_in_deg_and_mm():
    a = Extrinsic([1.2, -1.2, 1.2], [0.05, -0.1, 0.08])
    b = a.perturbed([0.003, -0.004, 0.0], np.radians([0.0, 0.0, 0.5]))
    d = difference(a, b)
    assert d["translation_mm"] == pytest.approx(5.0) and d["rotation_deg"] == pytest.approx(0.5)
    assert np.allclose(d["per_axis_mm"], [3, -4, 0]) and np.allclose(d["per_axis_deg"], [0, 0, 0.5])


# --- landscape, uncertainty, guardrails -------------------------------------------------------------

def test_landscape_peaks_at_the_truth_on_every_axis(tiny):
    stack, _, truth, _ = tiny
    sw = sweeps(stack, truth, span_m=0.05, span_deg=2.0, n=11)
    assert [s.axis for s in sw] == list(AXES)
    for s in sw:
        step = s.offsets[1] - s.offsets[0]
        assert abs(s.peak_offset) <= step + 1e-12, s.axis
        assert s.mi[len(s.mi) // 2] > s.mi[0] and s.mi[len(s.mi) // 2] > s.mi[-1]
        assert 0 < s.half_width() < s.offsets[-1] and s.secondary_ratio() < 0.9
    one = sweep1d(stack, truth, "yaw", 1.0, 5)
    assert one.axis == "rz" and one.mi[2] == pytest.approx(stack.mi(truth, per_scene=False)[0])
    two = sweep2d(stack, truth, "z", "rx", 0.04, 1.0, n=5)
    assert two.mi.shape == (5, 5) and np.unravel_index(np.argmax(two.mi), two.mi.shape) == (2, 2)
    assert guardrails.flat_landscape(sw) == []
    with pytest.raises(InputError):
        sweep1d(stack, truth, "w", 1.0)


def test_curvature_uncertainty_is_positive_finite_and_near_the_true_error(tiny):
    stack, _, truth, seed = tiny
    res = calibrate(stack, None, seed, CalibrationSettings())
    u = curvature(stack, res.extrinsic)
    err = np.abs(correction(truth, res.extrinsic))
    assert u.std.shape == (6,) and np.all(np.isfinite(u.std)) and np.all(u.std > 0)
    assert np.all(np.linalg.eigvalsh(u.hessian) < 0)  # a maximum
    # one calibration's error is one draw: it should sit within a few standard deviations
    assert np.all(err < 4 * u.std + np.array([1.0] * 3 + [0.01] * 3)), (err, u.std)
    with pytest.raises(InputError):
        curvature(stack.subset([0, 1]), res.extrinsic)


def test_guardrails_on_bound_few_points_few_scenes():
    seed = Extrinsic([1.2, -1.2, 1.2], [0.0, 0.0, 0.0])
    s = CalibrationSettings(translation_bound=0.1, rotation_bound_deg=5.0)
    on = seed.perturbed([0.1, 0, 0], [0, 0, 0])
    assert [w.code for w in guardrails.on_bound(on, seed, s)] == ["on_bound"]
    assert "x (+100.00 of +-100 mm)" in guardrails.on_bound(on, seed, s)[0].message
    assert guardrails.on_bound(seed.perturbed([0.05, 0, 0], [0, 0, 0]), seed, s) == []
    assert [w.code for w in guardrails.few_points(["a", "b"], np.array([5000, 10]))] == ["few_points"]
    w = guardrails.few_scenes(8, np.array([2.0, 1, 1, 0.1, 0.1, 0.1]), wanted_mm=1.0)
    assert [x.code for x in w] == ["few_scenes", "spread_too_large"] and "about 32 scenes" in w[1].message


# --- studies ---------------------------------------------------------------------------------------

def test_study_arguments_are_checked():
    with pytest.raises(InputError, match="at least one run"):
        check_study_args(0, 0.1, 1.0, ["SLSQP"])
    with pytest.raises(InputError, match=">= 0"):
        check_study_args(3, -0.1, 1.0, ["SLSQP"])
    with pytest.raises(InputError, match="unknown optimiser"):
        check_study_args(3, 0.1, 1.0, ["Adam"])
    with pytest.raises(InputError, match="1..4"):
        check_study_args(3, 0.1, 1.0, ["SLSQP"], subset=5, n_scenes=4)


def test_perturbed_seeds_are_uniform_within_the_noise():
    centre = Extrinsic([1.2, -1.2, 1.2], [0.05, -0.1, 0.08])
    specs = repeatability_specs(centre, 200, 0.05, 2.0, ["SLSQP"], n_scenes=6, subset=3)
    d = np.array([correction(centre, s.seed) for s in specs])
    assert np.all(np.abs(d[:, :3]) <= 50.0 + 1e-9) and np.all(np.abs(d[:, 3:]) <= 2.0 + 1e-9)
    assert np.abs(d[:, :3]).max() > 45 and np.abs(d[:, 3:]).max() > 1.8  # uniform: reaches the edges
    assert all(len(s.subset) == 3 for s in specs)
    counts = scene_count_specs(centre, [1, 3], 4, 0.01, 1.0, n_scenes=6)
    assert [len(s.subset) for s in counts] == [1] * 4 + [3] * 4 and {s.group for s in counts} == {1, 3}


def _check_repeatability(res, truth, n):
    assert len(res.runs) == n and not res.cancelled
    p = res.params()
    assert p.shape == (n, 6)
    # every run from a seed 2 cm / 1 deg off lands near the truth
    assert np.all(np.abs(p[:, :3]) < 40) and np.all(np.abs(p[:, 3:]) < 0.3), p  # 3-4 tiny scenes: a few cm at worst
    s = res.summary()["methods"]["SLSQP"]
    assert s["runs"] == n and s["seconds_mean"] > 0 and all(s["std"][a] is not None for a in AXES)


def test_repeatability_in_local_processes_with_progress(tiny_dir):
    from l2e_studio.scenes import load_scene_folder
    from l2e_studio.synth import read_truth

    ss = load_scene_folder(tiny_dir)
    truth = read_truth(tiny_dir / "truth.yaml")
    specs = repeatability_specs(ss.seed, 4, 0.02, 1.0, ["SLSQP"], 4, rng_seed=2)
    seen = []
    res = study("repeatability", StackSource(folder=str(tiny_dir)), ss.seed, CalibrationSettings(), specs, 0.02, 1.0,
                truth=truth, workers=2, on_progress=lambda done, total, run: seen.append((done, total)))
    _check_repeatability(res, truth, 4)
    assert seen == [(1, 4), (2, 4), (3, 4), (4, 4)]
    assert "2 local processes" in res.executor
    assert res.summary()["reference"] == "truth"


def test_repeatability_through_a_dask_localcluster_gives_the_same_runs(tiny_dir):
    distributed = pytest.importorskip("distributed", reason="dask[distributed] is not installed")
    from l2e_studio.scenes import load_scene_folder
    from l2e_studio.synth import read_truth

    ss = load_scene_folder(tiny_dir)
    truth = read_truth(tiny_dir / "truth.yaml")
    specs = repeatability_specs(ss.seed, 4, 0.02, 1.0, ["SLSQP"], 4, subset=3, rng_seed=5)
    source = StackSource(folder=str(tiny_dir))
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        res = study("repeatability", source, ss.seed, CalibrationSettings(), specs, 0.02, 1.0, truth=truth,
                    dask=cluster.scheduler_address)
        worker_pids = {info["pid"] for info in cluster.scheduler_info["workers"].values()} if "pid" in next(
            iter(cluster.scheduler_info["workers"].values())) else None
    assert res.executor.startswith("dask tcp://") and "(2 workers)" in res.executor
    _check_repeatability(res, truth, 4)
    if worker_pids:
        assert {r["worker_pid"] for r in res.runs} <= worker_pids
    local = study("repeatability", source, ss.seed, CalibrationSettings(), specs, 0.02, 1.0, truth=truth, workers=1)
    # the same code path: the same runs give the same results, wherever they ran
    assert np.allclose(local.params(), res.params(), atol=1e-6)
    assert [r["scenes"] for r in local.runs] == [r["scenes"] for r in res.runs] == [list(s.subset) for s in specs]


def test_an_unanswered_dask_address_is_an_input_error():
    pytest.importorskip("distributed", reason="dask[distributed] is not installed")
    with pytest.raises(InputError, match="no Dask scheduler answers"):
        with open_executor("tcp://127.0.0.1:9", connect_timeout=1.0):
            pass


def test_a_study_is_cancellable_and_keeps_the_finished_runs(tiny):
    stack, _, truth, seed = tiny
    from concurrent.futures import ThreadPoolExecutor

    specs = repeatability_specs(seed, 12, 0.02, 1.0, ["SLSQP"], stack.n_scenes, rng_seed=1)
    cancel = threading.Event()
    with ThreadPoolExecutor(1) as ex:  # any Executor: the code path is the same
        res = study("repeatability", StackSource(stack=stack), seed, CalibrationSettings(), specs, 0.02, 1.0,
                    truth=truth, executor=ex, on_progress=lambda done, total, run: cancel.set(), cancel=cancel)
    assert res.cancelled and 1 <= len(res.runs) < 12


def test_half_sample_bootstrap_gives_a_spread_per_parameter(tiny):
    stack, _, truth, seed = tiny
    from concurrent.futures import ThreadPoolExecutor

    res = calibrate(stack, None, seed, CalibrationSettings())
    specs = half_sample_specs(res.extrinsic, stack.n_scenes, n=6, rng_seed=0)
    assert all(len(s.subset) == 3 for s in specs)
    with ThreadPoolExecutor(1) as ex:
        st = study("bootstrap", StackSource(stack=stack), res.extrinsic, CalibrationSettings(coarse_to_fine=False), specs,
                   0.0, 0.0, executor=ex)
    u = from_half_samples(st.params())
    assert u.samples == 6 and np.all(np.isfinite(u.std)) and np.all(u.std > 0)
    assert np.all(u.std[:3] < 30) and np.all(u.std[3:] < 0.5)


def test_held_out_scenes_that_the_calibration_used_are_flagged():
    assert guardrails.held_out_used(["a"], ["b", "c"]) == []
    w = guardrails.held_out_used(["a", "c"], ["b", "c"])
    assert [x.code for x in w] == ["held_out_used"] and "c" in w[0].message


def test_report_crop_is_drawn_afresh_with_points_at_the_figures_size():
    """The report's crop shows the map enlarged, not the points: it is made at least as wide
    as the full figure (a page shows an image no wider than it is; a 384 px crop beside a 640 px
    figure showed 1 px points whose colour the outline swallowed), one lidar point covers about
    as many pixels of it as of the full figure, in the point's own colour, and it sits where
    the full figure puts it, enlarged about the window."""
    from l2e_studio.camera import CameraModel
    from l2e_studio.qa import figures

    cam = CameraModel(np.array([[400.0, 0, 320], [0, 400.0, 240], [0, 0, 1]]), 640, 480, np.zeros(5))
    ext = Extrinsic(np.zeros(3), np.zeros(3))
    point = np.array([[0.25, 0.1, 4.0]])  # projects to (345, 250)
    flat = np.full((480, 640), 30.0, np.float32)
    box = (300, 200, 192, 144)
    zoom = figures.crop_factor(cam, box)
    assert zoom == 4  # 192 px x 4 = 768 >= 640; never under 2
    assert figures.crop_factor(cam, (0, 0, 600, 400)) == 2
    full = figures.overlay(flat, point, np.array([200.0]), ext, cam, map_kind="image")
    crop = figures.overlay(flat, point, np.array([200.0]), ext, cam, map_kind="image", box=box, factor=zoom)
    f = figures.display_factor(cam)
    assert full.shape[:2] == (480 * f, 640 * f) and crop.shape[:2] == (144 * zoom * f, 192 * zoom * f)
    assert crop.shape[1] >= full.shape[1]

    def disc(img):
        mask = np.any(img != img[0, 0], axis=2)
        ys, xs = np.nonzero(mask)
        return mask.sum(), xs.mean(), ys.mean()

    def coloured(img):  # pixels neither the grey map nor the darkened outline: the point's colour
        return int(np.sum(np.ptp(img.astype(int), axis=2) > 40))

    (n_full, xf, yf), (n_crop, xc, yc) = disc(full), disc(crop)
    # shown at one width, the crop's disc covers (full width / crop width)^2 of its pixels on screen
    on_screen = n_crop * (full.shape[1] / crop.shape[1]) ** 2
    assert 0.5 * n_full <= on_screen <= 2.0 * n_full, (n_crop, n_full)
    assert coloured(crop) >= 4 and coloured(full) >= 4, (coloured(crop), coloured(full))
    assert (xc, yc) == pytest.approx(((xf / f - box[0]) * zoom * f, (yf / f - box[1]) * zoom * f), abs=zoom * f)


def test_the_places_guardrail_counts_places_not_scenes():
    """On real stacks: four takes of one place warn that they pin no translation; four places do
    not warn; a few places among many scenes say how few they are."""
    from test_climbs_back import _scenes

    for same_place, codes in ((True, ["one_place"]), (False, [])):
        scenes, cam, truth = _scenes(1.0, same_place=same_place)
        stack = stack_scenes(scenes, cam, truth, CalibrationSettings())
        assert [w.code for w in guardrails.few_places(stack.places)] == codes
    w = guardrails.few_places(np.array([0, 0, 1, 1, 1, 2]))
    assert [x.code for x in w] == ["few_places"] and "6 scenes show only 3 places" in w[0].message
    assert guardrails.few_places(np.array([0])) == [] and guardrails.few_places(np.arange(3)) == []
