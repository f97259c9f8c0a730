"""Scenes read from raw events: the Event map controls (window, start, hot pixels) rebuild the
map in the background, and the readout, the overlay, the 3D thumbnail and the saved result
follow; refused values, failures and runs in progress are handled. Server-side tests first,
then the same in a real browser (headless Debian Chromium through Playwright)."""

from __future__ import annotations

import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest
import yaml

from app_fixtures import free_port, screenshot, wait_for, write_event_recordings, write_small_scenes
from l2e_studio.calibrate import CalibrationSettings
from l2e_studio.io.events import Accumulation
from test_app_browser import browser, context, overlay_digest, page  # noqa: F401 (fixtures)
from test_app_browser_precision import text_field


@pytest.fixture
def event_folder(tmp_path, monkeypatch):
    """Two scenes whose maps are raw recordings (4 s of events each), caches in tmp."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    folder = write_small_scenes(tmp_path / "scenes", n_scenes=2)
    write_event_recordings(folder)
    return folder


@pytest.fixture
def scene_set(event_folder):
    from l2e_studio.scenes import load_scene_folder

    return load_scene_folder(event_folder)


@pytest.fixture
def app(scene_set, tmp_path):
    from l2e_studio.app.server import build_app

    a = build_app(scene_set, host="127.0.0.1", port=free_port(), out_dir=tmp_path / "results")
    a.views.mi_worker.wait_idle(20)
    a.views.recording_worker.wait_idle(20)
    yield a
    a.stop()


def user():
    return SimpleNamespace(client=SimpleNamespace(add_notification=lambda *a, **k: None), client_id=1)


def settle(app) -> None:
    assert app.maps.rebuilder.wait(30)
    for w in (app.views.overlay_worker, app.views.mi_worker, app.views.compare_worker, app.views.scene_3d_worker):
        assert w.wait_idle(20)


def type_settings(app, window: str = "3", start: str = "0", hot: str = "off", everywhere: bool = False) -> None:
    panel = app.event_maps
    panel.window.value, panel.start.value, panel.hot.value = window, start, hot
    panel.apply_all.value = everywhere


# --- server side -------------------------------------------------------------------------------------

def test_the_panel_shows_the_recording_and_its_current_settings(app):
    wait_for(lambda: "4.000 s" in app.event_maps.source.content, what="the recording's length")
    text = app.event_maps.source.content
    assert "scene_000" in text and "scene_000.npz" in text and "3 s from 0 s, hot pixels off" in text
    assert (app.event_maps.window.value, app.event_maps.start.value, app.event_maps.hot.value) == ("3", "0", "off")
    assert not app.event_maps.rebuild.disabled


def test_a_rebuild_replaces_one_map_and_the_readout_display_and_thumbnail_follow(app):
    settle(app)
    before = app.reading.per_scene.copy()
    display, thumb = app.displays[0], app.view3d.frustum.image.copy()
    frames = app.overlay.frames
    type_settings(app, window="0.5", start="1")
    app.event_maps._on_rebuild(user())
    settle(app)
    scene = app.scene_set.scenes[0]
    assert scene.accumulation == Accumulation(0.5, 1.0)
    assert app.displays[0] is not display and app.displays[0].scene is scene
    np.testing.assert_array_equal(app.readout.stack.raw_maps[0], scene.event_map)
    wait_for(lambda: app.reading.per_scene[0] != before[0], what="the new score of scene_000")
    assert app.reading.per_scene[1] == before[1]  # the other scene is untouched
    assert app.overlay.frames > frames and not np.array_equal(app.view3d.frustum.image, thumb)
    assert "Rebuilt the map of scene_000" in app.event_maps.status.content
    assert "0.5 s from 1 s" in app.event_maps.source.content
    assert app.scene_set.scenes[1].accumulation == Accumulation()
    # everywhere, with hot-pixel suppression
    type_settings(app, window="2", hot="4", everywhere=True)
    app.event_maps._on_rebuild(user())
    settle(app)
    assert [s.accumulation for s in app.scene_set.scenes] == [Accumulation(2.0, 0.0, 4.0)] * 2


def test_refused_values_are_kept_as_typed_and_block_rebuild(app):
    wait_for(lambda: app.recording(0) is not None, what="the recording's length")
    for window, start, hot, words in (("0", "0", "off", "Window: 0 s is outside (0, 3600] s"),
                                      ("-1", "0", "off", "outside (0, 3600]"),
                                      ("abc", "0", "off", "is not a number"),
                                      ("1", "4.5", "off", "past the end of the recording (4.000 s long)"),
                                      ("1", "-0.5", "off", "before the recording"),
                                      ("1", "0", "0", "Hot-pixel σ: 0 is outside (0, 1000]")):
        type_settings(app, window, start, hot)
        notes = app.event_maps.w_problem.content + app.event_maps.s_problem.content + app.event_maps.h_problem.content
        assert words in notes
        assert app.event_maps.rebuild.disabled and "fix the settings" in app.event_maps.status.content
        assert app.event_maps.window.value == window  # never clamped
    type_settings(app, "3", "2")  # a window past the end is allowed, and said
    assert not app.event_maps.rebuild.disabled and "counts the last 2 s" in app.event_maps.s_problem.content


def test_a_failed_rebuild_keeps_the_old_map_and_says_why(app, event_folder):
    settle(app)
    before = app.reading.per_scene.copy()
    old = app.scene_set.scenes[0]
    (event_folder / "event" / "scene_000.npz").write_bytes(b"not an event file")
    type_settings(app, window="1")
    app.event_maps._on_rebuild(user())
    settle(app)
    assert app.scene_set.scenes[0] is old and app.readout.stack.raw_maps[0] is not None
    np.testing.assert_array_equal(app.readout.stack.raw_maps[0], old.event_map)
    assert app.reading.per_scene[0] == before[0]
    status = app.event_maps.status.content
    assert status.startswith("✗ scene_000:") and "scene_000.npz" in status and "old map is kept" in status


def test_rebuild_waits_for_a_run_and_a_run_waits_for_a_rebuild(app, monkeypatch):
    import l2e_studio.app.rebuild as rebuild_module
    import l2e_studio.app.runs as runs_module

    release = threading.Event()
    real_calibrate, real_reaccumulate = runs_module.calibrate, rebuild_module.reaccumulate

    def slow_calibrate(*args, **kwargs):
        release.wait(30)
        return real_calibrate(*args, **kwargs)

    monkeypatch.setattr(runs_module, "calibrate", slow_calibrate)
    app.start_run(CalibrationSettings(rotation_only=True, coarse_to_fine=False, max_iterations=5))
    try:
        with pytest.raises(RuntimeError, match="optimisation is running"):
            app.rebuild_maps(Accumulation(1.0))
        assert app.event_maps.rebuild.disabled and "optimisation is running" in app.event_maps.status.content
    finally:
        release.set()
    assert app.wait_run(120)
    assert not app.event_maps.rebuild.disabled

    release.clear()
    monkeypatch.setattr(rebuild_module, "reaccumulate", lambda *a: release.wait(30) and real_reaccumulate(*a))
    app.rebuild_maps(Accumulation(1.0))
    try:
        assert app.rebuilding() and app.optimise.start.disabled
        assert "being rebuilt" in app.optimise.blocker.content
        with pytest.raises(RuntimeError, match="being rebuilt"):
            app.start_run(CalibrationSettings())
        with pytest.raises(RuntimeError, match="in progress"):
            app.rebuild_maps(Accumulation(2.0))
    finally:
        release.set()
    settle(app)
    assert not app.optimise.start.disabled and app.scene_set.scenes[0].accumulation == Accumulation(1.0)


def test_the_saved_result_records_the_maps_it_was_calibrated_on(app):
    app.state.set_included(1, False)  # scene_001 held out
    app.inclusion_changed()
    app.start_run(CalibrationSettings(rotation_only=True, coarse_to_fine=False))
    assert app.wait_run(180)
    type_settings(app, window="1", everywhere=True)  # after the run: the run's maps stay on record
    app.event_maps._on_rebuild(user())
    settle(app)
    path, _ = app.save_result()
    maps = yaml.safe_load(path.read_text())["maps"]
    assert maps["scene_000"]["accumulation"] == {"window_s": 3.0, "start_s": 0.0, "hot_pixel_sigma": None}
    assert maps["scene_001"]["accumulation"]["window_s"] == 1.0  # held out: scored now, on today's map
    assert maps["scene_000"]["file"].endswith("scene_000.npz") and maps["scene_000"]["kind"] == "events"


def test_a_scene_read_as_an_image_says_so_and_offers_nothing(tmp_path, monkeypatch):
    import shutil

    from l2e_studio.app.server import build_app
    from l2e_studio.scenes import load_scene_folder

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    folder = write_small_scenes(tmp_path / "scenes", n_scenes=2)
    shutil.copy(folder / "event" / "scene_001.png", tmp_path / "keep.png")
    write_event_recordings(folder)
    (folder / "event" / "scene_001.npz").unlink()
    shutil.copy(tmp_path / "keep.png", folder / "event" / "scene_001.png")
    a = build_app(load_scene_folder(folder), port=free_port(), out_dir=tmp_path / "out")
    try:
        a.select_scene(1)
        panel = a.event_maps
        assert "read as an image" in panel.source.content and "scene_001.png" in panel.source.content
        assert panel.rebuild.disabled and panel.window.disabled and panel.apply_all.disabled
        with pytest.raises(RuntimeError, match="not from raw events"):
            a.rebuild_maps(Accumulation(1.0))
        a.select_scene(0)
        assert not panel.rebuild.disabled and not panel.window.disabled
    finally:
        a.stop()


# --- in the browser ----------------------------------------------------------------------------------

def settled_digest(page, app) -> str:
    """The overlay's digest once the server has sent its frame at rest and the page
    shows it (a preview while things move has other bytes for the same picture)."""
    wait_for(lambda: app.views.overlay_worker.wait_idle(5) and app.overlay.rest_frame, what="the frame at rest")
    previous = overlay_digest(page)
    while True:
        time.sleep(0.4)
        now = overlay_digest(page)
        if now == previous:
            return now
        previous = now


def score_cell(page, app, index: int = 0):
    """The Scenes table's "score now" cell of scene ``index`` as the server last computed it."""
    return page.get_by_role("cell", name=f"{app.reading.per_scene[index]:.4f}").first


@pytest.mark.browser
@pytest.mark.timeout(240)
def test_changing_the_window_in_the_browser_rebuilds_the_map_and_the_overlay_and_score_follow(page, app):
    page.get_by_text("Event map").first.wait_for()
    page.get_by_text("4.000 s").first.wait_for()  # the recording's length
    wait_for(lambda: app.reading is not None, what="the first reading")
    score_cell(page, app).wait_for()
    score0, digest0 = app.reading.per_scene.copy(), settled_digest(page, app)
    frame0 = app.overlay.image.image.copy()

    window = text_field(page, "Window (s)")
    rebuild = page.get_by_role("button", name="Rebuild map")
    window.fill("0")  # refused beside the field, kept as typed
    page.get_by_text("Window: 0 s is outside (0, 3600] s").first.wait_for()
    wait_for(lambda: not rebuild.is_enabled(), what="Rebuild disabled for a zero window")
    assert window.input_value() == "0" and app.scene_set.scenes[0].accumulation == Accumulation()
    screenshot(page, "20_event_window_refused")

    window.fill("0.5")
    wait_for(lambda: rebuild.is_enabled(), what="Rebuild enabled again")
    assert page.get_by_text("Window: 0 s is outside").count() == 0
    rebuild.click()
    page.get_by_text("Rebuilt the map of scene_000").first.wait_for()
    assert app.scene_set.scenes[0].accumulation == Accumulation(0.5)
    assert settled_digest(page, app) != digest0  # the page shows another picture, not only another encoding
    assert app.overlay.image.image.shape == frame0.shape and not np.array_equal(app.overlay.image.image, frame0)
    wait_for(lambda: app.reading.per_scene[0] != score0[0], what="a new score on the server")
    score_cell(page, app).wait_for()  # the table shows the new score
    assert page.get_by_role("cell", name=f"{score0[0]:.4f}").count() == 0
    page.get_by_text("0.5 s from 0 s").first.wait_for()
    screenshot(page, "21_event_map_rebuilt")

    start = text_field(page, "Start (s)")
    start.fill("9")
    page.get_by_text("past the end of the recording (4.000 s long)").first.wait_for()
    wait_for(lambda: not rebuild.is_enabled(), what="Rebuild disabled for a start past the end")
    assert start.input_value() == "9"
