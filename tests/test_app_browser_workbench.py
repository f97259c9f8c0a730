"""The workbench at a laptop's 1366x768, in a real browser (headless Debian Chromium): seed values
refused beside their field and never left out of step with the state (after Reset, Undo or a loaded
seed file), the tabs on one row, the picking mode for PnP, a saved result offered as a download, the
swipe as the default before/after comparison, the first-steps hint on the embedded sample (and none
without a truth file), and a real rig at default settings (skipped when ../shared/realdata is
absent). Screenshots land in ``test-artifacts/app/``.
"""

from __future__ import annotations

import os
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from playwright.sync_api import expect

from app_fixtures import free_port, screenshot, wait_for
from test_app_browser import (app, browser, close_webgl_notice, exact_field, open_app, open_tab,  # noqa: F401
                              scene_set, slider_root)

pytestmark = [pytest.mark.browser, pytest.mark.timeout(300)]

LAPTOP = {"width": 1366, "height": 768}
REALDATA = Path(os.environ.get("L2E_REALDATA", Path(__file__).resolve().parents[2] / "shared" / "realdata"))
if not REALDATA.is_dir():  # a worktree beside the main checkout
    REALDATA = Path("/work/shared/realdata")


@pytest.fixture
def laptop(browser, app):  # noqa: F811
    context = browser.new_context(viewport=LAPTOP, accept_downloads=True)
    context.set_default_timeout(30_000)
    page = context.new_page()
    open_app(page, app)
    yield page
    context.close()  # before the app stops


def problem_beside(page, axis: str):
    """The warning element right after the ``axis =`` field (before its nudge buttons)."""
    field = exact_field(page, axis)
    return field, page.locator(f"xpath=//label[normalize-space()='{axis} =']/following::*[contains(., '⚠')][1]")


def test_refused_seed_values_are_said_beside_the_field_and_reset_puts_field_and_state_in_step(laptop, app):
    page = laptop
    open_tab(page, "Seed")
    before = app.state.snapshot().extrinsic
    x, _ = problem_beside(page, "x")
    x.fill("1e9")
    note = page.get_by_text("x: 1e9 m is outside [-100, 100] m").first
    note.wait_for()
    assert app.state.snapshot().extrinsic is before  # refused: nothing changed
    # beside the field: just below it, and on screen while the field is
    fbox, nbox = x.bounding_box(), note.bounding_box()
    assert 0 <= nbox["y"] - (fbox["y"] + fbox["height"]) < 60 and nbox["y"] + nbox["height"] <= LAPTOP["height"]
    screenshot(page, "30_seed_refused_beside_field")
    roll = exact_field(page, "roll")
    roll.fill("1e300")
    page.get_by_text("outside [-180, 180] °").first.wait_for()
    assert app.extrinsic.values[3] == 0.0 and app.state.snapshot().extrinsic is before
    roll.fill("abc")
    page.get_by_text("roll: “abc” is not a number").first.wait_for()
    # a valid value is taken; then Reset puts every field, slider and the state back together
    roll.fill("1.5")
    wait_for(lambda: app.extrinsic.values[3] == 1.5, what="roll = 1.5")
    page.get_by_role("button", name="Reset to file seed").click()
    wait_for(lambda: app.extrinsic.values[3] == 0.0, what="reset")
    wait_for(lambda: roll.input_value() == "0" and x.input_value() == app.extrinsic.fields[0].value, what="fields reset")
    assert app.extrinsic.sliders[3].value == 0.0 and not any(p.visible for p in app.extrinsic.problems)
    assert np.allclose(app.state.snapshot().extrinsic.params, app.state.reference.params)
    assert page.get_by_text("outside [-100, 100]").count() == 0
    # the next nudge moves from 0, not from a refused value
    page.get_by_role("button", name="+ 0.1°").first.click()
    wait_for(lambda: app.extrinsic.values[3] == pytest.approx(0.1, abs=1e-12), what="nudge from 0")
    x.fill("1e9")
    page.get_by_text("x: 1e9 m is outside").first.wait_for()
    page.get_by_role("button", name="Undo").click()  # undo rewrites the fields: the refusal goes with its text
    wait_for(lambda: app.extrinsic.values[3] == 0.0, what="undo")
    wait_for(lambda: x.input_value() != "1e9", what="x rewritten")
    assert not any(p.visible for p in app.extrinsic.problems)
    screenshot(page, "31_seed_after_reset")


def test_tabs_fit_one_row_at_1366x768_and_stay_there_on_switching(laptop, app):
    page = laptop
    tabs = page.get_by_role("tab")
    names = ["Scenes", "Seed", "Optimise", "Target", "Result", "QA"]
    for name in names + ["Overlay"]:
        page.get_by_role("tab", name=name).wait_for()

    def rows() -> set[float]:
        return {round(page.get_by_role("tab", name=n).bounding_box()["y"]) for n in names}

    assert len(rows()) == 1, rows()
    for name in names:
        open_tab(page, name)
        time.sleep(0.2)
        assert len(rows()) == 1, (name, rows())
    assert tabs.count() >= len(names)
    screenshot(page, "32_tabs_one_row_1366")


def test_picking_mode_looks_through_the_camera_and_widens_the_3d_view(laptop, app):
    from types import SimpleNamespace

    page = laptop
    open_tab(page, "Seed")
    page.get_by_text("Initial guess from clicked pairs").click()
    client = wait_for(lambda: next(iter(app.server.get_clients().values()), None), what="a client")
    width0 = app.overlay.display_width
    page.get_by_role("button", name="Start picking").click()
    wait_for(lambda: app.pairs.armed, what="picking armed")
    page.get_by_role("button", name="Stop picking").wait_for()
    # the overlay narrows so that the 3D view gets most of what the controls leave
    wait_for(lambda: app.overlay.display_width < 0.7 * width0, what="a narrower overlay")
    # every tab looks from the camera's pose, along its optical axis, image up
    inv = app.state.snapshot().extrinsic.inverse()
    wait_for(lambda: np.allclose(client.camera.position, inv.translation, atol=1e-3), what="the viewer at the camera")
    forward = np.asarray(client.camera.look_at) - np.asarray(client.camera.position)
    assert np.degrees(np.arccos(forward @ inv.R[:, 2] / np.linalg.norm(forward))) < 0.5
    assert not app.view3d.gizmo.visible
    # points the camera cannot see are dimmed, those it sees keep their colours
    pts, colours = app.displays[0].cloud()
    shown = np.asarray(app.view3d.cloud.colors)
    from l2e_studio.app.overlay import project_scene

    seen = np.zeros(len(pts), bool)
    seen[project_scene(pts, app.state.snapshot().extrinsic, app.camera).index] = True
    assert seen.any() and (~seen).any()
    assert np.array_equal(shown[seen], colours[seen]) and (shown[~seen].astype(int) <= colours[~seen] * 0.3).all()
    # pick one point and its pixel: armed again at once for the next pair, marker scaled with distance
    k = int(np.flatnonzero(seen)[0])
    app.pairs._on_scene_click(SimpleNamespace(ray_origin=tuple(inv.translation), ray_direction=tuple(pts[k] - inv.translation)))
    page.get_by_text("Now click the same spot").first.wait_for()
    dist = float(np.linalg.norm(app.pairs.pending - inv.translation))
    assert app.pairs._marker.point_size == pytest.approx(2 * max(0.03, 0.006 * dist), rel=1e-3)
    time.sleep(1.0)
    screenshot(page, "33_picking_mode")
    img = page.locator("img[src^='blob:']").first
    box = img.bounding_box()
    img.click(position={"x": box["width"] * 0.5, "y": box["height"] * 0.5})
    wait_for(lambda: len(app.pairs.pairs()) == 1 and app.pairs.armed and app.pairs.pending is None,
             what="the pair added and the next pick armed")
    page.get_by_role("button", name="Stop picking").click()
    wait_for(lambda: app.overlay.display_width == width0 and app.view3d.gizmo.visible, what="back to the normal layout")


def test_far_only_pairs_get_a_warning_after_solve_pnp(laptop, app):
    from l2e_studio.app.pairs import Pair
    from l2e_studio.geometry import project_points

    page = laptop
    truth = app.state.snapshot().extrinsic
    rng = np.random.default_rng(1)
    pts = np.column_stack([rng.uniform(38, 45, 8), rng.uniform(-10, 10, 8), rng.uniform(-3, 3, 8)])
    uv, _ = project_points(truth.transform(pts), app.camera)
    app.pairs.text.value = "\n".join(f"{a:.4f} {b:.4f} {c:.4f}  {u:.1f} {v:.1f}" for (a, b, c), (u, v) in zip(pts, uv))
    app.pairs.show()
    open_tab(page, "Seed")
    page.get_by_text("Initial guess from clicked pairs").click()
    solve = page.get_by_role("button", name="Solve PnP")
    expect(solve).to_be_enabled()  # the browser has the server's eight pairs (CI once clicked too early)
    solve.click()
    wait_for(lambda: "PnP over 8 pairs" in app.pairs.status.content, timeout=30,
             what=lambda: f"the PnP status; it reads {app.pairs.status.content!r}, pairs {len(app.pairs.pairs())}")
    page.get_by_text("PnP over 8 pairs").first.wait_for()
    page.get_by_text("add pairs close to the camera").first.wait_for()
    assert "translation uncertain by" in app.pairs.status.content or "unconstrained" in app.pairs.status.content
    screenshot(page, "34_pnp_far_pairs_warning")
    assert isinstance(app.pairs.pairs()[0], Pair)


def test_a_saved_result_is_offered_as_a_browser_download(laptop, app):
    page = laptop
    open_tab(page, "Optimise")
    page.get_by_text("Rotation only").click()
    page.get_by_role("button", name="Start").click()
    page.get_by_text("Finished").first.wait_for(timeout=180_000)
    open_tab(page, "Result")
    page.get_by_role("button", name="Save result").click()
    saved = wait_for(lambda: list(app.out_dir.glob("l2e_result_*.yaml")), what="the result file")
    link = page.locator("a[download]").filter(has_text="l2e_result_").first
    link.wait_for()
    with page.expect_download() as info:
        link.click()
    got = info.value
    assert got.suggested_filename == saved[0].name
    assert Path(got.path()).read_bytes() == saved[0].read_bytes()
    screenshot(page, "35_result_download")


def test_editing_a_display_field_keeps_the_overlay_in_view(laptop, app):
    page = laptop
    img = page.locator("img[src^='blob:']").first
    thumb = slider_root(page, "Point size (px)").get_by_role("slider")
    thumb.scroll_into_view_if_needed()
    y0 = img.bounding_box()["y"]
    size0 = app.overlay.point_size.value
    thumb.focus()
    page.keyboard.press("ArrowRight")  # one pixel larger
    wait_for(lambda: app.overlay.point_size.value == size0 + 1, what="point size one larger")
    frames = app.overlay.frames
    wait_for(lambda: app.overlay.frames > frames, what="a new frame")
    time.sleep(1.0)
    assert abs(img.bounding_box()["y"] - y0) < 5  # the overlay did not move away
    screenshot(page, "36_display_edit_keeps_overlay")


def test_load_seed_file_after_a_refused_value_puts_fields_sliders_and_state_in_step(laptop, app, tmp_path):
    """The third way back from a refused value (Reset and Undo: above): a seed file loaded by the
    upload button rewrites every field and slider, and the refusal goes with its text."""
    from l2e_studio.app.exact import format_value
    from l2e_studio.app.files import seed_document

    page = laptop
    open_tab(page, "Seed")
    loaded = app.state.reference.perturbed([0.012, -0.007, 0.004], np.radians([0.3, -0.2, 0.5]))
    path = tmp_path / "other_seed.yaml"
    path.write_bytes(seed_document(loaded))
    x, _ = problem_beside(page, "x")
    x.fill("1e9")
    page.get_by_text("x: 1e9 m is outside [-100, 100] m").first.wait_for()
    with page.expect_file_chooser() as chooser:
        page.get_by_role("button", name="Load seed file").click()
    chooser.value.set_files(str(path))
    page.get_by_text("other_seed.yaml: the sliders now show it").first.wait_for()
    wait_for(lambda: np.allclose(app.state.snapshot().extrinsic.matrix, loaded.matrix, atol=1e-9), what="the loaded seed")
    wait_for(lambda: x.input_value() == format_value(app.extrinsic.values[0]), what="x rewritten")
    assert app.extrinsic.values[0] == pytest.approx(loaded.translation[0], abs=1e-6)
    for i, axis in enumerate(("x", "y", "z", "roll", "pitch", "yaw")):
        assert exact_field(page, axis).input_value() == format_value(app.extrinsic.values[i]), axis
        assert app.extrinsic.sliders[i].value == pytest.approx(app.extrinsic.values[i], abs=1e-9), axis
    assert not any(p.visible for p in app.extrinsic.problems)
    assert page.get_by_text("x: 1e9 m is outside").count() == 0
    screenshot(page, "38_seed_loaded_after_refusal")


def test_the_swipe_is_the_default_before_after_comparison(laptop, app):
    """Nothing chosen: after a run, Before / after shows one map-wide image split by the swipe line
    (side by side would be two maps wide), and a drag on it moves the line."""
    page = laptop
    open_tab(page, "Optimise")
    page.get_by_text("Rotation only").click()
    page.get_by_role("button", name="Start").click()
    page.get_by_text("Finished").first.wait_for(timeout=180_000)
    page.get_by_role("tab", name="Before / after").click()
    wait_for(lambda: app.compare.frames >= 1 and app.compare.image.visible, what="the before/after image")
    assert app.compare.mode.value == "swipe"
    from test_app_browser import labelled

    assert labelled(page, "Compare").input_value() == "swipe"  # what the page shows chosen
    img = page.locator("img[src^='blob:']").nth(1)
    img.wait_for()
    w, h = page.evaluate("i => [i.naturalWidth, i.naturalHeight]", img.element_handle())
    assert w / h == pytest.approx(app.camera.width / app.camera.height, rel=0.03)  # one map, not two
    # the swipe line: the columns yellow from top to bottom (not a yellow point) in the image the page
    # decoded, at the middle (the amount starts at 0.5)
    line = page.evaluate("""i => { const c = document.createElement('canvas'); c.width = i.naturalWidth;
        c.height = i.naturalHeight; const g = c.getContext('2d'); g.drawImage(i, 0, 0);
        const d = g.getImageData(0, 0, c.width, c.height).data, cols = [];
        for (let x = 0; x < c.width; x++) { let n = 0;
            for (let y = 0; y < c.height; y++) { const k = 4 * (y * c.width + x);
                if (d[k] > 180 && d[k + 1] > 180 && d[k + 2] < 110) n++; }
            if (n > 0.8 * c.height) cols.push(x); }
        return cols; }""", img.element_handle())
    assert line and all(abs(x - w / 2) <= 3 for x in line), (line, w)
    screenshot(page, "39_before_after_swipe_default")
    box = img.bounding_box()
    page.mouse.move(box["x"] + box["width"] * 0.5, box["y"] + box["height"] / 2)
    page.mouse.down()
    for f in np.linspace(0.5, 0.25, 6):
        page.mouse.move(box["x"] + box["width"] * f, box["y"] + box["height"] / 2)
        time.sleep(0.08)
    page.mouse.up()
    wait_for(lambda: app.compare.amount.value == pytest.approx(0.25, abs=0.03), what="the swipe at 25 %")
    assert app.compare.mode.value == "swipe"


# --- the first-run hint ------------------------------------------------------------------------------

@contextmanager
def laptop_on(browser, folder: Path, out: Path):  # noqa: F811
    """A page at 1366x768 on an app over another scene folder: (page, app)."""
    from l2e_studio.app.server import build_app
    from l2e_studio.scenes import load_scene_folder

    other = build_app(load_scene_folder(folder), host="127.0.0.1", port=free_port(), out_dir=out)
    context = browser.new_context(viewport=LAPTOP)
    try:
        context.set_default_timeout(60_000)
        page = context.new_page()
        open_app(page, other)
        yield page, other
    finally:
        context.close()  # before the app stops
        other.stop()


def test_the_embedded_sample_opens_with_a_first_steps_hint(browser, tmp_path):  # noqa: F811
    """The sample as `l2e-studio app` with no folder opens it: the Scenes tab says at first sight
    that the seed is off on purpose (by truth.yaml's amounts) and what to press."""
    import yaml

    from l2e_studio.samples import sample_scenes_dir

    err = yaml.safe_load((sample_scenes_dir() / "truth.yaml").read_text())["seed_error"]
    with laptop_on(browser, sample_scenes_dir(), tmp_path / "results") as (page, _):
        hint = page.locator("text=First steps >> visible=true").first
        hint.wait_for()
        text = " ".join(hint.locator("xpath=ancestor::div[1]").inner_text().split())
        assert (f"seed is off on purpose, by {err['rotation_deg']:.1f}° and {100 * err['translation_m']:.1f} cm"
                in text), text
        assert "2.0° and 5.0 cm" in text  # the sample's own amounts, as the README tells them
        for words in ("Press Start in the Optimise tab", "compare in Before / after", "in the Result tab"):
            assert words in text, (words, text)
        box = hint.bounding_box()
        assert 0 <= box["y"] and box["y"] + box["height"] <= LAPTOP["height"]  # on screen without scrolling
        assert page.get_by_role("tab", name="Scenes").get_attribute("aria-selected") == "true"
        screenshot(page, "40_sample_first_steps")


@pytest.mark.parametrize("truth", ["absent", "without seed_error"])
def test_no_first_steps_hint_without_a_truth_file_saying_how_far_off_the_seed_is(browser, tmp_path, truth):  # noqa: F811
    from app_fixtures import write_small_scenes

    folder = write_small_scenes(tmp_path / "scenes", n_scenes=2)
    if truth == "absent":
        (folder / "truth.yaml").unlink()
    else:  # a truth file of a real rig: the transform only
        import yaml

        doc = yaml.safe_load((folder / "truth.yaml").read_text())
        (folder / "truth.yaml").write_text(yaml.safe_dump({"T_cam_lidar": doc["T_cam_lidar"]}))
    with laptop_on(browser, folder, tmp_path / "results") as (page, other):
        page.get_by_text("2 scenes").first.wait_for()  # the Scenes tab, drawn after the hint's place
        assert page.locator("text=First steps >> visible=true").count() == 0
        assert page.locator("text=off on purpose >> visible=true").count() == 0
        assert not other.scenes.hint.visible and other.scenes.hint.content == ""


# --- a real rig at default settings ------------------------------------------------------------------

RIGS = ("kitti_odometry_00", "hitsz_vlp16", "lcecalib_rles01_frame")  # 64 and 16 beams; 1241, 1440 and 346 px wide


@pytest.mark.realdata
@pytest.mark.parametrize("rig", RIGS)
def test_a_real_rig_at_default_settings_shows_its_points(browser, rig, tmp_path):  # noqa: F811
    """The first screen of a real rig, untouched: the points must be visible on the photo."""
    from l2e_studio.app.overlay import default_color_by
    from l2e_studio.app.server import build_app
    from l2e_studio.scenes import load_scene_folder

    root = REALDATA / rig
    if not (root / "reference.yaml").is_file():
        pytest.skip(f"{root} is absent")
    scene_set = load_scene_folder(root, seed_file=root / "reference.yaml")
    real = build_app(scene_set, host="127.0.0.1", port=free_port(), out_dir=tmp_path / "results")
    context = browser.new_context(viewport=LAPTOP)
    try:
        context.set_default_timeout(60_000)
        page = context.new_page()
        open_app(page, real)
        assert real.overlay.color_by.value == default_color_by(scene_set.scenes[0].map_kind)
        wait_for(lambda: real.overlay.frames > 0 and real.overlay.rest_frame, what="the frame at rest")
        time.sleep(1.0)
        path = screenshot(page, f"37_real_rig_default_{rig}")
        # the overlay as shown on screen: the points' colours must cover a good share of it
        import cv2

        shot = cv2.imread(str(path))[:, :, ::-1]
        box = page.locator("img[src^='blob:']").first.bounding_box()
        crop = shot[int(box["y"]): int(box["y"] + box["height"]), int(box["x"]): int(box["x"] + box["width"])]
        hsv = cv2.cvtColor(np.ascontiguousarray(crop), cv2.COLOR_RGB2HSV)
        coloured = (hsv[:, :, 1] > 120) & (hsv[:, :, 2] > 80)  # the maps are grey: colour is the points
        assert coloured.mean() > 0.002, coloured.mean()  # saturated colour on 0.2 % of the frame at least
    finally:
        context.close()
        real.stop()
