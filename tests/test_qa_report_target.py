"""The HTML report of a checkerboard result: the per-frame table and the residual plot, end to end
from ``l2e-studio calibrate`` (the board's target.yaml in the folder) to ``l2e-studio report``."""

from __future__ import annotations

import base64
import re

import cv2
import numpy as np
import pytest
import yaml

from l2e_studio.cli import main as cli_main

pytestmark = pytest.mark.timeout(600)


def test_report_of_a_checkerboard_result_has_the_frames_and_the_residual_plot(tmp_path):
    from l2e_studio.synth import TargetConfig, write_target_dataset

    folder = write_target_dataset(tmp_path / "boards", TargetConfig(n_scenes=4, modality="frame", width=640,
                                                                    height=360, seed=12))
    # one frame without a board: listed and skipped, in the result file and in the report
    cv2.imwrite(str(folder / "image" / "scene_003.png"), np.full((360, 640), 90, np.uint8)
                + np.random.default_rng(0).integers(0, 40, (360, 640), dtype=np.uint8))
    result = tmp_path / "result.yaml"
    assert cli_main(["calibrate", "--scenes", str(folder), "--out", str(result), "--quiet"]) == 0
    doc = yaml.safe_load(result.read_text())
    assert doc["method"] == "target"
    page = tmp_path / "report.html"
    assert cli_main(["report", "--result", str(result), "--scenes", str(folder), "--steps", "3",
                     "--out", str(page)]) == 0
    html = page.read_text()
    section = html[html.index("<h2 id='target'>"):]
    section = section[: section.index("<h2", 5)]
    rows = re.findall(r"<tr>(.*?)</tr>", section)
    frames = {f["name"]: f for f in doc["target"]["frames"]}
    for name, f in frames.items():
        row = next(r for r in rows if name in r)
        if f["used"]:
            assert f"{1000 * f['plane_rms_m']:.1f}" in row  # plane RMS in mm, as the file holds it
        else:
            assert "left out" in row and (f["reason"] or "").split(":")[0] in row
    assert not frames["scene_003"]["detected"]
    assert "Board found in 3 of 4 images" in section
    png = re.search(r"alt='checkerboard residuals per frame' src='data:image/png;base64,([^']+)'", section)
    image = cv2.imdecode(np.frombuffer(base64.b64decode(png.group(1)), np.uint8), cv2.IMREAD_COLOR)
    assert image is not None and image.shape[0] > 300 and image.shape[1] > 400
    assert "per-axis standard deviation" in section
