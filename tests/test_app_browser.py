"""The workbench driven in a real browser: headless Chromium (Debian's) through Playwright.

The app runs in-process on a free port over four small synthetic scenes; every test opens
the page, works the controls as a person would and checks both what the page shows and the
server's state. Screenshots land in ``test-artifacts/app/``.
"""

from __future__ import annotations

import re
import time

import cv2
import numpy as np
import pytest
import yaml

from app_fixtures import free_port, launch_browser, need_chromium, new_context, screenshot, wait_for, write_small_scenes
from l2e_studio.app.pose import extrinsic_from_sliders
from l2e_studio.app.text import score_num
from l2e_studio.io.cameras import load_seed

pytestmark = [pytest.mark.browser, pytest.mark.timeout(240)]


# --- fixtures -------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def scene_set(tmp_path_factory):
    from l2e_studio.scenes import load_scene_folder

    return load_scene_folder(write_small_scenes(tmp_path_factory.mktemp("scenes") / "small"))


@pytest.fixture
def app(scene_set, tmp_path):
    from l2e_studio.app.server import build_app

    a = build_app(scene_set, host="127.0.0.1", port=free_port(), out_dir=tmp_path / "results")
    yield a
    a.stop()


@pytest.fixture(scope="module")
def browser():
    need_chromium()
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        b = launch_browser(pw)
        yield b
        b.close()


@pytest.fixture
def context(browser, app):
    c = new_context(browser)
    yield c
    c.close()  # before the app stops (see new_context)


@pytest.fixture
def page(context, app):
    p = context.new_page()
    open_app(p, app)
    return p


# --- page helpers ----------------------------------------------------------------------------------

def open_app(page, app) -> None:
    page.goto(app.url)
    page.get_by_text("Use in optimisation").wait_for()
    page.locator("img[src^='blob:']").first.wait_for()
    close_webgl_notice(page)


def close_webgl_notice(page, wait_s: float = 2.0) -> None:
    """Close viser's "WebGL is running in software mode" notice (headless Chromium has no GPU;
    with the overlay panel widened for large windows the notice can lie over the tabs)."""
    notice = page.locator(".mantine-Notification-root", has_text="WebGL")
    deadline = time.monotonic() + wait_s
    while time.monotonic() < deadline and notice.count() == 0:
        time.sleep(0.1)
    for n in notice.all():
        try:
            n.locator("button").first.click(timeout=2_000)
        except Exception:  # closed by itself meanwhile
            pass


def overlay_digest(page) -> str:
    """SHA-256 of the JPEG bytes the overlay image currently shows."""
    return page.evaluate(
        """async () => {
            for (let attempt = 0; ; attempt++) {
                const img = document.querySelector("img[src^='blob:']");
                try {  // a new frame can revoke the blob URL between the lookup and the fetch
                    const buf = await (await fetch(img.src)).arrayBuffer();
                    const d = await crypto.subtle.digest("SHA-256", buf);
                    return Array.from(new Uint8Array(d)).map(b => b.toString(16).padStart(2, "0")).join("");
                } catch (err) {
                    if (attempt >= 20) throw err;
                    await new Promise(r => setTimeout(r, 50));
                }
            }
        }"""
    )


def labelled(page, label: str):
    """The input element viser labels with ``label`` (a slider root, a select box ...)."""
    element_id = page.locator("label", has_text=label).first.get_attribute("for")
    return page.locator(f"[id='{element_id}']")


slider_root = labelled


def number_field(page, label: str):
    """The number box next to a slider (or a plain number input) with this label."""
    return slider_root(page, label).locator("xpath=..").locator("input.mantine-NumberInput-input")


def exact_field(page, axis: str):
    """The Seed tab's exact text field of one axis (``x``, ``roll`` ...)."""
    label = page.locator("label").filter(has_text=re.compile(rf"^{re.escape(axis)} =$")).first
    return label.locator("xpath=ancestor::div[1]/..//input")


def readout(page) -> str:
    return page.get_by_text("included scenes:").inner_text()


def open_tab(page, name: str) -> None:
    page.get_by_role("tab", name=name).click()


# --- the tests -------------------------------------------------------------------------------------

def test_page_loads_with_panels_overlay_and_scene_list(page, app):
    for tab in ("Overlay", "Before / after", "Scenes", "Seed", "Optimise", "Result"):
        assert page.get_by_role("tab", name=tab).is_visible()
    assert page.get_by_text("L2E Studio").first.is_visible()
    for name in app.state.scene_names:
        assert page.get_by_role("cell", name=name).first.is_visible()
    # the overlay shows the whole map of the selected scene, drawn at the panel's frame width (points
    # at their screen size; a small map is magnified), and the MI column is filled in
    size = page.evaluate("() => { const i = document.querySelector(\"img[src^='blob:']\"); return [i.naturalWidth, i.naturalHeight]; }")
    assert app.camera.width < size[0] <= app.overlay.display_width
    assert size[1] == pytest.approx(size[0] * app.camera.height / app.camera.width, abs=1)
    wait_for(lambda: app.reading is not None, what="the first MI reading")
    first_mi = score_num(app.reading.per_scene[0])
    page.get_by_role("cell", name=first_mi).first.wait_for()
    screenshot(page, "01_loaded")


def test_slider_move_changes_overlay_and_mi_readout(page, app):
    open_tab(page, "Seed")
    page.get_by_text("included scenes:").wait_for()
    wait_for(lambda: app.views.overlay_worker.wait_idle(5) and app.overlay.frames >= 1)
    text0, digest0 = readout(page), overlay_digest(page)
    frames0 = app.overlay.frames

    thumb = slider_root(page, "yaw (°)").get_by_role("slider")
    thumb.focus()
    for _ in range(5):  # five keyboard steps of 0.1 deg ("fine" step)
        page.keyboard.press("ArrowRight")
    wait_for(lambda: abs(app.extrinsic.sliders[5].value - 0.5) < 1e-6, what="yaw slider at 0.5 deg on the server")
    values = np.array([s.value for s in app.extrinsic.sliders])
    expected = extrinsic_from_sliders(values, app.state.reference)
    wait_for(lambda: np.allclose(app.state.snapshot().extrinsic.params, expected.params), what="state follows the sliders")
    wait_for(lambda: readout(page) != text0, what="the MI readout to change in the page")
    wait_for(lambda: overlay_digest(page) != digest0, what="a new overlay image in the page")
    assert app.overlay.frames > frames0

    # typing into the number field of x moves the translation
    x_new = round(float(app.state.reference.translation[0]) + 0.02, 3)
    field = exact_field(page, "x")
    field.fill(str(x_new))
    field.press("Enter")
    wait_for(lambda: abs(app.state.snapshot().extrinsic.translation[0] - x_new) < 1e-9, what="x typed in")
    screenshot(page, "02_slider_moved")


def test_optimisation_runs_to_completion_and_saves(page, app):
    open_tab(page, "Optimise")
    page.get_by_role("button", name="Start").click()
    wait_for(lambda: app.state.snapshot().run.status != "idle", what="the run to start")
    page.get_by_text("Finished").first.wait_for(timeout=120_000)
    snap = app.state.snapshot()
    r = snap.result
    assert snap.run.status == "done" and not r.cancelled
    assert r.score_result > r.score_seed
    # the curve: the best point on the readout's scale, ending on the result; a drawn uPlot in the page
    assert len(snap.run.history) == r.evaluations > 1
    assert snap.run.best_curve[-1] == (r.evaluations, pytest.approx(r.score_result, rel=1e-9, abs=1e-12))
    wait_for(lambda: len(app.optimise.plot.data[0]) == len(snap.run.best_curve), what="the curve's data")
    assert app.optimise.plot.visible
    assert page.locator(".uplot canvas").first.is_visible()
    screenshot(page, "03_optimised")

    open_tab(page, "Result")
    page.get_by_text(score_num(app.result_scores.accepted.score)).first.wait_for()
    # the verdict, in words, beside the result
    v = snap.verdict
    assert v is not None
    page.get_by_text(f"Verdict: {v.summary()}").first.wait_for()
    handed = v.extrinsic  # what the verdict hands back is what the file holds
    page.get_by_role("button", name="Save result").click()
    page.get_by_text("Result saved").first.wait_for()
    saved = sorted((app.out_dir).glob("l2e_result_*.yaml"))
    assert len(saved) == 1
    doc = yaml.safe_load(saved[0].read_text())
    assert np.allclose(doc["T_cam_lidar"], handed.matrix, atol=1e-9)
    assert np.allclose(doc["optimiser_result"]["T_cam_lidar"], r.extrinsic.matrix, atol=1e-9)
    assert doc["verdict"]["status"] == v.status
    assert doc["score"]["result"] == pytest.approx(r.score_result)
    assert doc["scenes"] == list(app.state.scene_names)
    assert np.allclose(load_seed(saved[0]).params, handed.params, atol=1e-8)
    png = cv2.imread(str(saved[0].with_name(saved[0].stem + "_before_after.png")))
    assert png is not None and png.shape == (app.camera.height, 2 * app.camera.width, 3)
    # saving again never replaces the first file
    first = saved[0].read_bytes()
    page.get_by_role("button", name="Save result").click()
    wait_for(lambda: len(list(app.out_dir.glob("l2e_result_*.yaml"))) == 2, what="a second result file")
    assert saved[0].read_bytes() == first

    open_tab(page, "Before / after")
    wait_for(lambda: app.compare.frames >= 1, what="the before/after image")
    page.get_by_text("(seed) →").first.wait_for()
    screenshot(page, "04_before_after")

    open_tab(page, "Result")
    page.get_by_role("button", name=app.results.accept.label).click()
    accepted = v.extrinsic if v.trusted else r.extrinsic
    wait_for(lambda: np.allclose(app.state.snapshot().extrinsic.params, accepted.params), what="accepted result")


def test_cancel_stops_a_run_within_a_second(page, app):
    app.optimise.method.value = "Nelder-Mead"  # the slowest optimiser: a run long enough to cancel
    open_tab(page, "Optimise")
    page.get_by_role("button", name="Start").click()
    wait_for(lambda: app.state.snapshot().run.evaluations >= 20, timeout=60, what="the run to get going")
    assert app.state.snapshot().run.status == "running"
    # the page stamps the click (epoch ms): Playwright's own checks before clicking take long on
    # a busy machine and are no part of the app
    page.evaluate("""() => document.addEventListener('click', () => {
        window.__clicked = performance.timeOrigin + performance.now(); }, true)""")
    page.get_by_role("button", name="Cancel").click()
    wait_for(lambda: app.state.snapshot().run.status == "cancelled", timeout=10, interval=0.005, what="cancelled")
    seconds = time.time() - page.evaluate("() => window.__clicked") / 1000.0
    assert seconds < 1.0, f"cancel took {seconds:.2f} s from the click"
    assert app.state.snapshot().result.cancelled
    page.get_by_text("Cancelled").first.wait_for()
    assert page.get_by_role("button", name="Start").is_enabled()
    screenshot(page, "05_cancelled")


def test_two_tabs_share_state_and_a_closed_tab_loses_nothing(browser, context, app):
    # Two windows rather than two tabs of one window: headless Chromium throttles a background
    # tab, which only slows the test down; the server cannot tell the difference.
    other = new_context(browser)
    a, b = context.new_page(), other.new_page()
    try:
        open_app(a, app)
        open_app(b, app)
        open_tab(a, "Seed")
        open_tab(b, "Seed")
        field = exact_field(a, "yaw")
        field.fill("1.5")
        field.press("Enter")
        wait_for(lambda: exact_field(b, "yaw").input_value() == "1.5", what="tab B's yaw field")
        wait_for(lambda: app.views.mi_worker.wait_idle(5) and readout(a) == readout(b), what="the same readout in both")

        open_tab(a, "Scenes")
        open_tab(b, "Scenes")
        labelled(a, "Scene").click()
        a.get_by_role("option", name="scene_002").click()
        wait_for(lambda: app.state.snapshot().selected == 2, what="scene_002 selected")
        wait_for(lambda: labelled(b, "Scene").input_value() == "scene_002", what="tab B's scene")
        b.get_by_text("scene_002 · MI").first.wait_for()

        # a run started in one tab finishes while that tab is gone, and the other sees it
        open_tab(a, "Optimise")
        a.get_by_role("button", name="Start").click()
        wait_for(lambda: app.state.snapshot().run.status == "running", what="the run to start")
        a.close()
        open_tab(b, "Optimise")
        b.get_by_text("Finished").first.wait_for(timeout=120_000)
        assert app.state.snapshot().result is not None
        screenshot(b, "06_second_tab")
    finally:
        for p in (a, b):
            if not p.is_closed():
                p.close()
        other.close()


def painted_overlay(page) -> list:
    """(a digest of the overlay's pixels as the page decoded them, its JPEG's SHA-256): the image
    drawn through a canvas, so it is what the browser shows, not only which blob the tag names."""
    return page.evaluate(
        """async () => {
            for (let attempt = 0; ; attempt++) {
                const img = document.querySelector("img[src^='blob:']");
                try {
                    const buf = await (await fetch(img.src)).arrayBuffer();
                    await img.decode();
                    const c = document.createElement('canvas');
                    c.width = img.naturalWidth; c.height = img.naturalHeight;
                    const g = c.getContext('2d');
                    g.drawImage(img, 0, 0);
                    const px = g.getImageData(0, 0, c.width, c.height).data;
                    const hex = async (b) => Array.from(new Uint8Array(await crypto.subtle.digest("SHA-256", b)))
                        .map(x => x.toString(16).padStart(2, "0")).join("");
                    return [await hex(px), await hex(buf)];
                } catch (err) {  // a new frame replaced this one meanwhile
                    if (attempt >= 20) throw err;
                    await new Promise(r => setTimeout(r, 50));
                }
            }
        }"""
    )


def test_one_key_press_paints_the_new_overlay_then_the_frame_at_rest(page, app):
    """One arrow key on the focused yaw slider: the page paints a different overlay, and it
    ends on the server's frame at rest for the new extrinsic (no timing asserted)."""
    import hashlib

    open_tab(page, "Seed")
    page.get_by_text("included scenes:").wait_for()
    sent = []  # (state version, at rest, SHA-256 of the JPEG) of every frame the server sends
    render = app.overlay.render
    app.overlay.render = lambda snap, rest=True: (render(snap, rest),
                                                  sent.append((snap.version, rest, hashlib.sha256(app.overlay.image._data).hexdigest())))[0]
    wait_for(lambda: app.views.overlay_worker.wait_idle(5) and app.overlay.rest_frame, what="the first frame at rest")
    pixels0, jpeg0 = painted_overlay(page)
    version0 = app.state.snapshot().version

    slider_root(page, "yaw (°)").get_by_role("slider").focus()
    page.keyboard.press("ArrowRight")
    wait_for(lambda: app.state.snapshot().version > version0, what="the key press on the server")
    version = app.state.snapshot().version
    wait_for(lambda: any(v == version and rest for v, rest, _ in sent), what="the frame at rest of the new extrinsic")
    at_rest = next(h for v, rest, h in sent if v == version and rest)
    wait_for(lambda: painted_overlay(page)[1] == at_rest, what="the page to show the frame at rest")
    pixels, jpeg = painted_overlay(page)
    assert jpeg != jpeg0 and pixels != pixels0  # another image, decoded to other pixels
    assert any(v == version and not rest for v, rest, _ in sent)  # a quick preview came first
