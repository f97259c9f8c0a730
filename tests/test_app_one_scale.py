"""One score, one scale: on an edge-score run (camera images, multi-start search) the curve's best
never falls, at stage changes or new starts, and is named "edge score"; the Optimise tab, the
Result tab and the readout after Accept show the same number for the same pose."""

from __future__ import annotations

import numpy as np
import pytest

from app_fixtures import free_port, wait_for, write_small_scenes
from l2e_studio.app.panels.optimise import curve_data
from l2e_studio.app.text import score_num
from l2e_studio.calibrate import CalibrationSettings


@pytest.fixture(scope="module")
def app(tmp_path_factory):
    from l2e_studio.app.server import build_app
    from l2e_studio.scenes import load_scene_folder

    ss = load_scene_folder(write_small_scenes(tmp_path_factory.mktemp("scale") / "s", map_kind="image"))
    a = build_app(ss, port=free_port(), out_dir=tmp_path_factory.mktemp("out"))
    a.set_extrinsic(a.state.reference.perturbed([0.03, -0.02, 0.02], np.radians([0.6, -0.5, 0.4])), "typed")
    yield a
    a.stop()


@pytest.mark.timeout(300)
def test_edge_score_run_one_scale_everywhere(app):
    assert app.readout.label == "edge score"
    app.start_run(CalibrationSettings())
    assert app.wait_run(240)
    snap = app.state.snapshot()
    r, run = snap.result, snap.run
    assert r.objective == "edges" and len(r.ends) >= 2  # the multi-start search ran
    # the raw stage values do fall where a stage or a start begins (the reason for one scale) ...
    h = np.asarray(run.history)
    changes = np.flatnonzero(np.diff(h[:, 3]) != 0) + 1
    assert (h[changes, 2] < h[changes - 1, 2]).any()
    # ... the curve does not: best so far on the readout's scale, ending on the result
    x, y, stage = curve_data(run)
    assert np.all(np.diff(y) >= 0) and np.all(np.diff(x) >= 0)
    assert run.best_curve[-1] == (r.evaluations, pytest.approx(r.score_result, rel=1e-9, abs=1e-12))
    assert set(stage) <= {1.0, 2.0, 3.0} and (np.diff(stage) < 0).any()  # new starts climb the stages again
    assert "edge score" in app.optimise.plot.series[1]["label"] and "MI" not in app.optimise.plot.series[1]["label"]

    handed = score_num(app.result_scores.accepted.score)
    assert float(handed) != 0.0 and len(handed.split(".")[1].lstrip("0")) >= 4  # 4 significant digits
    assert f"edge score {handed}" in app.optimise.status.content  # Optimise tab, after the run
    assert f"edge score {handed}" in app.results.summary.content  # Result tab
    app.accept_result()
    wait_for(lambda: app.views.mi_worker.wait_idle(5) and app.reading is not None
             and np.allclose(app.reading.extrinsic.params, snap.accepted.params), what="the readout at the result")
    assert f"included scenes: {handed}" in app.extrinsic.readout.content  # readout after Accept
