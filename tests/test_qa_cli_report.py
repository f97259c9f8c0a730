"""The QA sub-commands end to end on a small synthetic folder, their bad-input handling, and the
HTML report opened in a real headless Chromium (every image must load)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
import yaml

from l2e_studio.cli import main as cli_main
from l2e_studio.synth import SynthConfig, write_dataset

ARTIFACTS = Path(__file__).resolve().parents[1] / "test-artifacts" / "qa"
CFG = SynthConfig(n_scenes=5, width=320, height=180, points_per_scan=5000, seed=4)


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return write_dataset(tmp_path_factory.mktemp("qacli") / "scenes", CFG)


@pytest.fixture(scope="module")
def calibrated(folder, tmp_path_factory):
    """A result file calibrated on four scenes (scene_004 is left out) with a verdict section."""
    out = tmp_path_factory.mktemp("res")
    train = out / "train"
    import shutil

    shutil.copytree(folder, train, ignore=shutil.ignore_patterns("scene_004.*", ".l2e_cache"))
    result = out / "result.yaml"
    assert cli_main(["calibrate", "--scenes", str(train), "--out", str(result), "--quiet"]) == 0
    doc = yaml.safe_load(result.read_text())
    doc["verdict"] = {"trusted": True, "reasons": ["held-out MI above the seed", "sharp landscape"]}
    result.write_text(yaml.safe_dump(doc, sort_keys=False))
    return result


def _one_error_line(capsys, text):
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("l2e-studio: error: ") and text in err[0], err
    return err[0]


def test_heldout_cli_table(folder, calibrated, tmp_path, capsys):
    out = tmp_path / "table.json"
    rc = cli_main(["heldout", "--scenes", str(folder), "--candidate", f"release={calibrated}", "--held-out", "scene_004",
                   "--group", "early=scene_000,scene_001", "--calibrate", "--out", str(out)])
    assert rc == 0
    assert capsys.readouterr().out.count("scenes pooled]") == 5  # one row per group, not eaten as markup
    t = json.loads(out.read_text())
    assert [c["name"] for c in t["candidates"]] == ["seed", "result", "truth", "release"]
    assert set(t["groups"]) == {"held out", "training", "early", "rest", "all"}
    g = t["groups"]["held out"]
    assert g["scenes"] == 1 and g["result"] > g["seed"] + 0.05 and g["release"] > g["seed"] + 0.05
    assert any(d["a"] == "result" and d["b"] == "release" for d in t["differences"])


def test_study_cli_repeatability_and_scenes(folder, tmp_path, capsys):
    out = tmp_path / "rep.json"
    rc = cli_main(["study", "repeatability", "--scenes", str(folder), "-n", "3", "--noise-m", "0.02", "--noise-deg", "1",
                   "--workers", "2", "--out", str(out), "--quiet"])
    assert rc == 0
    d = json.loads(out.read_text())
    assert d["summary"]["runs"] == 3 and d["summary"]["reference"] == "truth" and len(d["runs"]) == 3
    assert "SLSQP" in d["summary"]["methods"]
    out2 = tmp_path / "scenes.json"
    assert cli_main(["study", "scenes", "--scenes", str(folder), "-n", "2", "--counts", "2,5", "--workers", "2",
                     "--out", str(out2), "--quiet"]) == 0
    d2 = json.loads(out2.read_text())
    assert set(d2["summary"]["scene_counts"]) == {"2", "5"}


@pytest.mark.parametrize("argv, text", [
    (["-n", "0"], "at least one run, got N=0"),
    (["--noise-m", "-0.1"], "noise levels must be finite and >= 0"),
    (["--noise-deg", "-1"], "noise levels must be finite and >= 0"),
    (["--methods", "Adam"], "unknown optimiser 'Adam'"),
])
def test_study_cli_bad_input_is_one_line_and_writes_nothing(folder, tmp_path, capsys, argv, text):
    out = tmp_path / "s.json"
    assert cli_main(["study", "repeatability", "--scenes", str(folder), "--out", str(out), *argv]) == 2
    _one_error_line(capsys, text)
    assert list(tmp_path.iterdir()) == []


def test_study_cli_dask_address_that_does_not_answer(folder, tmp_path, capsys):
    pytest.importorskip("distributed", reason="dask[distributed] is not installed")
    out = tmp_path / "s.json"
    assert cli_main(["study", "repeatability", "--scenes", str(folder), "-n", "2", "--dask", "tcp://127.0.0.1:9",
                     "--out", str(out)]) == 2
    _one_error_line(capsys, "no Dask scheduler answers at tcp://127.0.0.1:9")
    assert list(tmp_path.iterdir()) == []


def test_landscape_cli(folder, calibrated, tmp_path, capsys):
    out = tmp_path / "land.json"
    assert cli_main(["landscape", "--scenes", str(folder), "--at", str(calibrated), "--steps", "7", "--pair", "x,ry",
                     "--out", str(out)]) == 0
    d = json.loads(out.read_text())
    assert [s["axis"] for s in d["sweeps"]] == ["x", "y", "z", "rx", "ry", "rz"]
    assert d["sweep2d"]["axes"] == ["x", "ry"] and len(d["sweep2d"]["mi"]) == 5
    assert cli_main(["landscape", "--scenes", str(folder), "--pair", "x,w", "--out", str(tmp_path / "l2.json")]) == 2
    _one_error_line(capsys, "unknown axis 'w'")


def _read_only_dir(tmp_path) -> Path:
    if os.geteuid() == 0:  # root writes through permission bits: use a place no one can create files in
        return Path("/proc/l2e-qa-report-test")
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    return ro


def test_report_into_a_read_only_folder_is_one_line_exit_2(calibrated, folder, tmp_path, capsys):
    ro = _read_only_dir(tmp_path)
    assert cli_main(["report", "--result", str(calibrated), "--scenes", str(folder), "--out", str(ro / "r.html")]) == 2
    _one_error_line(capsys, "cannot write here")
    assert not (ro / "r.html").exists()


@pytest.fixture(scope="module")
def report(folder, calibrated, tmp_path_factory):
    out = tmp_path_factory.mktemp("report")
    study = out / "rep.json"
    assert cli_main(["study", "repeatability", "--scenes", str(folder), "-n", "3", "--noise-m", "0.02", "--noise-deg", "1",
                     "--methods", "SLSQP,L-BFGS-B", "--workers", "2", "--out", str(study), "--quiet"]) == 0
    scenes = out / "scenes.json"
    assert cli_main(["study", "scenes", "--scenes", str(folder), "-n", "2", "--counts", "2,5", "--workers", "2",
                     "--out", str(scenes), "--quiet"]) == 0
    html = out / "report.html"
    assert cli_main(["report", "--result", str(calibrated), "--scenes", str(folder), "--study", str(study),
                     "--study", str(scenes), "--group", "early=scene_000,scene_001", "--steps", "9",
                     "--out", str(html)]) == 0
    return html


def test_report_is_self_contained_and_holds_every_section(report):
    text = report.read_text()
    assert "http://" not in text.replace("http://www.w3.org", "") and "https://" not in text  # nothing fetched
    assert "<script src" not in text and "<link" not in text
    for needle in ("TRUSTED", "held-out MI above the seed", "static_transform_publisher --x", "&lt;joint name=", "T_cam_lidar",
                   "scene_004 (held out)", "Pooled by group", "curvature (Hessian + scene jackknife)",
                   "true error of the result", "repeatability spread (SLSQP", "L-BFGS-B", "sha256", "camera.yaml",
                   "TRUSTED: the result passed every check", "result (handed back)", "drx (deg)",
                   "scene_000 (event map)", "coloured by intensity over the event map", "# status: trusted"):
        assert needle in text, needle
    data = json.loads(text.split('id=\'l2e-qa-data\'>')[1].split("</script>")[0].replace("<\\/", "</"))
    assert data["verdict"]["trusted"] is True
    assert data["scores"]["groups"]["held out"]["scenes"] == 1
    assert len(data["inputs"]) >= 12 and all(len(f["sha256"]) == 64 for f in data["inputs"])
    # before and after for each of the 5 scenes, full size and crop, plus the plots
    assert text.count("<img") == 5 * 4 + 2 + 1 + 1  # overlays, landscapes, scatter, scene count


@pytest.mark.browser
@pytest.mark.timeout(120)
def test_report_opens_in_chromium_and_every_image_loads(report):
    from app_fixtures import launch_browser, need_chromium

    need_chromium()
    from playwright.sync_api import sync_playwright

    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    with sync_playwright() as pw:
        browser = launch_browser(pw)
        try:
            page = browser.new_page(viewport={"width": 1366, "height": 768})  # a laptop, as the app tests
            page.route("**/*", lambda route: route.abort() if not route.request.url.startswith(("file:", "data:"))
                       else route.continue_())  # offline: anything fetched from the network fails
            page.goto(report.as_uri())
            page.wait_for_load_state("load")
            widths = page.evaluate("() => Array.from(document.images).map(i => [i.alt, i.complete, i.naturalWidth])")
            assert len(widths) == 24
            assert all(done and w > 0 for _, done, w in widths), widths
            assert page.locator("h2").all_inner_texts()[:2] == ["Verdict", "Result, in every export form"]
            page.screenshot(path=str(ARTIFACTS / "report_top.png"))
            page.evaluate("document.getElementById('scores').scrollIntoView()")
            page.screenshot(path=str(ARTIFACTS / "report_scores.png"))
            page.evaluate("document.getElementById('overlays').scrollIntoView()")
            page.screenshot(path=str(ARTIFACTS / "report_overlays.png"))
            page.screenshot(path=str(ARTIFACTS / "report_full.png"), full_page=True)
        finally:
            browser.close()


def test_a_report_on_scenes_of_one_place_says_they_pin_no_translation(folder, calibrated, tmp_path):
    """Four takes of one place (the rig never moved): the report's guardrails say so, and that
    more takes of it would not pin the translation (the count of scenes alone looks fine)."""
    import shutil

    one = tmp_path / "one_place"
    shutil.copytree(folder, one, ignore=shutil.ignore_patterns("scene_00[1-9].*", ".l2e_cache"))
    for k in (1, 2, 3):
        for sub, ext in (("lidar", "txt"), ("event", "png")):
            shutil.copy(one / sub / f"scene_000.{ext}", one / sub / f"scene_00{k}.{ext}")
    html = tmp_path / "one.html"
    assert cli_main(["report", "--result", str(calibrated), "--scenes", str(one), "--steps", "5",
                     "--out", str(html)]) == 0
    text = html.read_text()
    assert "all 4 scenes show one place" in text and "no translation" in text
