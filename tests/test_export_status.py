"""The verdict travels with the result: every export format states it, in its own comment syntax,
and a result without a verdict (cancelled, or not judged) says so in the file and in the exports."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from dataclasses import replace

import numpy as np
import pytest
import yaml

from l2e_studio.cli import main as cli_main
from l2e_studio.export import EXPORT_FORMATS, export_text, result_to_dict, write_result
from l2e_studio.geometry import Extrinsic
from l2e_studio.io.cameras import load_seed
from l2e_studio.verdict import Check, Verdict
from test_export import CAM, fake_result

COMMENT = {"matrix": "#", "ros1": "#", "ros2": "#", "kalibr": "#", "yaml": "#", "urdf": "<!--"}


def rotation_verdict(res) -> Verdict:
    """``trusted-rotation`` as judge() returns it: the result's rotation, the seed's translation."""
    mixed = Extrinsic(res.extrinsic.rotvec, res.seed.translation)
    check = Check("halves agree (translation)", False, "refined on either half alone the translation moves 4.0 cm")
    return Verdict("trusted-rotation", mixed, False, (f"{check.name}: {check.detail}",), (check,), 1.0)


def comment_lines(text: str, fmt: str) -> list[str]:
    return [ln for ln in text.splitlines() if ln.lstrip().startswith(COMMENT[fmt])]


@pytest.mark.parametrize("fmt", list(EXPORT_FORMATS))
def test_trusted_rotation_exports_say_the_translation_is_the_seeds(tmp_path, fmt):
    res = fake_result()
    v = rotation_verdict(res)
    doc = result_to_dict(res, CAM, verdict=v)
    text = export_text(v.extrinsic, fmt, result=doc)
    if fmt == "json":
        data = json.loads(text)
        assert data["status"] == "trusted-rotation"
        assert any("SEED's translation" in n for n in data["status_notes"])
        assert data["verdict"]["status"] == "trusted-rotation"
    else:
        notes = " ".join(comment_lines(text, fmt))
        assert "status: trusted-rotation" in notes and "SEED's translation, not calibrated" in notes
    if fmt == "urdf":
        ET.fromstring(f"<robot>{text}</robot>")  # still well-formed XML ("--" never inside a comment)
    path = tmp_path / f"T{EXPORT_FORMATS[fmt]}"
    path.write_text(text)
    back = load_seed(path)  # the header does not stop it reading back
    assert np.allclose(back.matrix, v.extrinsic.matrix, atol=1e-8)
    assert np.allclose(back.translation, res.seed.translation, atol=1e-9)


@pytest.mark.parametrize("fmt", ["ros1", "urdf", "matrix"])
def test_a_seed_file_export_says_it_has_no_verdict(fmt):
    text = export_text(Extrinsic([0.1, 0.2, 0.3], [0.0, 0.1, 0.2]), fmt)
    assert "status: no verdict" in " ".join(comment_lines(text, fmt))


def test_a_cancelled_run_is_not_judged_in_the_file_and_its_exports(tmp_path):
    res = replace(fake_result(), cancelled=True, message="cancelled")
    path, _ = write_result(tmp_path / "r.yaml", res, CAM)
    doc = yaml.safe_load(path.read_text())
    assert doc["verdict"]["status"] == "not judged" and doc["verdict"]["cancelled"] is True
    assert doc["cancelled"] is True and doc["optimiser"]["cancelled"] is True
    ros = export_text(load_seed(path), "ros2", result=doc)
    assert "# status: not judged" in ros and "cancelled" in ros


def test_judging_cancelled_after_a_finished_run_says_cancelled(tmp_path):
    path, _ = write_result(tmp_path / "r.json", fake_result(), CAM, judging_cancelled=True)
    doc = json.loads(path.read_text())
    assert doc["cancelled"] is True and doc["optimiser"]["cancelled"] is False  # the optimiser itself finished
    assert doc["verdict"] == {"status": "not judged", "summary": "not judged: its judging was cancelled",
                              "cancelled": True}


def test_export_cli_prints_the_status_and_require_trusted_refuses(tmp_path, capsys):
    res = fake_result()
    v = rotation_verdict(res)
    path, _ = write_result(tmp_path / "r.yaml", res, CAM, verdict=v)
    out = tmp_path / "exports"
    assert cli_main(["export", str(path), "--format", "ros1,urdf", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "status: trusted-rotation" in printed and "SEED's translation" in printed
    assert "status: trusted-rotation" in (out / "T_cam_lidar.ros1.txt").read_text()
    refused = tmp_path / "refused"
    assert cli_main(["export", str(path), "--require-trusted", "--out", str(refused)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'trusted-rotation', not 'trusted'" in err[0] and "r.yaml" in err[0]
    assert not refused.exists()
    trusted = replace(v, status="trusted", reasons=(), extrinsic=res.extrinsic)
    ok, _ = write_result(tmp_path / "ok.yaml", res, CAM, verdict=trusted)
    assert cli_main(["export", str(ok), "--require-trusted", "--format", "matrix", "--out", str(tmp_path / "m.txt")]) == 0
    assert "# status: trusted (trusted:" in (tmp_path / "m.txt").read_text()


@pytest.mark.parametrize("fmt", ["ros2", "urdf", "kalibr", "json"])
def test_a_confirmed_seed_says_so_in_every_export(fmt):
    """A trusted verdict whose result moved within its spread hands back the seed: each export
    says the seed's values stand and why, and reads back as the seed."""
    from l2e_studio.verdict import Spread

    res = fake_result()
    note = "the seed's rotation stands (the result turned 0.05 deg from it, within 2x the 0.10 deg its independent estimates spread)"
    v = Verdict("trusted", res.seed, False, (), (), 1.0, (), "", Spread(0.1, 0.004), True, "xyz", note)
    doc = result_to_dict(res, CAM, verdict=v)
    assert doc["verdict"]["spread"] == {"rotation_deg": 0.1, "translation_m": 0.004}
    text = export_text(v.extrinsic, fmt, result=doc)
    said = " ".join(json.loads(text)["status_notes"]) if fmt == "json" else " ".join(comment_lines(text, fmt))
    assert "the seed stands, confirmed" in said and "SEED's values stand" in said and "0.05 deg" in said
    if fmt == "urdf":
        ET.fromstring(f"<robot>{text}</robot>")
