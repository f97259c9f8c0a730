"""The running app without a browser: the GUI handles' callbacks, the 3D gizmo, scene
switching, seed files, display controls and results, checked through the shared state."""

from __future__ import annotations

import time

from types import SimpleNamespace

import numpy as np
import pytest

from app_fixtures import free_port, wait_for, write_small_scenes
from l2e_studio.app.panels.view3d import camera_pose, extrinsic_from_pose
from l2e_studio.app.pose import sliders_from_extrinsic
from l2e_studio.calibrate import CalibrationSettings
from l2e_studio.io.cameras import load_seed


@pytest.fixture(scope="module")
def scene_set(tmp_path_factory):
    from l2e_studio.scenes import load_scene_folder

    folder = write_small_scenes(tmp_path_factory.mktemp("srv") / "s", n_scenes=3)
    (folder / "lidar" / "scene_002.txt").write_text("1,2\n3,4\n")  # a broken scan: one failed scene
    return load_scene_folder(folder)


@pytest.fixture
def app(scene_set, tmp_path):
    from l2e_studio.app.server import build_app

    a = build_app(scene_set, port=free_port(), out_dir=tmp_path / "out")
    a.views.overlay_worker.wait_idle(10)
    a.views.mi_worker.wait_idle(10)
    yield a
    a.stop()


def user(client=None):
    """A GUI event as if a browser tab sent it."""
    return SimpleNamespace(client=client or SimpleNamespace(add_notification=lambda *a, **k: None,
                                                             send_file_download=lambda *a, **k: None), client_id=1)


def idle(app) -> None:
    for w in (app.views.overlay_worker, app.views.mi_worker, app.views.compare_worker, app.views.scene_3d_worker):
        assert w.wait_idle(20)


def test_failed_scene_is_listed_with_its_error(app, scene_set):
    assert [f.name for f in scene_set.failures] == ["scene_002"]
    assert app.state.scene_names == ["scene_000", "scene_001"]
    text = app.scenes.failures.content
    assert app.scenes.failures.visible and "scene_002" in text and "scene_002.txt" in text


def test_gizmo_and_sliders_edit_the_same_extrinsic(app):
    ext = app.state.reference.perturbed([0.02, -0.01, 0.03], [0.01, 0.02, -0.01])
    wxyz, pos = camera_pose(ext)
    assert np.allclose(extrinsic_from_pose(wxyz, pos).params, ext.params, atol=1e-12)
    app.view3d.gizmo.wxyz, app.view3d.gizmo.position = wxyz, pos
    app.view3d._on_gizmo(user())
    assert np.allclose(app.state.snapshot().extrinsic.params, ext.params, atol=1e-12)
    sliders = np.array([s.value for s in app.extrinsic.sliders])
    assert np.allclose(sliders, sliders_from_extrinsic(ext, app.state.reference), atol=1e-9)
    frames = app.overlay.frames
    idle(app)
    assert app.overlay.frames > frames
    # and the other way: a slider move re-poses the gizmo
    app.extrinsic.sliders[0].value = float(app.extrinsic.sliders[0].value) + 0.05
    app.extrinsic._on_slider(user(), 0)
    w2, p2 = camera_pose(app.state.snapshot().extrinsic)
    deadline = time.monotonic() + 5  # the gizmo follows slider moves once they rest (0.3 s)
    while not np.allclose(app.view3d.gizmo.position, p2) and time.monotonic() < deadline:
        time.sleep(0.02)
    assert np.allclose(app.view3d.gizmo.position, p2) and not np.allclose(p2, pos)


def test_scene_switch_changes_cloud_overlay_and_readout(app):
    cloud0 = np.array(app.view3d.cloud.points)
    image0 = app.overlay.image.image.copy()
    app.scenes.dropdown.value = "scene_001"
    app.select_scene(1)
    idle(app)
    assert app.state.snapshot().selected == 1
    # the cloud follows the overlay's frame at rest (drawing it must not hold up the new overlay)
    wait_for(lambda: app.view3d.shown_scene == 1, what="the 3D cloud of scene_001")
    assert app.overlay.rest_frame
    assert not np.array_equal(np.array(app.view3d.cloud.points), cloud0)
    assert not np.array_equal(app.overlay.image.image, image0)
    assert "scene_001" in app.overlay.caption.content and "scene_001" in app.extrinsic.readout.content


def test_exclusion_changes_the_pooled_mi_only(app):
    idle(app)
    before = app.reading
    app.state.set_included(1, False)
    app.inclusion_changed()
    idle(app)
    after = app.reading
    assert after.total != pytest.approx(before.total)
    assert np.allclose(after.per_scene, before.per_scene)
    assert "1 included scenes" in app.extrinsic.readout.content
    with pytest.raises(RuntimeError):
        app.state.set_all_included(False)
        app.start_run(CalibrationSettings())


def test_display_controls_change_the_overlay(app):
    idle(app)
    shots = [app.overlay.image.image.copy()]
    for handle, value in ((app.overlay.color_by, "depth"), (app.overlay.point_size, 7),
                          (app.overlay.contrast, 3.0), (app.overlay.map_mode, "smoothed")):
        handle.value = value  # programmatic updates run the same callbacks
        idle(app)
        shots.append(app.overlay.image.image.copy())
    for a, b in zip(shots, shots[1:]):
        assert not np.array_equal(a, b)


def test_seed_save_and_reset(app):
    ext = app.state.reference.perturbed([0.01, 0, 0], [0, 0, 0.01])
    app.set_extrinsic(ext, source="test")
    sent = {}
    client = SimpleNamespace(add_notification=lambda title, body, **k: sent.setdefault("note", (title, body)),
                             send_file_download=lambda name, data, **k: sent.setdefault("file", (name, data)))
    app.extrinsic._on_save(user(client))
    saved = list(app.out_dir.glob("seed_*.yaml"))
    assert len(saved) == 1 and sent["note"][0] == "Seed saved" and str(saved[0]) in sent["note"][1]
    assert np.allclose(load_seed(saved[0]).params, ext.params, atol=1e-9)
    assert sent["file"][1] == saved[0].read_bytes()
    app.extrinsic.reset.value = True  # a click
    # the reset button's click callback runs synchronously on assignment
    assert np.allclose(app.state.snapshot().extrinsic.params, app.state.reference.params)
    assert np.allclose([s.value for s in app.extrinsic.sliders][3:], 0, atol=1e-9)


def test_run_result_accept_and_discard(app):
    app.start_run(CalibrationSettings(rotation_only=True, coarse_to_fine=False))
    assert app.wait_run(120)
    snap = app.state.snapshot()
    assert snap.run.status == "done" and snap.result is not None
    assert not app.results.accept.disabled and not app.results.save.disabled
    assert "MI" in app.results.summary.content and "scene_000" in app.results.table.content
    idle(app)
    assert app.compare.frames >= 1 and app.compare.image.visible
    for mode in ("swipe", "blend"):
        app.compare.mode.value = mode
        idle(app)
        dw = app.overlay.display_width  # drawn at the panel's frame width (points at their screen size)
        assert app.compare.image.image.shape == (round(app.camera.height * dw / app.camera.width), dw, 3)
    app.accept_result()
    assert np.allclose(app.state.snapshot().extrinsic.params, snap.result.extrinsic.params)
    app.discard_result()
    idle(app)
    assert app.results.accept.disabled and not app.compare.image.visible
    with pytest.raises(RuntimeError):
        app.save_result()


def test_sliders_widen_their_range_for_a_far_extrinsic(app):
    ref = app.state.reference
    far = ref.perturbed([1.3, 0.0, 0.0], [0.0, 0.0, np.radians(40.0)])
    app.set_extrinsic(far, source="file")
    x, roll = app.extrinsic.sliders[0], app.extrinsic.sliders[3]  # optical z = body forward: a roll
    assert x.min <= far.translation[0] <= x.max and x.value == pytest.approx(far.translation[0])
    assert roll.min <= roll.value <= roll.max and roll.value == pytest.approx(40.0)
    values = np.array([s.value for s in app.extrinsic.sliders])
    from l2e_studio.app.pose import extrinsic_from_sliders

    assert np.allclose(extrinsic_from_sliders(values, ref).params, far.params, atol=1e-9)


def test_a_failing_run_is_reported_and_the_app_carries_on(app, monkeypatch):
    import l2e_studio.app.runs as runs_module

    def broken(*args, **kwargs):
        raise ValueError("the optimiser fell over")

    notes = []
    monkeypatch.setattr(runs_module, "calibrate", broken)
    monkeypatch.setattr(app, "notify_all", lambda title, body, color=None: notes.append((title, body)))
    app.start_run(CalibrationSettings())
    assert app.wait_run(30)
    run = app.state.snapshot().run
    assert run.status == "failed" and "fell over" in run.error
    assert notes and notes[-1][0] == "Optimisation failed" and "fell over" in notes[-1][1]
    assert not app.optimise.start.disabled and app.optimise.cancel.disabled
    assert "Failed" in app.optimise.status.content


def test_fine_gizmo_moves_a_tenth_and_catches_up_at_rest(app):
    start = app.state.snapshot().extrinsic
    wxyz, pos = camera_pose(start)
    app.view3d.fine.value = True
    app.view3d.gizmo.position = pos + np.array([0.10, 0.0, 0.0])  # a 10 cm drag in the lidar frame
    app.view3d._on_gizmo(user())
    moved = app.state.snapshot().extrinsic
    _, pos2 = camera_pose(moved)
    assert np.allclose(pos2 - pos, [0.01, 0.0, 0.0], atol=1e-9)  # a tenth of it
    deadline = time.monotonic() + 5  # at rest the gizmo goes to the true pose
    while not np.allclose(app.view3d.gizmo.position, pos2) and time.monotonic() < deadline:
        time.sleep(0.02)
    assert np.allclose(app.view3d.gizmo.position, pos2)
    # a rotation step is scaled too
    from scipy.spatial.transform import Rotation

    from l2e_studio.app.panels.view3d import scaled_gizmo_step

    w0, p0 = camera_pose(start)
    turned = Rotation.from_rotvec([0, 0, 0.2]) * Rotation.from_quat([w0[1], w0[2], w0[3], w0[0]])
    x, y, z, w = turned.as_quat()
    got = scaled_gizmo_step(start, (w0, p0), (np.array([w, x, y, z]), p0), 0.1)
    assert start.error_to(got)[0] == pytest.approx(np.degrees(0.02), rel=1e-6)  # (deg, m): 0.2 rad / 10


def test_the_verdict_is_shown_beside_the_result_and_saved(app):
    import yaml

    app.start_run(CalibrationSettings())
    assert app.wait_run(180)
    snap = app.state.snapshot()
    v = snap.verdict
    assert v is not None and v.status in ("trusted", "trusted-rotation", "not-trusted")
    assert f"Verdict: {v.summary()}" in app.results.summary.content
    for reason in v.reasons:
        assert reason in app.results.summary.content
    rotation = ("Accept rotation (seed's translation kept)" if v.seed_axes == "xyz" else
                f"Accept (seed's translation kept along {', '.join(v.seed_axes)})")
    expected = {"trusted": "Accept as seed", "trusted-rotation": rotation,
                "not-trusted": "Accept anyway (not trusted)"}[v.status]
    if v.seed_stands:  # every part moved within its spread: nothing to accept but the seed itself
        expected = "Keep the seed (confirmed)"
    elif v.settled:  # some part did: the label names what of the seed is kept
        expected = f"Accept (seed's {' and '.join(v.from_seed())} kept)"
    assert app.results.accept.label == expected
    path, _ = app.save_result()
    doc = yaml.safe_load(path.read_text())
    assert doc["verdict"]["status"] == v.status and doc["verdict"]["summary"] == v.summary()
    app.accept_result()
    accepted = app.state.snapshot().extrinsic
    wanted = v.extrinsic if v.trusted else snap.result.extrinsic
    assert np.allclose(accepted.params, wanted.params)


def test_camera_images_are_read_out_and_optimised_with_the_edge_score(tmp_path):
    """Scenes of camera images: the readout shows the score the optimiser climbs (the edge
    score), labelled as such, and ``objective`` overrides it."""
    from l2e_studio.app.server import build_app
    from l2e_studio.scenes import load_scene_folder
    from l2e_studio.synth import SynthConfig, write_dataset

    folder = write_dataset(tmp_path / "img", SynthConfig(n_scenes=2, width=320, height=180, points_per_scan=6000,
                                                         seed=4, map_kind="image"))
    scene_set = load_scene_folder(folder)
    for objective, name, label in (("auto", "edges", "edge score"), ("mi", "mi", "MI")):
        a = build_app(scene_set, port=free_port(), out_dir=tmp_path / "out", objective=objective)
        try:
            assert a.readout.stack.objective_name == name and a.readout.label == label
            a.views.mi_worker.wait_idle(10)
            assert f"**{label} ·" in a.extrinsic.readout.content
            a.start_run(CalibrationSettings(coarse_to_fine=False))
            assert a.wait_run(120)
            assert a.state.snapshot().result.objective == name
        finally:
            a.stop()
