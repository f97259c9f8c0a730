"""The workbench's target mode without a browser: the board fields, the detections and their marks,
a checkerboard run through the same Runner, and a frame left out by a click changing the result."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from app_fixtures import free_port
from l2e_studio.app.panels.target import BOARD_POINT_RGB, check_board, draw_board_marks

pytestmark = pytest.mark.timeout(400)

#: small frame-camera board scenes: quick to detect and to solve
BOARDS = dict(n_scenes=6, modality="frame", width=640, height=360, seed=12)


@pytest.fixture(scope="module")
def board_set(tmp_path_factory):
    from l2e_studio.scenes import load_scene_folder
    from l2e_studio.synth import TargetConfig, write_target_dataset

    return load_scene_folder(write_target_dataset(tmp_path_factory.mktemp("boards") / "b", TargetConfig(**BOARDS)))


@pytest.fixture(scope="module")
def app(board_set, tmp_path_factory):
    from l2e_studio.app.server import build_app

    a = build_app(board_set, port=free_port(), out_dir=tmp_path_factory.mktemp("out"))
    assert a.target.worker.wait_idle(120)
    yield a
    a.stop()


def user():
    return SimpleNamespace(client=SimpleNamespace(add_notification=lambda *a, **k: None), client_id=1)


def test_board_fields_are_checked_as_typed():
    ok = check_board("10 x 7", "0,068", "0.8 x 0.6")
    assert ok.board is not None and ok.board.squares == (10, 7) and ok.board.square_m == pytest.approx(0.068)
    assert check_board("10x7", "0.068", "").board.size_m == pytest.approx((0.68, 0.476))  # blank: the grid alone
    bad = check_board("2 x 7", "0.068", "0.8 x 0.6")
    assert bad.board is None and "3..100" in bad.problems[0]
    assert "metres" in check_board("10 x 7", "zero", "").problems[1]
    small = check_board("10 x 7", "0.068", "0.5 x 0.4")
    assert small.board is None and "smaller than the printed grid" in small.problems[2]
    assert check_board("10.5 x 7", "0.068", "").board is None


def test_marks_draw_board_points_and_corners():
    image = np.zeros((100, 160, 3), np.uint8)
    out = draw_board_marks(image, np.array([[40.0, 30.0], [60.0, 30.0]]), np.array([[100.0, 70.0]]), 3)
    assert tuple(out[70, 100]) == BOARD_POINT_RGB and tuple(out[70, 103]) != BOARD_POINT_RGB
    ring = out[25:36, 35:46]
    assert ring[..., 0].max() > 150 and ring[..., 1].max() < 120  # the first corner red
    assert out[20:41, 50:71, 1].max() > 150  # the next green
    assert not image.any()  # drawn on a copy


def test_detections_fill_the_table_and_mark_the_overlay(app):
    v = app.target
    assert "target.yaml" in v.source.content
    assert v.squares.value == "10 x 7"
    assert sum(x.detected for x in v.views.values()) == len(app.scene_set.scenes)
    assert "✓" in v.table.content and "scene_005" in v.table.content
    snap = app.state.snapshot()
    with_marks = app.overlay.draw(0, snap.extrinsic)
    v.marks.value = False
    without = app.overlay.draw(0, snap.extrinsic)
    v.marks.value = True
    magenta = lambda im: int(np.count_nonzero(np.all(im == BOARD_POINT_RGB, axis=2)))  # noqa: E731
    if v.views["scene_000"].board_indices is not None:
        assert magenta(with_marks) > 50 and magenta(without) == 0
    assert np.count_nonzero(np.any(with_marks != without, axis=2)) > 200  # the corners at least
    # a refused board disables detection and a checkerboard start, with the reason
    v.square.value = "-1"
    v.check()
    assert v.detect.disabled and v.square_problem.visible
    app.optimise.calibration.value = "checkerboard"
    app.optimise.show_start()
    assert app.optimise.start.disabled and "Target tab" in app.optimise.blocker.content
    v.square.value = "0.068"
    v.check()
    app.optimise.show_start()
    assert not app.optimise.start.disabled


def _run(app) -> object:
    app.start_run(app.run_settings(), "checkerboard")
    assert app.wait_run(300)
    snap = app.state.snapshot()
    assert snap.run.status == "done", snap.run.error
    return snap.result


def test_a_checkerboard_run_and_a_frame_left_out_by_a_click(app):
    from l2e_studio.synth import read_truth

    truth = read_truth(app.scene_set.root / "truth.yaml")
    first = _run(app)
    assert first.method == "target" and first.target is not None
    deg, m = first.extrinsic.error_to(truth)
    assert m < 0.01 and deg < 0.5  # a calibration, not the seed (2 deg / 5 cm off)
    assert "checkerboard" in app.results.summary.content
    assert "used" in app.target.status.content
    rows = [r.split("|") for r in app.target.table.content.splitlines() if r.startswith("| ✓ |")]
    assert len(rows) == 6 and all(float(r[6]) > 0 and float(r[7]) > 0 for r in rows)  # plane, edge RMS (mm)
    verdict = app.state.snapshot().verdict
    assert verdict is not None and f"Verdict: {verdict.summary()}" in app.results.summary.content
    # one score, one scale: the Result tab's numbers are the readout's, under the readout's name
    # (the run's own "board planes" are minus mm; they were shown as the seed's beside the readout's)
    label, names = app.readout.label, app.state.scene_names
    assert label != "board planes" and f"**{label} " in app.results.summary.content
    assert "board planes" not in app.results.summary.content + app.results.table.content
    at_seed = app.readout.read(first.seed, [True] * len(names)).per_scene
    rows = {r.split("|")[1].strip(): r.split("|") for r in app.results.table.content.splitlines() if r.startswith("| scene_")}
    for i, n in enumerate(names):
        assert float(rows[n][2]) == pytest.approx(at_seed[i], rel=1e-3, abs=1e-6), (n, rows[n])
    assert sum(bool(v.used) for v in app.target.views.values()) >= 4
    # a click on the first cell of scene_002's row leaves it out (the page writes this pointer)
    app.scenes.pointer.value = "toggle:scene_002,1"
    app.scenes._on_row_click(user())
    assert app.state.snapshot().included[2] is False
    second = _run(app)
    record = next(f for f in second.target.frames if f.name == "scene_002")
    assert not record.used and "left out by the user" in record.reason
    assert not np.allclose(second.extrinsic.params, first.extrinsic.params)
    assert "left out by the user" in app.target.table.content
    # the same exports as a score climb: the result file with the board's section
    import yaml

    path, png = app.save_result()
    doc = yaml.safe_load(path.read_text())
    assert doc["method"] == "target" and png is not None and png.is_file()
    frames = {f["name"]: f for f in doc["target"]["frames"]}
    assert frames["scene_002"]["used"] is False and frames["scene_000"]["used"] is True


def test_a_checkerboard_run_cancels(app):
    app.start_run(app.run_settings(), "checkerboard")
    assert app.cancel_run()
    assert app.wait_run(120)
    snap = app.state.snapshot()
    assert snap.run.status == "cancelled" and snap.result.cancelled and snap.verdict is None


def test_a_targetless_run_is_checked_against_the_detected_boards(app):
    """With boards detected, a score-climb run's verdict also weighs the boards (evidence the
    optimiser never climbed): the check is in the verdict the Result tab and the file show."""
    from l2e_studio.synth import read_truth
    from l2e_studio.verdict import Verdict

    check = app.target.evidence()
    assert check is not None
    truth = read_truth(app.scene_set.root / "truth.yaml")
    stack = app.readout.stack
    wrong = truth.perturbed([0, 0, 0], np.radians([1.5, 0, 0]))
    judged = check(stack, Verdict("trusted", wrong, False, (), (), 0.0), app.scene_set.seed)
    assert judged.status == "not-trusted" and judged.reasons[-1].startswith("boards agree")
    assert check(stack, Verdict("trusted", truth, False, (), (), 0.0), app.scene_set.seed).status == "trusted"

    app.start_run(app.run_settings(), "score climb (targetless)")
    assert app.wait_run(300)
    snap = app.state.snapshot()
    assert snap.run.status == "done" and snap.result.method != "target"
    assert any(c.name == "boards agree" for c in snap.verdict.checks), [c.name for c in snap.verdict.checks]
