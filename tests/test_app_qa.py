"""The app's QA tab without a browser: held-out table, a background study, exports, the report."""

from __future__ import annotations

import pytest

from app_fixtures import free_port, write_small_scenes
from l2e_studio.calibrate import CalibrationSettings, calibrate
from l2e_studio.io.cameras import load_seed


@pytest.fixture(scope="module")
def scene_set(tmp_path_factory):
    from l2e_studio.scenes import load_scene_folder

    return load_scene_folder(write_small_scenes(tmp_path_factory.mktemp("qaapp") / "s", n_scenes=4))


@pytest.fixture
def app(scene_set, tmp_path):
    from l2e_studio.app.server import build_app

    a = build_app(scene_set, port=free_port(), out_dir=tmp_path / "out")
    yield a
    a.stop()


@pytest.mark.timeout(180)
def test_qa_tab_table_study_export_and_report(app, scene_set, tmp_path):
    qa = app.qa
    app.state.set_included(3, False)  # scene 3 is held out
    table = qa.score_now()
    assert table.held_out.tolist() == [False, False, False, True]
    assert "scene_003 (held out)" in qa.table.content and "[held out: 1 scenes pooled]" in qa.table.content

    qa.n_runs.value = 2
    thread = qa.start_study()
    thread.join(120)
    assert not thread.is_alive()
    assert len(qa.last_study.runs) == 2 and "2 runs" in qa.study_text.content
    assert qa.plot.visible and len(qa.plot.data[0]) == 2 and qa.progress.value == pytest.approx(100.0)

    res = calibrate(scene_set.scenes, scene_set.camera, scene_set.seed, CalibrationSettings())
    app.state.result = res
    for fmt in ("ros2", "urdf", "kalibr", "json"):
        name, data = qa.export_document(fmt)
        p = tmp_path / name
        p.write_bytes(data)
        assert res.extrinsic.error_to(load_seed(p))[0] < 1e-6
    path = qa.write_report()
    text = path.read_text()
    assert path.parent == app.out_dir and "scene_003 (held out)" in text and text.count("<img") >= 4 * 4
    qa.n_runs.value = 0
    assert qa.start_study() is None and "at least one run" in qa.study_text.content


@pytest.mark.timeout(120)
def test_qa_tab_says_when_the_scenes_show_one_place(scene_set, tmp_path):
    """Four takes of one scene (a rig that never moved): the QA tab's guardrails say that they
    pin no translation, where the count of scenes alone would pass; the four places do not."""
    from dataclasses import replace

    from l2e_studio.app.server import build_app

    takes = [replace(scene_set.scenes[0], name=f"take_{i}") for i in range(4)]
    for scenes, expect in ((takes, True), (scene_set.scenes, False)):
        a = build_app(replace(scene_set, scenes=scenes), port=free_port(), out_dir=tmp_path / f"out{expect}")
        try:
            a.qa.score_now()
            assert ("**one_place**: all 4 scenes show one place" in a.qa.table.content) is expect, a.qa.table.content
        finally:
            a.stop()
