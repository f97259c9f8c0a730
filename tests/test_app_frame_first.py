"""The overlay frame goes out first: after a slider step the score readout starts only once the
frame of that state is handed to viser, and after a scene switch the two scene tables and the
before/after images follow the new scene's frame (a real app on a real port, no browser)."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from app_fixtures import free_port, wait_for, write_small_scenes
from l2e_studio.app.panels import overlay_view


@pytest.fixture(scope="module")
def scene_set(tmp_path_factory):
    from l2e_studio.scenes import load_scene_folder

    return load_scene_folder(write_small_scenes(tmp_path_factory.mktemp("scenes") / "small"))


@pytest.fixture
def app(scene_set, tmp_path):
    from l2e_studio.app.server import build_app

    a = build_app(scene_set, port=free_port(), out_dir=tmp_path / "out")
    a.views.overlay_worker.wait_idle(30)
    a.views.mi_worker.wait_idle(30)
    time.sleep(0.5)  # the first frame at rest and the tables
    yield a
    a.stop()


def record(app, monkeypatch) -> list[tuple[float, str, int]]:
    """(time, what, state version) of each frame handed to viser, readout started, table and
    before/after drawn, from now on."""
    events: list[tuple[float, str, int]] = []
    lock = threading.Lock()

    def note(what: str) -> None:
        with lock:
            events.append((time.perf_counter(), what, app.state.snapshot().version))

    send = overlay_view.send_jpeg
    monkeypatch.setattr(overlay_view, "send_jpeg", lambda h, img, data: (note("frame"), send(h, img, data))[1])
    read = app.readout.read
    monkeypatch.setattr(app.readout, "read", lambda *a, **k: (note("readout"), read(*a, **k))[1])
    for name, obj, attr in (("scene table", app.scenes, "_table"), ("target table", app.target, "_table"),
                            ("before/after", app.compare, "render")):
        real = getattr(obj, attr)
        monkeypatch.setattr(obj, attr, lambda *a, _r=real, _n=name, **k: (note(_n), _r(*a, **k))[1])
    return events


def first(events, what: str, version: int) -> float:
    return next(t for t, w, v in events if w == what and v >= version)


def test_the_readout_starts_after_the_frame_of_a_slider_step(app, monkeypatch):
    events = record(app, monkeypatch)
    for k in range(3):
        ext = app.state.snapshot().extrinsic.perturbed([0.002 * (k + 1), 0, 0], [0, 0, 0.001])
        app.set_extrinsic(ext, source="sliders")
        version = app.state.snapshot().version
        wait_for(lambda: any(w == "readout" and v >= version for _, w, v in events), what="the readout")
        assert first(events, "frame", version) < first(events, "readout", version)
        app.views.mi_worker.wait_idle(10)
        app.views.overlay_worker.wait_idle(10)


def test_a_scene_switch_sends_the_frame_before_the_tables_and_before_after(app, monkeypatch):
    events = record(app, monkeypatch)
    app.select_scene(1)
    version = app.state.snapshot().version
    wait_for(lambda: {"scene table", "target table", "before/after", "readout"} <= {w for _, w, v in events if v >= version},
             what="the tables, before/after and the readout after the switch")
    frame = first(events, "frame", version)
    assert all(frame < first(events, what, version) for what in ("scene table", "target table", "before/after", "readout"))
    assert "**" + app.state.scene_names[1] + "**" in app.scenes.table.content  # the table shows the new selection
    assert np.isfinite(app.reading.per_scene[1])


def test_the_workbench_reads_and_climbs_the_edge_gradient_it_was_started_with(tmp_path):
    """``serve --edge-gradient scan-lines``: the live score, the Optimise tab's settings and the
    run's result all read the gradient across the scan lines."""
    from l2e_studio.app.server import build_app
    from l2e_studio.scenes import load_scene_folder

    folder = write_small_scenes(tmp_path / "img", map_kind="image", n_scenes=2)
    scene_set = load_scene_folder(folder)
    a = build_app(scene_set, port=free_port(), out_dir=tmp_path / "out", edge_gradient="scan-lines")
    try:
        assert a.readout.stack.gradient == "scan-lines" and a.readout.stack.scan is not None
        settings = a.run_settings()
        assert settings.edge_gradient == "scan-lines"
        a.start_run(settings)
        wait_for(lambda: a.state.snapshot().result is not None, timeout=120)
        assert a.state.snapshot().result.edge_gradient == "scan-lines"
    finally:
        a.stop()
