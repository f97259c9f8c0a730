"""Unit tests of the workbench's precision tools: undo/redo, exact number parsing, slider
ranges, settings checks (no browser, no server)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from l2e_studio.app.history import History
from l2e_studio.app.state import SessionState
from l2e_studio.geometry import Extrinsic


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_history_keeps_at_least_fifty_steps_and_redoes_them():
    h: History[int] = History(limit=200, clock=Clock())
    current = 0
    for v in range(1, 61):  # 60 separate changes ("nudge" never merges)
        h.record(current, "nudge")
        current = v
    for expected in range(59, -1, -1):
        current = h.undo(current)
        assert current == expected
    assert h.undo(current) is None
    for expected in range(1, 61):
        current = h.redo(current)
        assert current == expected
    assert h.redo(current) is None


def test_history_merges_a_drag_burst_and_a_new_change_drops_redo():
    clock = Clock()
    h: History[int] = History(merge_seconds=0.5, clock=clock)
    for v in range(5):  # one slider drag: 5 updates 0.1 s apart
        h.record(v, "sliders")
        clock.t += 0.1
    assert h.depth == (1, 0)
    clock.t += 2.0
    h.record(5, "sliders")  # a new drag after a pause
    assert h.depth == (2, 0)
    assert h.undo(6) == 5 and h.depth == (1, 1)
    h.record(5, "typed")
    assert h.depth == (2, 0)


def test_session_state_undo_covers_every_kind_of_change():
    ref = Extrinsic(np.zeros(3), np.zeros(3))
    st = SessionState(["a"], reference=ref)
    a = ref.perturbed([0.01, 0, 0], [0, 0, 0])
    b = ref.perturbed([0.02, 0, 0], [0, 0, 0])
    st.set_extrinsic(a, "nudge")
    st.set_extrinsic(b, "file")
    st.reset_extrinsic()
    assert st.snapshot().extrinsic is ref
    assert st.undo() is b and st.undo() is a and st.undo() is ref and st.undo() is None
    assert st.redo() is a and st.snapshot().extrinsic is a
    st.result = type("R", (), {"extrinsic": b})()
    st.accept_result()
    assert st.snapshot().extrinsic is b and st.undo() is a
    with pytest.raises(RuntimeError):
        SessionState(["a"], reference=ref).accept_result()


def test_parse_number_takes_every_value_and_refuses_the_rest():
    from l2e_studio.app.exact import format_value, is_partial, parse_number

    assert parse_number("-0.1234") == -0.1234
    assert parse_number(" −0,5 ") == -0.5  # a pasted minus sign and a decimal comma
    assert parse_number("1e-4") == 1e-4 and parse_number("+3") == 3.0
    for bad in ("", "-", "abc", "nan", "inf", "1..2"):
        assert parse_number(bad) is None
    assert all(is_partial(t) for t in ("", "-", "+", "1e-", "-."))
    assert not is_partial("abc") and not is_partial("nan")
    assert format_value(-0.1234) == "-0.1234" and format_value(-1e-9) == "0" and format_value(2.0) == "2"


def test_centred_range_narrows_with_the_step():
    from l2e_studio.app.exact import centred_range, nudged

    assert centred_range(-1.726, 0.1, rotation=True) == pytest.approx((-11.726, 8.274))
    assert centred_range(0.0, 1.0, rotation=True) == (-90.0, 90.0)  # capped
    assert centred_range(0.05, 0.0001) == pytest.approx((0.04, 0.06))
    assert nudged(-1.726, 0.1) == pytest.approx(-1.626, abs=1e-15)


def test_seed_values_are_checked_like_the_optimiser_settings():
    from l2e_studio.app.checks import check_seed_value

    assert check_seed_value("-0.1234", "x", False).value == -0.1234
    assert check_seed_value("100", "z", False).value == 100.0 and check_seed_value("-180", "yaw", True).value == -180.0
    for text, rotation, words in (("1e9", False, "x: 1e9 m is outside [-100, 100] m"),
                                  ("1e300", True, "outside [-180, 180] °"), ("abc", False, "is not a number"),
                                  ("inf", True, "is not a number")):
        c = check_seed_value(text, "x" if not rotation else "roll", rotation)
        assert c.value is None and words in c.problem, c.problem


def test_settings_checks_refuse_instead_of_clamping():
    from l2e_studio.app.checks import check_rotation_bound, check_sigma, check_translation_bound, start_blocker

    assert check_translation_bound("0.2").value == 0.2
    # the app takes what the CLI takes (calibrate --bound-m [0, 5], --bound-deg (0, 90], --sigma [0, 200])
    assert check_translation_bound("0").value == 0.0 and check_translation_bound("5").value == 5.0
    for bad, words in (("-0.1", "outside"), ("5.5", "Rotation only"), ("nan", "not a number")):
        c = check_translation_bound(bad)
        assert c.value is None and words in c.problem
    assert check_rotation_bound("500").value is None and "500" in check_rotation_bound("500").problem
    assert check_rotation_bound("90").value == 90.0 and check_rotation_bound("0").value is None
    assert check_sigma("200").value == 200.0 and check_sigma("201").value is None
    assert check_sigma("-1").value is None and check_sigma("0").value == 0.0 and check_sigma("NaN").value is None and check_sigma("2.5").value == 2.5
    assert "no scene is included" in start_blocker(0, [], False)
    assert start_blocker(3, ["x"], False) and start_blocker(3, [], True) and start_blocker(3, [], False) == ""


def test_numbers_never_read_nan():
    from l2e_studio.app.text import num

    assert num(float("nan")) == "—" and num(None) == "—" and num(float("inf")) == "—"
    assert num(0.12345) == "0.1235" and num(0.1, signed=True) == "+0.1000"


def test_state_shows_the_result_after_a_run_until_the_extrinsic_changes():
    from types import SimpleNamespace

    ref = Extrinsic(np.zeros(3), np.zeros(3))
    st = SessionState(["a"], reference=ref)
    run = st.begin_run()
    best = ref.perturbed([0.01, 0, 0], [0, 0, 0])
    st.finish_run(run, SimpleNamespace(extrinsic=best, cancelled=False))
    assert st.snapshot().shown_extrinsic is best and st.snapshot().extrinsic is ref
    st.set_extrinsic(ref.perturbed([0, 0.01, 0], [0, 0, 0]), "nudge")
    assert st.snapshot().shown_extrinsic is st.snapshot().extrinsic


def test_scan_cache_lives_in_the_user_cache_dir_not_the_data_folder(tmp_path, monkeypatch):
    from app_fixtures import write_small_scenes
    from l2e_studio.scenes import load_scene_folder

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    folder = write_small_scenes(tmp_path / "data", n_scenes=2)
    before = sorted(p.relative_to(folder) for p in folder.rglob("*"))
    load_scene_folder(folder)
    load_scene_folder(folder)  # second load: from the cache
    assert sorted(p.relative_to(folder) for p in folder.rglob("*")) == before
    cached = list((tmp_path / "cache" / "l2e-studio" / "scans").rglob("*.npy"))
    assert len(cached) == 2


def test_panels_never_import_the_server_module():
    import ast
    from pathlib import Path

    import l2e_studio.app.panels as panels

    for path in Path(panels.__file__).parent.glob("*.py"):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                assert not (node.module or "").endswith("server"), f"{path.name} imports {node.module}"


def test_previews_are_display_sized_and_settle_fires_once_after_quiet():
    import threading
    import time

    from l2e_studio.app.panels.overlay_view import DISPLAY_WIDTH, display_sized
    from l2e_studio.app.workers import Settle

    big = np.zeros((720, 1280, 3), np.uint8)
    assert display_sized(big).shape == (360, DISPLAY_WIDTH, 3)
    small = np.zeros((180, 320, 3), np.uint8)
    assert display_sized(small) is small

    fired = []
    done = threading.Event()
    settle = Settle("t", lambda: (fired.append(time.monotonic()), done.set()), quiet=0.15)
    try:
        t0 = time.monotonic()
        for _ in range(5):  # a burst: one call, 0.15 s after the last poke
            time.sleep(0.05)
            settle.poke()
            last = time.monotonic()
        assert done.wait(2.0)
        time.sleep(0.3)
        assert len(fired) == 1 and fired[0] - last >= 0.14 and fired[0] - t0 < 2.0
    finally:
        settle.stop()


def test_zoom_windows_are_native_resolution_and_clamped_to_the_map():
    from l2e_studio.app.inspect import Window, cropped, legend_html, zoom_window

    shape = (720, 1280, 3)
    assert zoom_window(shape, "fit", (0, 0), 640) == Window(0, 0, 1280, 720)
    w = zoom_window(shape, "1:1", (640, 360), 640)
    assert (w.width, w.height) == (640, 360) and (w.x0, w.y0) == (320, 180)
    corner = zoom_window(shape, "4x", (5, 5), 640)  # clamped inside the map
    assert (corner.x0, corner.y0, corner.width) == (0, 0, 160)
    img = np.arange(720 * 1280 * 3, dtype=np.uint32).reshape(shape).astype(np.uint8)
    z = cropped(img, corner)  # sent at map resolution; the browser magnifies it without smoothing
    assert z.shape == (corner.height, 160, 3) and np.array_equal(z, img[: corner.height, :160])
    assert corner.to_map(0.5, 0.5) == (80.0, corner.height / 2)
    assert "1.5 m (near)" in legend_html("depth", (1.5, 30.0)) and "intensity" in legend_html("intensity")


def test_edge_view_marks_map_edges_and_depth_edges():
    from l2e_studio.app.inspect import edge_view

    m = np.zeros((60, 80), np.float32)
    m[:, 40:] = 1.0  # one vertical map edge at x = 40
    ys, xs = np.mgrid[0:60:1, 0:80:1]
    uv = np.stack([xs.ravel(), ys.ravel()], 1).astype(float)
    depth = np.where(xs.ravel() < 40, 2.0, 10.0)  # a depth step at the same place
    out = edge_view(m, uv, depth)
    white = np.all(out == 255, axis=2)
    assert white[:, 36:44].any() and not white[:, :30].any()


def test_scene_order_sorts_by_name_points_and_mi():
    from l2e_studio.app.panels.scenes import scene_order

    names, points, mi = ["b", "a", "c"], [10, 30, 20], np.array([0.2, np.nan, 0.5])
    assert scene_order("name", names, points, mi) == [1, 0, 2]
    assert scene_order("points", names, points, mi) == [1, 2, 0]
    assert scene_order("score now (high first)", names, points, mi) == [2, 0, 1]  # NaN last
    assert scene_order("score now (low first)", names, points, mi) == [0, 2, 1]
    assert scene_order("score now (low first)", names, points, None) == [1, 0, 2]


def test_pnp_from_four_or_more_pairs_recovers_the_extrinsic():
    from l2e_studio.app.pairs import Pair, nearest_point_to_ray, reprojection_errors, solve_pnp
    from l2e_studio.camera import CameraModel
    from l2e_studio.geometry import LIDAR_TO_CAMERA_AXES, project_points

    K = np.array([[500.0, 0, 320], [0, 500.0, 180], [0, 0, 1]])
    cam = CameraModel(K, 640, 360, D=np.array([-0.05, 0.01, 0.0, 0.0, 0.0]))
    T = np.eye(4)
    T[:3, :3] = LIDAR_TO_CAMERA_AXES
    T[:3, 3] = (0.05, -0.1, 0.02)
    truth = Extrinsic.from_matrix(T).perturbed([0.01, 0.02, -0.01], [0.02, -0.01, 0.03])
    pts = np.array([[6, 1, 0.5], [8, -2, 1], [5, 0.5, -0.7], [10, 3, 0.2], [7, -1, -1.0], [9, 2, 1.5]], float)
    uv, _ = project_points(truth.transform(pts), cam)
    pairs = [Pair(tuple(p), tuple(q)) for p, q in zip(pts, uv)]
    with pytest.raises(ValueError):
        solve_pnp(pairs[:3], cam)
    got = solve_pnp(pairs, cam)
    assert np.allclose(got.params, truth.params, atol=1e-6)
    assert np.all(reprojection_errors(got, pairs, cam) < 1e-4)
    assert reprojection_errors(Extrinsic.from_matrix(T), pairs, cam).max() > 5
    # picking: the ray from the origin through point 3 finds point 3
    assert nearest_point_to_ray(pts, (0, 0, 0), pts[3]) == 3
    assert nearest_point_to_ray(pts, (0, 0, 0), (0, 0, -1)) is None


def test_panel_layout_gives_the_overlay_the_space_and_bounds_odd_reports():
    from l2e_studio.app.panels.overlay_view import panel_layout

    p1366, f1366 = panel_layout(1366)
    p1920, f1920 = panel_layout(1920)
    assert 700 <= p1366 <= 1366 - 400 - 200 and f1366 < p1366  # the 3D view keeps ~220 px
    assert p1920 > p1366 and p1920 <= 0.6 * 1920 and f1920 < p1920
    assert panel_layout(0) == panel_layout(320) and panel_layout(10**9) == panel_layout(8192)
    assert panel_layout(800)[1] >= 480


def test_frames_fit_the_byte_budget_at_the_best_quality_or_smaller():
    from l2e_studio.app.panels.overlay_view import REST_QUALITIES, jpeg_within

    smooth = np.tile(np.linspace(0, 255, 720, dtype=np.float32)[:, None, None], (1, 1280, 3)).astype(np.uint8)
    img, data, q = jpeg_within(smooth, 60_000, REST_QUALITIES)
    assert q == REST_QUALITIES[0] and img.shape == smooth.shape and len(data) <= 60_000
    noise = np.random.default_rng(0).integers(0, 256, (720, 1280, 3), dtype=np.uint8)
    img, data, q = jpeg_within(noise, 60_000, REST_QUALITIES)
    assert len(data) <= 60_000 and img.shape[1] < 1280 and q in REST_QUALITIES  # shrunk to fit
    assert cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR).shape == img.shape
    hinted, _, _ = jpeg_within(noise, 60_000, REST_QUALITIES, width=img.shape[1])
    assert hinted.shape[1] == img.shape[1]  # the width that fitted last time: no wider attempt first


def test_busy_workers_are_waited_for_against_one_deadline_not_one_timeout_each() -> None:
    """Five workers each stuck in a job: told to stop together and joined by one deadline, they
    are let go in about that time (one timeout each in turn would take five times as long); a
    job that ends in time is waited for."""
    import threading as th
    import time as tm

    from l2e_studio.app.workers import LatestWorker, join_by

    release, started = th.Event(), []
    stuck = [LatestWorker(f"stuck-{k}", lambda: (started.append(1), release.wait(30))) for k in range(5)]
    for w in stuck:
        w.poke()
    deadline = tm.monotonic() + 10
    while len(started) < 5 and tm.monotonic() < deadline:
        tm.sleep(0.01)
    assert len(started) == 5
    for w in stuck:
        w.request_stop()
    t0 = tm.monotonic()
    join_by(stuck, t0 + 1.0)
    waited = tm.monotonic() - t0
    assert 0.9 <= waited < 3.0, waited  # (in turn: 5 s)
    assert all(w._thread.is_alive() for w in stuck)  # still in their jobs: daemons, let go
    release.set()
    join_by(stuck, tm.monotonic() + 10)
    assert not any(w._thread.is_alive() for w in stuck)  # each stopped after its job
