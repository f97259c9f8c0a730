"""The page keeps its main thread for the overlay while the seed is tuned: in a browser that draws
WebGL in software (headless Chromium with --disable-gpu: SwiftShader), the 3D view stops drawing
while the seed slider is pressed, keeps its last picture, and catches up once the presses stop or
the pointer enters it (real Chromium through Playwright, a real app)."""

from __future__ import annotations

import time

import cv2
import numpy as np
import pytest

from app_fixtures import wait_for
from l2e_studio.app.browser_js import TUNE_PAUSE_MS
from l2e_studio.app.panels.view3d import camera_pose
from test_app_browser import app, browser, open_app, open_tab, scene_set, slider_root  # noqa: F401 (the fixtures)

pytestmark = [pytest.mark.browser, pytest.mark.timeout(240)]


@pytest.fixture
def page(browser, app):  # noqa: F811
    context = browser.new_context(viewport={"width": 1366, "height": 768})
    p = context.new_page()
    open_app(p, app)
    yield p
    context.close()


def gl_counts(page) -> dict:
    return page.evaluate("() => { const s = window.__l2e3d; return s && {soft: s.soft, drawn: s.drawn, "
                         "skipped: s.skipped, paused: s.paused()}; }")


def canvas_pixels(page) -> np.ndarray:
    png = page.locator("canvas").first.screenshot()
    return cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)


def gizmo_at(app, extrinsic) -> bool:
    _, pos = camera_pose(extrinsic)
    return np.allclose(np.asarray(app.view3d.gizmo.position), pos, atol=1e-6)


def test_3d_view_pauses_while_the_seed_slider_is_pressed_and_catches_up(page, app):
    wait_for(lambda: gl_counts(page), what="the page script's 3D state")
    if not gl_counts(page)["soft"]:
        pytest.skip("this Chromium draws WebGL on a GPU: the 3D view is never paused")
    wait_for(lambda: gl_counts(page)["drawn"] > 0, what="the 3D view drawn at start")
    open_tab(page, "Seed")
    page.get_by_text("included scenes:").wait_for()
    before = canvas_pixels(page)
    assert before.std() > 3  # a picture (the cloud and the frustum), not a blank canvas

    slider_root(page, "yaw (°)").get_by_role("slider").focus()
    counts0 = gl_counts(page)
    version0 = app.state.snapshot().version
    t0 = time.monotonic()
    for i in range(6):  # a person nudging: a press every 0.4 s for 2.4 s
        page.keyboard.press("ArrowRight")
        wait_for(lambda: app.state.snapshot().version > version0 + i, what=f"press {i + 1} on the server")
        time.sleep(max(0.0, t0 + 0.4 * (i + 1) - time.monotonic()))
    during = gl_counts(page)
    # the 3D view asked for frames (viser's 1 Hz heartbeat, the gizmo posed at rest) and drew none
    assert during["paused"] and during["drawn"] == counts0["drawn"] and during["skipped"] > counts0["skipped"]
    held = canvas_pixels(page)
    assert held.std() > 3 and np.abs(held.astype(int) - before.astype(int)).mean() < 1.0  # its last picture

    # the presses stopped: the gizmo follows on the server and the page draws it again
    ext = app.state.snapshot().extrinsic
    wait_for(lambda: gizmo_at(app, ext), timeout=5, what="the 3D gizmo at the new extrinsic")
    wait_for(lambda: gl_counts(page)["drawn"] > during["drawn"], timeout=TUNE_PAUSE_MS / 1000 + 3,
             what="the 3D view drawn again after the pause")
    assert not gl_counts(page)["paused"]

    # one more press pauses it again; the pointer entering the 3D view ends the pause at once
    page.keyboard.press("ArrowLeft")
    wait_for(lambda: gl_counts(page)["paused"], timeout=2, what="a new pause")
    drawn = gl_counts(page)["drawn"]
    box = page.locator("canvas").first.bounding_box()
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    assert not gl_counts(page)["paused"]
    wait_for(lambda: gl_counts(page)["drawn"] > drawn, timeout=2.5, what="the 3D view drawn on hover")
