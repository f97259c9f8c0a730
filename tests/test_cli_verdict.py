"""The verdict through the real CLI: in the summary, in the result file, and what it hands back."""

from __future__ import annotations

import shutil
from pathlib import Path

import yaml

from l2e_studio.geometry import Extrinsic
from l2e_studio.synth import SynthConfig, read_truth, write_dataset
from test_cli_calibrate import run_cli


def test_a_good_result_is_trusted_and_written(small_synth_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "r.yaml"
    proc = run_cli("calibrate", "--scenes", small_synth_dir, "--out", out, "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert "verdict: trusted" in proc.stdout
    doc = yaml.safe_load(out.read_text())
    assert doc["verdict"]["status"] == "trusted" and doc["verdict"]["reasons"] == []
    assert doc["score"]["objective"] == "mi"
    assert all(c["passed"] for c in doc["verdict"]["checks"].values())
    truth = read_truth(small_synth_dir / "truth.yaml")
    deg, m = Extrinsic.from_matrix(doc["T_cam_lidar"]).error_to(truth)
    assert deg < 0.2 and m < 0.025  # four small scenes (test_cli_calibrate's tolerance)


def test_an_untrusted_result_keeps_the_seed_or_is_marked(tmp_path: Path) -> None:
    # the paper's MI on camera images with sky, shading and unrelated texture: pulled away
    config = SynthConfig(n_scenes=3, width=480, height=270, points_per_scan=12_000, seed=5, map_kind="image",
                         traps=("sky", "shading", "texture"), seed_error_deg=2.0, seed_error_m=0.1)
    folder = write_dataset(tmp_path / "trap", config)
    truth = read_truth(folder / "truth.yaml")
    out = tmp_path / "r.yaml"
    proc = run_cli("calibrate", "--scenes", folder, "--objective", "mi", "--out", out, "--quiet")
    assert proc.returncode == 0, proc.stderr
    doc = yaml.safe_load(out.read_text())
    optimiser = Extrinsic.from_matrix(doc["optimiser_result"]["T_cam_lidar"])
    seed = Extrinsic.from_matrix(doc["seed"]["T_cam_lidar"])
    written = Extrinsic.from_matrix(doc["T_cam_lidar"])
    if optimiser.error_to(truth)[0] > seed.error_to(truth)[0]:
        assert doc["verdict"]["status"] == "not-trusted" and doc["verdict"]["kept_seed"]
        assert written.error_to(seed)[0] < 1e-6
        assert "verdict: not trusted: the seed is kept" in proc.stdout.splitlines()
        assert any(line.startswith("  - ") for line in proc.stdout.splitlines())  # one line per reason
        marked = tmp_path / "m.yaml"
        run_cli("calibrate", "--scenes", folder, "--objective", "mi", "--on-untrusted", "mark", "--out", marked, "--quiet")
        mdoc = yaml.safe_load(marked.read_text())
        assert mdoc["verdict"]["status"] == "not-trusted" and not mdoc["verdict"]["kept_seed"]
        assert Extrinsic.from_matrix(mdoc["T_cam_lidar"]).error_to(optimiser)[0] < 0.05
    assert written.error_to(truth)[0] <= seed.error_to(truth)[0] + 0.1


def test_photos_under_event_are_scored_as_images(tmp_path: Path) -> None:
    folder = write_dataset(tmp_path / "img", SynthConfig(n_scenes=2, width=320, height=180, points_per_scan=6000,
                                                        seed=4, map_kind="image"))
    shutil.move(folder / "image", folder / "event")  # the reference layout: everything under event/
    out = tmp_path / "r.yaml"
    proc = run_cli("calibrate", "--scenes", folder, "--out", out, "--quiet", "--no-verdict")
    assert proc.returncode == 0, proc.stderr
    notes = [line for line in proc.stderr.splitlines() if line.startswith("note:")]
    assert len(notes) == 1 and "look like camera images" in notes[0] and "--map-kind events" in notes[0]
    assert yaml.safe_load(out.read_text())["score"]["objective"] == "edges"
    forced = tmp_path / "f.yaml"
    proc = run_cli("calibrate", "--scenes", folder, "--map-kind", "events", "--out", forced, "--quiet", "--no-verdict")
    assert proc.returncode == 0 and "note:" not in proc.stderr
    assert yaml.safe_load(forced.read_text())["score"]["objective"] == "mi"


def test_the_edge_gradient_is_chosen_on_the_command_line_and_recorded(tmp_path: Path) -> None:
    """``--edge-gradient scan-lines`` climbs maps of the gradient across the scan lines; the result
    file says which gradient the edge score read, and the default is the magnitude."""
    folder = write_dataset(tmp_path / "img", SynthConfig(n_scenes=2, width=320, height=180, points_per_scan=6000,
                                                        seed=4, map_kind="image"))
    docs = {}
    for gradient in ("magnitude", "scan-lines"):
        out = tmp_path / f"{gradient}.yaml"
        args = ("--edge-gradient", gradient) if gradient != "magnitude" else ()
        proc = run_cli("calibrate", "--scenes", folder, *args, "--out", out, "--quiet", "--no-verdict")
        assert proc.returncode == 0, proc.stderr
        docs[gradient] = yaml.safe_load(out.read_text())
        assert docs[gradient]["score"]["edge_gradient"] == gradient
    # the same seed, two different maps: the scores differ
    assert docs["magnitude"]["score"]["seed"] != docs["scan-lines"]["score"]["seed"]
    proc = run_cli("calibrate", "--scenes", folder, "--edge-gradient", "sobel", "--out", tmp_path / "x.yaml")
    assert proc.returncode != 0 and "sobel" in proc.stderr
