"""A real lidar + frame camera recording (../shared/realdata/opencalib_lidar2camera, OpenCalib).

Loads the PCD intensities and K/D, checks that the reference extrinsic makes the projected
points line up with the image (overlay written to test-artifacts/), and runs a calibration
from a seed 2 deg / 5 cm away. Run as a script to print the nearness per scene and overall.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from l2e_studio.geometry import Extrinsic, in_image, project_points
from l2e_studio.io.cameras import load_rig, load_seed
from l2e_studio.io.lidar import load_lidar
from l2e_studio.io.maps import load_map

pytestmark = pytest.mark.realdata

ROOT = Path(__file__).resolve().parents[2] / "shared" / "realdata" / "opencalib_lidar2camera"
ARTIFACTS = Path(__file__).resolve().parents[1] / "test-artifacts"


@dataclass
class RealScene:
    name: str
    points: np.ndarray
    intensity: np.ndarray
    image: np.ndarray
    camera: object
    reference: Extrinsic


def _scene(name: str) -> RealScene:
    if not ROOT.is_dir():
        pytest.skip(f"{ROOT} is absent")
    if name == "manual":
        d = ROOT / "manual_calib" / "data"
        rig, ref = load_rig(d / "center_camera-intrinsic.json"), load_seed(d / "top_center_lidar-to-center_camera-extrinsic.json")
        scan, (image, kind) = load_lidar(d / "0.pcd"), load_map(d / "0.png")
    else:
        d = ROOT / "auto_calib_v2.0" / "data" / "ours" / name
        rig = load_rig(d / "calib.txt")
        ref = rig.seed
        scan = load_lidar(d / "calib.pcd")
        image, kind = load_map(next(p for p in sorted(d.iterdir()) if p.suffix in (".jpg", ".png")))
    assert kind == "image"
    # The intrinsic json says 1080 rows but the image has 1200 (SOURCE.md): the image size wins.
    camera = rig.camera(image.shape[1], image.shape[0])
    return RealScene(name, scan.points, scan.intensity, image, camera, ref)


NAMES = ["manual", "1", "2", "3"]


@pytest.mark.parametrize("name", NAMES)
def test_loads_with_intensities_and_intrinsics(name: str) -> None:
    s = _scene(name)
    assert s.image.shape == (1200, 1920)
    assert len(s.points) > 70_000
    assert s.intensity.min() >= 0 and s.intensity.max() <= 255 and np.unique(s.intensity).size > 50
    assert s.camera.K[0, 0] > 2000 and s.camera.D.size in (4, 5)


def _correlation(s: RealScene, T: Extrinsic) -> float:
    """Pearson correlation of lidar intensity and (lightly blurred) image grey under the points."""
    import cv2

    uv, front = project_points(T.transform(s.points), s.camera)
    ok = front & in_image(uv, s.camera)
    grey = cv2.GaussianBlur(s.image, (0, 0), 1.5)
    px = np.rint(uv[ok]).astype(int)
    return float(np.corrcoef(s.intensity[ok], grey[px[:, 1], px[:, 0]])[0, 1])


@pytest.mark.parametrize("name", NAMES)
def test_reference_extrinsic_lines_up_with_the_image(name: str) -> None:
    s = _scene(name)
    uv, front = project_points(s.reference.transform(s.points), s.camera)
    ok = front & in_image(uv, s.camera)
    _overlay(s, uv[ok], s.intensity[ok], ARTIFACTS / f"opencalib_{name}_overlay.png")
    assert ok.sum() > 5_000
    if name in ("1", "2"):
        pytest.xfail("scenes 1/2: intensity and grey are not positively correlated (see the overlay)")
    # Retro-reflective paint, signs and poles are bright for both sensors: the correlation peaks
    # at the reference and falls when the rotation is off by 1 deg about any axis.
    at_ref = _correlation(s, s.reference)
    off = [_correlation(s, s.reference.perturbed(np.zeros(3), np.radians(d) * axis))
           for d in (1.0, -1.0) for axis in np.eye(3)]
    assert at_ref > 0.25 and at_ref > max(off), (at_ref, off)


def _overlay(s: RealScene, uv: np.ndarray, inten: np.ndarray, path: Path) -> None:
    """Half-size image with the projected points coloured by lidar intensity."""
    import cv2

    path.parent.mkdir(parents=True, exist_ok=True)
    small = cv2.resize(np.clip(s.image, 0, 255).astype(np.uint8), (960, 600), interpolation=cv2.INTER_AREA)
    base = cv2.cvtColor(small, cv2.COLOR_GRAY2BGR)
    colours = cv2.applyColorMap(np.clip(inten * 3, 0, 255).astype(np.uint8).reshape(-1, 1), cv2.COLORMAP_JET)[:, 0]
    px = np.clip(np.rint(uv / 2).astype(int), 0, [959, 599])
    base[px[:, 1], px[:, 0]] = colours
    cv2.imwrite(str(path), base)


def _perturbations() -> list[tuple[np.ndarray, np.ndarray]]:
    """Seeds 2 deg and 5 cm away from the reference, in a few fixed directions."""
    rng = np.random.default_rng(2023)
    out = []
    for _ in range(2):
        a, b = rng.normal(size=3), rng.normal(size=3)
        out.append((0.05 * a / np.linalg.norm(a), np.radians(2.0) * b / np.linalg.norm(b)))
    return out


def calibrate_from_perturbed(scene_names: list[str]) -> list[tuple[float, float, float, float]]:
    """(start deg, start m, end deg, end m) for each perturbed seed, all given scenes together."""
    from l2e_studio.calibrate import CalibrationSettings, calibrate
    from l2e_studio.scenes import Scene

    loaded = [_scene(n) for n in scene_names]
    ref, camera = loaded[0].reference, loaded[0].camera
    scenes = [Scene(s.name, s.points, s.intensity, s.image, "image") for s in loaded]
    settings = CalibrationSettings(translation_bound=0.2, rotation_bound_deg=5.0)
    rows = []
    for dt, dr in _perturbations():
        seed = ref.perturbed(dt, dr)
        result = calibrate(scenes, camera, seed, settings)
        rows.append((*seed.error_to(ref), *result.extrinsic.error_to(ref)))
    return rows


# Scenes 1 and 2 share one rig (same K, D, T); "manual" and "3" each have their own.
GROUPS = [["manual"], ["1"], ["2"], ["3"], ["1", "2"]]


def test_street_scenes_never_end_below_the_seed_and_are_flagged_as_unreliable() -> None:
    """The DESIGN.md pitfall on real data: lidar intensity against a street image has its MI peak
    degrees from the reference. The engine must not hand back a pose the MI scores below the
    seed, and the quality check must say the answer cannot be trusted."""
    from l2e_studio.calibrate import calibrate
    from l2e_studio.evaluate import assess
    from l2e_studio.objective import SceneStack
    from l2e_studio.scenes import Scene

    loaded = [_scene(n) for n in ("1", "2")]
    ref, camera = loaded[0].reference, loaded[0].camera
    stack = SceneStack.build([Scene(s.name, s.points, s.intensity, s.image, "image") for s in loaded], camera, 2.0)
    dt, dr = _perturbations()[0]
    seed = ref.perturbed(dt, dr)
    result = calibrate(stack, None, seed)
    assert result.score_result >= result.score_seed
    report = assess(stack, result.extrinsic, seed, subsets=2)
    assert any(w.startswith(("unstable", "flat")) for w in report.warnings), report.warnings


if __name__ == "__main__":  # print the nearness table: python tests/test_realdata_opencalib.py
    groups = [g.split("+") for g in sys.argv[1:]] or GROUPS
    for group in groups:
        for start_deg, start_m, end_deg, end_m in calibrate_from_perturbed(group):
            print(f"{'+'.join(group):8s} start {start_deg:.2f} deg {start_m * 100:.1f} cm -> "
                  f"end {end_deg:.2f} deg {end_m * 100:.1f} cm", flush=True)
