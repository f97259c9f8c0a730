"""The target mode in a real browser (Debian's Chromium through Playwright) at 1366x768, on a
synthetic board sequence: the detections shown (table, corners and lidar board points on the
overlay), a checkerboard run with its verdict and residuals, and a frame left out by a click on
its row changing the result. Screenshots land in ``test-artifacts/app/target_*.png``."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from app_fixtures import free_port, launch_browser, need_chromium, screenshot, wait_for
from l2e_studio.app.panels.target import BOARD_POINT_RGB

pytestmark = [pytest.mark.browser, pytest.mark.timeout(600)]

VIEWPORT = {"width": 1366, "height": 768}
ENDED = ("done", "failed", "cancelled")
BOARDS = dict(n_scenes=6, modality="frame", width=640, height=360, seed=21)


@pytest.fixture(scope="module")
def board_set(tmp_path_factory):
    from l2e_studio.scenes import load_scene_folder
    from l2e_studio.synth import TargetConfig, write_target_dataset

    return load_scene_folder(write_target_dataset(tmp_path_factory.mktemp("boards") / "b", TargetConfig(**BOARDS)))


@pytest.fixture(scope="module")
def app(board_set, tmp_path_factory):
    from l2e_studio.app.server import build_app

    a = build_app(board_set, port=free_port(), out_dir=tmp_path_factory.mktemp("results"))
    yield a
    a.stop()


@pytest.fixture(scope="module")
def page(app):
    need_chromium()
    from playwright.sync_api import sync_playwright

    from test_app_browser import open_app

    with sync_playwright() as pw:
        browser = launch_browser(pw)
        context = browser.new_context(viewport=VIEWPORT)
        context.set_default_timeout(90_000)  # a loaded 2-core machine: detection runs while the page loads
        p = context.new_page()
        open_app(p, app)
        yield p
        context.close()
        browser.close()


def shown_overlay(page) -> np.ndarray:
    """The overlay image the page shows now, decoded (RGB)."""
    data = page.evaluate(
        """async () => {
            for (let attempt = 0; ; attempt++) {
                const img = document.querySelector("img[src^='blob:']");
                try {
                    const buf = await (await fetch(img.src)).arrayBuffer();
                    return Array.from(new Uint8Array(buf));
                } catch (err) {
                    if (attempt >= 20) throw err;
                    await new Promise(r => setTimeout(r, 50));
                }
            }
        }"""
    )
    bgr = cv2.imdecode(np.frombuffer(bytes(data), np.uint8), cv2.IMREAD_COLOR)
    return bgr[:, :, ::-1]


def magenta_share(rgb: np.ndarray) -> float:
    """Share of magenta pixels (the board points' colour, as JPEG leaves it)."""
    r, g, b = (rgb[..., k].astype(np.int16) for k in range(3))
    assert BOARD_POINT_RGB == (255, 0, 200)
    return float(np.mean((r > 150) & (b > 110) & (g < 110)))


def open_tab(page, name: str) -> None:
    from test_app_browser import close_webgl_notice

    close_webgl_notice(page, 0.0)  # it can lie over the second row of tabs at 1366 px
    page.get_by_role("tab", name=name).click()


def frame_rows(page) -> list[str]:
    return page.locator("table:has(th:text-is('frame')) tbody tr").all_inner_texts()


def choose(page, label: str, option: str) -> None:
    element_id = page.locator("label", has_text=label).first.get_attribute("for")
    page.locator(f"[id='{element_id}']").click()
    page.get_by_role("option", name=option).click()


def test_detections_run_verdict_and_a_frame_left_out(page, app):
    # --- the detections: the table in the Target tab, the marks on the overlay -----------------
    open_tab(page, "Target")
    page.get_by_text("Board found in").first.wait_for(timeout=120_000)
    rows = frame_rows(page)
    assert len(rows) == BOARDS["n_scenes"] and sum(r.split("\t")[2].strip() in ("quad", "quad x2", "SB") for r in rows) == BOARDS["n_scenes"]
    app.views.overlay_worker.wait_idle(10)
    wait_for(lambda: magenta_share(shown_overlay(page)) > 0.004, timeout=30, what="board points on the overlay")
    with_marks = shown_overlay(page)
    screenshot(page, "target_01_detections")
    page.get_by_text("Show board marks").first.click()
    wait_for(lambda: magenta_share(shown_overlay(page)) < 0.2 * magenta_share(with_marks), timeout=30,
             what="the marks gone when switched off")
    page.get_by_text("Show board marks").first.click()
    wait_for(lambda: magenta_share(shown_overlay(page)) > 0.5 * magenta_share(with_marks), timeout=30,
             what="the marks back")

    # --- a checkerboard run: verdict and residuals ----------------------------------------------
    open_tab(page, "Optimise")
    choose(page, "Method", "checkerboard")
    wait_for(lambda: app.optimise.calibration.value == "checkerboard", what="the method chosen")
    page.get_by_role("button", name="Start").click()
    wait_for(lambda: app.state.snapshot().run.status in ENDED, timeout=300, what="the run to end")
    first = app.state.snapshot()
    assert first.run.status == "done", first.run.error
    assert first.result.method == "target"
    page.get_by_text("Finished").first.wait_for(timeout=60_000)
    open_tab(page, "Result")
    page.get_by_text("checkerboard").first.wait_for()
    if first.verdict is not None:
        page.get_by_text(f"Verdict: {first.verdict.summary()}").first.wait_for()
    screenshot(page, "target_02_result")
    open_tab(page, "Target")
    page.get_by_text("frames used").first.wait_for()
    rows = frame_rows(page)
    residuals = [r for r in rows if not r.split("\t")[-1].strip()]  # no note: used
    assert len(residuals) >= 4
    assert all(any(ch.isdigit() for ch in r.split("\t")[5]) for r in residuals)  # plane RMS in mm shown
    screenshot(page, "target_03_frames_after_run")

    # --- a frame left out by a click on its row's first cell: the result changes ------------------
    row = page.locator("table:has(th:text-is('frame')) tbody tr").filter(has_text="scene_003").first
    row.locator("td").first.click()
    wait_for(lambda: app.state.snapshot().included[3] is False, what="scene_003 left out by the click")
    open_tab(page, "Optimise")
    page.get_by_role("button", name="Start").click()
    wait_for(lambda: app.state.snapshot().result is not first.result and app.state.snapshot().run.status in ENDED,
             timeout=300, what="the second run's result")
    second = app.state.snapshot()
    assert second.run.status == "done", second.run.error
    assert not np.allclose(second.result.extrinsic.params, first.result.extrinsic.params)
    open_tab(page, "Target")
    page.get_by_text("left out by the user").first.wait_for(timeout=30_000)
    row = page.locator("table:has(th:text-is('frame')) tbody tr").filter(has_text="scene_003").first
    assert "left out by the user" in row.inner_text()
    screenshot(page, "target_04_frame_left_out")

    # --- the board points in the 3D view, seen from beside the rig ------------------------------
    cloud = app.target.cloud
    wait_for(lambda: cloud.visible and len(cloud.points) == app.target.views["scene_000"].lidar_points,
             what="scene_000's board points in the 3D view")
    centre = np.asarray(cloud.points, float).mean(axis=0)
    for client in app.server.get_clients().values():
        client.camera.position = tuple(centre + np.array([-1.2, 2.2, 1.0]))
        client.camera.look_at = tuple(centre)
        client.camera.up_direction = (0.0, 0.0, 1.0)
    page.wait_for_timeout(1500)
    screenshot(page, "target_05_board_points_3d")
