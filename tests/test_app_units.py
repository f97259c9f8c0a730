"""The workbench's parts without a browser: overlay drawing, slider <-> pose mapping, the shared
session state, file naming/saving, the MI readout and the coalescing worker."""

from __future__ import annotations

import threading
import time
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
import yaml

from app_fixtures import write_small_scenes
from l2e_studio.app.files import fresh_path, save_seed, seed_document, seed_from_upload
from l2e_studio.app.overlay import (
    OverlayStyle,
    compose_before_after,
    disc_offsets,
    draw_points,
    encode_jpeg,
    grey_rgb,
    intensity_colors,
    normalise_map,
    point_colors,
    project_scene,
    render_overlay,
    render_view,
)
from l2e_studio.app.pose import extrinsic_from_sliders, sliders_from_extrinsic
from l2e_studio.geometry import LIDAR_TO_CAMERA_AXES
from l2e_studio.app.state import SessionState
from l2e_studio.app.workers import LatestWorker
from l2e_studio.camera import CameraModel
from l2e_studio.errors import InputError
from l2e_studio.geometry import Extrinsic, project_points
from l2e_studio.io.cameras import load_seed


def lidar_to_optical(t=(0.05, -0.1, 0.02)) -> Extrinsic:
    T = np.eye(4)
    T[:3, :3] = LIDAR_TO_CAMERA_AXES
    T[:3, 3] = t
    return Extrinsic.from_matrix(T)


CAMERA = CameraModel(np.array([[100.0, 0, 31.5], [0, 100.0, 23.5], [0, 0, 1]]), 64, 48)


# --- overlay ---------------------------------------------------------------------------------------

def test_draw_points_paints_discs_at_rounded_pixels():
    base = np.zeros((20, 30, 3), np.uint8)
    uv = np.array([[5.2, 4.9], [29.4, 19.4], [-3.0, 5.0], [10.0, 19.6]])  # the last two are off the image
    colors = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [9, 9, 9]], np.uint8)
    out = draw_points(base, uv, colors, point_size=1, opacity=1.0)
    assert out[5, 5].tolist() == [255, 0, 0]
    assert out[19, 29].tolist() == [0, 255, 0]
    assert (out.reshape(-1, 3).any(axis=1)).sum() == 2  # nothing else, nothing wraps around
    assert base.sum() == 0  # the base is not modified

    big = draw_points(base, uv[:1], colors[:1], point_size=3, opacity=1.0)
    lit = np.argwhere(big[:, :, 0] == 255)
    assert len(lit) == len(disc_offsets(3)[0]) == 9
    assert lit.min(0).tolist() == [4, 4] and lit.max(0).tolist() == [6, 6]


def test_draw_points_blends_with_opacity_and_keeps_near_points_on_top():
    base = np.full((4, 4, 3), 100, np.uint8)
    out = draw_points(base, np.array([[1.0, 1.0]]), np.array([[200, 0, 0]], np.uint8), 1, opacity=0.25)
    assert out[1, 1].tolist() == [125, 75, 75]
    # two points on one pixel: the nearer (smaller depth) wins whatever the input order
    uv = np.array([[2.0, 2.0], [2.0, 2.0]])
    cols = np.array([[0, 0, 255], [255, 0, 0]], np.uint8)
    for depth, expected in (([1.0, 5.0], [0, 0, 255]), ([5.0, 1.0], [255, 0, 0])):
        out = draw_points(base, uv, cols, 1, 1.0, depth=np.array(depth))
        assert out[2, 2].tolist() == expected


def test_disc_offsets_grow_with_size_and_are_centred():
    sizes = [len(disc_offsets(s)[0]) for s in range(1, 9)]
    assert sizes[0] == 1 and all(b >= a for a, b in zip(sizes, sizes[1:]))
    dy, dx = disc_offsets(5)
    assert dy.mean() == pytest.approx(0) and dx.mean() == pytest.approx(0)


def test_normalise_map_clips_events_and_scales_images():
    m = np.zeros((10, 10), np.float32)
    m[0, :5] = [1, 2, 3, 4, 1000]  # a hot pixel far above the clip
    m[1, 0] = np.nan
    n = normalise_map(m, "events")
    assert n.dtype == np.float32 and np.isfinite(n).all()
    assert n[0, 4] == n.max()  # clipped to 127 like the objective, then scaled
    assert n[0, 3] / n[0, 0] == pytest.approx(4.0)
    img = normalise_map(np.arange(100, dtype=np.float32).reshape(10, 10), "image")
    assert img.max() == pytest.approx(1.0) and img[0, 0] == 0
    with pytest.raises(ValueError):
        normalise_map(np.zeros((2, 2, 2)))
    g = grey_rgb(np.array([[0.0, 0.5, 1.0]]), contrast=2.0)
    assert g.shape == (1, 3, 3) and g[0, :, 0].tolist() == [0, 255, 255]


def test_render_overlay_puts_points_where_the_geometry_projects_them():
    ext = lidar_to_optical()
    pts = np.array([[5.0, 0.3, -0.2], [8.0, -0.5, 0.4], [-5.0, 0.0, 0.0]], np.float32)  # last: behind
    proj = project_scene(pts, ext, CAMERA)
    uv_ref, front = project_points(ext.transform(pts.astype(np.float64)), CAMERA)
    assert proj.index.tolist() == [0, 1] and not front[2]
    assert np.allclose(proj.uv, uv_ref[:2], atol=1e-3)
    base = np.zeros((48, 64, 3), np.uint8)
    colors = intensity_colors(np.array([255, 0, 128], np.float32))
    out = render_overlay(base, pts, ext, CAMERA, OverlayStyle(point_size=1, opacity=1.0), colors)
    for k in (0, 1):
        u, v = np.rint(uv_ref[k]).astype(int)
        assert out[v, u].tolist() == colors[k].tolist()
    depth_cols = point_colors(proj, None, "depth")
    assert depth_cols.shape == (2, 3) and not np.array_equal(depth_cols[0], depth_cols[1])


def test_overlay_style_rejects_bad_values():
    for bad in (dict(color_by="height"), dict(point_size=0), dict(opacity=1.5), dict(contrast=0)):
        with pytest.raises(ValueError):
            OverlayStyle(**bad)


def test_compose_before_after_modes():
    a = np.zeros((20, 40, 3), np.uint8)
    b = np.full((20, 40, 3), 200, np.uint8)
    side = compose_before_after(a, b, "side by side")
    assert side.shape == (10, 40, 3)
    assert compose_before_after(a, b, "side by side", scale=1.0).shape == (20, 80, 3)
    swipe = compose_before_after(a, b, "swipe", 0.25)
    assert swipe[15, 2].tolist() == [0, 0, 0] and swipe[15, 30].tolist() == [200, 200, 200]
    blend = compose_before_after(a, b, "blend", 0.5)
    assert blend[15, 30].tolist() == [100, 100, 100]
    with pytest.raises(ValueError):
        compose_before_after(a, b[:10], "blend")
    jpeg = encode_jpeg(blend)
    assert cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR).shape == blend.shape


# --- sliders <-> pose ------------------------------------------------------------------------------

def test_sliders_round_trip_and_mean_what_they_say():
    ref = lidar_to_optical()
    v = np.array([0.1, -0.2, 0.05, 2.0, -3.0, 5.0])
    ext = extrinsic_from_sliders(v, ref)
    assert np.allclose(sliders_from_extrinsic(ext, ref, near=v), v, atol=1e-9)
    assert np.allclose(ext.translation, v[:3])
    assert np.allclose(sliders_from_extrinsic(ref, ref)[3:], 0, atol=1e-12)
    # yaw turns the view about the up axis: a point straight ahead moves sideways, not up/down
    ahead = np.array([[10.0, 0.0, 0.0]])
    moved = extrinsic_from_sliders([0, 0, 0, 0, 0, 5.0], ref).transform(ahead)[0]
    assert abs(moved[0]) > 0.5 and abs(moved[1]) < 1e-9
    # pitch tilts: the same point moves up or down
    moved = extrinsic_from_sliders([0, 0, 0, 0, 5.0, 0], ref).transform(ahead)[0]
    assert abs(moved[1]) > 0.5 and abs(moved[0]) < 1e-9


def test_sliders_stay_near_their_current_values():
    ref = lidar_to_optical()
    v = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 179.0])
    ext = extrinsic_from_sliders(v, ref)
    near = np.array([0, 0, 0, 0, 0, 178.0])
    assert sliders_from_extrinsic(ext, ref, near=near)[5] == pytest.approx(179.0)
    ext2 = extrinsic_from_sliders([0, 0, 0, 0, 0, 181.0], ref)  # same as -179
    assert sliders_from_extrinsic(ext2, ref, near=near)[5] == pytest.approx(181.0)


# --- state -----------------------------------------------------------------------------------------

def test_session_state_rules():
    ref = lidar_to_optical()
    st = SessionState(["a", "b", "c"], reference=ref)
    assert st.snapshot().extrinsic is ref and st.included == [True] * 3
    v0 = st.version
    moved = ref.perturbed([0.01, 0, 0], [0, 0, 0])
    st.set_extrinsic(moved)
    assert st.version > v0 and st.snapshot().extrinsic is moved
    st.set_included(1, False)
    assert st.snapshot().included == (True, False, True)
    with pytest.raises(IndexError):
        st.select(3)

    run = st.begin_run()
    with pytest.raises(RuntimeError):
        st.begin_run()
    best = moved.perturbed([0, 0.01, 0], [0, 0, 0])
    assert st.record_progress(run, 1, 0.2, 0.2, best, 0.1)
    assert not st.record_progress(run + 7, 2, 0.3, 0.3, best, 0.2)  # stale run: ignored
    snap = st.snapshot()
    assert snap.run.history == ((1, 0.2, 0.2, 0),) and snap.shown_extrinsic is best  # following the best
    st.set_follow_best(False)
    assert st.snapshot().shown_extrinsic is moved

    result = SimpleNamespace(extrinsic=best, cancelled=True)
    assert st.finish_run(run, result)
    assert st.snapshot().run.status == "cancelled" and st.snapshot().result is result
    assert st.accept_result() is best and st.snapshot().extrinsic is best
    st.discard_result()
    with pytest.raises(RuntimeError):
        st.accept_result()
    assert st.reset_extrinsic() is ref

    st.set_all_included(False)
    with pytest.raises(RuntimeError):
        st.begin_run()  # nothing to optimise over
    run = (st.set_all_included(True), st.begin_run())[1]
    st.finish_run(run, error="boom")
    assert st.snapshot().run.status == "failed" and st.snapshot().run.error == "boom"


# --- files -----------------------------------------------------------------------------------------

def test_fresh_path_never_reuses_a_name(tmp_path):
    import datetime as dt

    when = dt.datetime(2024, 5, 6, 7, 8, 9)
    first = fresh_path(tmp_path, "l2e_result", ".yaml", when)
    first.write_text("x")
    second = fresh_path(tmp_path, "l2e_result", ".yaml", when)
    assert first.name == "l2e_result_20240506-070809.yaml"
    assert second != first and not second.exists()


def test_seed_files_round_trip_through_the_engine_reader(tmp_path):
    ext = lidar_to_optical().perturbed([0.01, 0.02, -0.03], [0.01, -0.02, 0.005])
    path = save_seed(tmp_path, ext)
    assert np.allclose(load_seed(path).params, ext.params, atol=1e-9)
    assert np.allclose(seed_from_upload("mine.yaml", seed_document(ext)).params, ext.params, atol=1e-9)
    matrix_txt = "\n".join(" ".join(f"{x:.12f}" for x in row) for row in ext.matrix).encode()
    assert np.allclose(seed_from_upload("T.txt", matrix_txt).params, ext.params, atol=1e-8)
    with pytest.raises(InputError, match="unsupported seed file type"):
        seed_from_upload("seed.exe", b"MZ")
    with pytest.raises(InputError, match="broken.yaml"):
        seed_from_upload("broken.yaml", b"seed: {translation: [1, 2]}\n")
    doc = yaml.safe_load(seed_document(ext))
    assert np.allclose(doc["seed"]["rotvec"], ext.rotvec)


# --- MI readout --------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def small_set(tmp_path_factory):
    from l2e_studio.scenes import load_scene_folder

    return load_scene_folder(write_small_scenes(tmp_path_factory.mktemp("units") / "s", n_scenes=3))


def test_readout_pools_included_scenes_like_a_stack_of_those_scenes(small_set):
    from l2e_studio.app.readout import MiReadout
    from l2e_studio.objective import SceneStack

    ss = small_set
    readout = MiReadout(ss.scenes, ss.camera, ss.seed, sigma=5.0)
    ext = ss.seed.perturbed([0.01, 0, 0], [0, 0.002, 0])
    everything = readout.read(ext, [True, True, True])
    full = SceneStack.build(ss.scenes, ss.camera, 5.0)
    total, per = full.mi(ext)
    assert everything.total == pytest.approx(total, rel=1e-9)
    assert np.allclose(everything.per_scene, per)
    subset = readout.read(ext, [True, False, True])
    sub_total, _ = SceneStack.build([ss.scenes[0], ss.scenes[2]], ss.camera, 5.0).mi(ext)
    assert subset.total == pytest.approx(sub_total, rel=1e-9)
    assert np.allclose(subset.per_scene, per)  # per-scene values do not depend on the inclusion
    readout.set_sigma(2.0)
    assert readout.read(ext, [True] * 3).total != pytest.approx(everything.total)


# --- worker -----------------------------------------------------------------------------------------

def test_latest_worker_coalesces_bursts_and_runs_after_the_last_poke():
    seen: list[int] = []
    counter = {"value": 0}
    gate = threading.Event()

    def job() -> None:
        gate.wait(2)
        seen.append(counter["value"])

    worker = LatestWorker("test", job)
    try:
        for i in range(1, 51):
            counter["value"] = i
            worker.poke()
        gate.set()
        assert worker.wait_idle(5)
        assert seen[-1] == 50  # the last state was drawn
        assert len(seen) <= 3  # 50 pokes, a handful of runs
        time.sleep(0.05)
        assert worker.runs == len(seen)
    finally:
        worker.stop()


# --- points at their screen size (render_view) -----------------------------------------------------

def _one_point_view(window=None, width=None, screen_width=None, outline=0, size=3):
    """One point at map pixel (32, 24) of a 64x48 grey map, drawn through render_view."""
    ext = lidar_to_optical((0.0, 0.0, 0.0))
    # a point on the optical axis 10 m ahead projects onto the principal point (31.5, 23.5)
    pts = np.array([[10.0, 0.0, 0.0]], np.float32)
    base = np.full((48, 64, 3), 128, np.uint8)
    style = OverlayStyle(point_size=size, opacity=1.0, outline=outline)
    colors = intensity_colors(np.array([255.0], np.float32))
    return render_view(base, pts, ext, CAMERA, style, colors, window, width, screen_width, pixelated=window is not None)


def _lit(img, colour):
    return np.argwhere(np.all(img == colour, axis=2))


def test_points_keep_their_screen_size_at_any_zoom_and_map_size():
    colour = intensity_colors(np.array([255.0], np.float32))[0]
    # the whole 64-px map shown 640 px wide, and a 4x window of it shown at the same width
    fit = _one_point_view(width=640, screen_width=640)
    zoomed = _one_point_view(window=(16, 12, 32, 24), width=640, screen_width=640)
    for img in (fit, zoomed):
        lit = _lit(img, colour)
        assert len(lit) == len(disc_offsets(3)[0])  # 3 px across on screen either way
    # centred where the map pixel lands: (31.5 + 0.5) * 10 - 0.5 in the fit frame
    assert _lit(fit, colour).mean(axis=0) == pytest.approx([239.5, 319.5], abs=1.0)
    assert _lit(zoomed, colour).mean(axis=0) == pytest.approx([(23.5 + 0.5 - 12) * 20 - 0.5, (31.5 + 0.5 - 16) * 20 - 0.5],
                                                             abs=1.0)
    # the map's pixels are blocks in the zoomed frame (nearest neighbour), not smoothed
    assert zoomed.shape == (480, 640, 3)
    # drawn at map resolution for a file, as if shown 16 px wide: discs scaled up 4x
    big = _one_point_view(screen_width=16)
    assert len(_lit(big, colour)) == len(disc_offsets(12)[0])


def test_outline_darkens_a_ring_around_each_disc():
    colour = intensity_colors(np.array([255.0], np.float32))[0]
    img = _one_point_view(width=640, screen_width=640, outline=1)
    disc = _lit(img, colour)
    dark = np.argwhere(np.all(img == 32, axis=2))  # 128 >> 2
    assert len(disc) == len(disc_offsets(3)[0]) and len(dark) > 0
    assert np.abs(dark - disc.mean(axis=0)).max() <= 3  # a thin ring, next to the disc
    assert (img == 128).all(axis=2).sum() == 640 * 480 - len(disc) - len(dark)  # nothing else changes


def test_point_colours_skip_the_dark_ends_of_turbo_and_depth_is_the_default_on_photos():
    from l2e_studio.app.overlay import default_color_by
    from l2e_studio.drawing import point_table

    lum = point_table().astype(float) @ [0.299, 0.587, 0.114]
    assert lum.min() > 60  # turbo's own ends are ~30-45: dark purple / dark red on dark asphalt
    assert default_color_by("image") == "depth" and default_color_by("events") == "intensity"


# --- pairs for PnP ---------------------------------------------------------------------------------

def test_pair_spread_flags_far_only_pairs_and_passes_near_and_far_ones():
    from l2e_studio.app.pairs import Pair, pair_spread, solve_pnp, translation_warning

    cam = CameraModel(np.array([[700.0, 0, 640], [0, 700.0, 360], [0, 0, 1]]), 1280, 720)
    ext = lidar_to_optical((0.1, -0.2, 0.05))
    rng = np.random.default_rng(0)

    def pairs_between(near, far, n=8):
        pts = np.column_stack([rng.uniform(near, far, n), rng.uniform(-0.5, 0.5, n) * near,
                               rng.uniform(-0.3, 0.3, n) * near])
        uv, _ = project_points(ext.transform(pts), cam)
        return [Pair(tuple(p), tuple(q)) for p, q in zip(pts, uv)]

    good = pairs_between(3.0, 15.0)
    spread = pair_spread(solve_pnp(good, cam), good, cam)
    assert spread.translation_std.max() < 0.02 and translation_warning(spread, 0.2 / 3) == ""
    far = pairs_between(38.0, 45.0)
    spread = pair_spread(solve_pnp(far, cam), far, cam)
    assert spread.translation_std.max() > 0.2  # ±20 cm and more: the seed's translation is a guess
    text = translation_warning(spread, 0.2 / 3)
    assert "close to the camera" in text and "other distances" in text and "40." in text
    # two pairs cannot pin six parameters
    assert not np.isfinite(pair_spread(ext, good[:2], cam).translation_std).any()


def test_default_point_size_follows_the_scan_density():
    from l2e_studio.app.overlay import default_point_size

    assert default_point_size(20_000, 727, 220) == 2  # a 64-beam scan on KITTI's letterbox image
    assert default_point_size(6_000, 727, 546) == 3  # a 16-beam scan on a 4:3 photo
    assert default_point_size(50, 727, 546) == 5 and default_point_size(0, 727, 546) == 5  # never huge
