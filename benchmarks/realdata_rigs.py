"""The real dev rigs in ../shared/realdata (read in place, never copied), as scenes + camera +
reference extrinsic. Used by bench_realdata.py and the real-data tests; absent data -> empty."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from l2e_studio.camera import CameraModel
from l2e_studio.geometry import Extrinsic
from l2e_studio.io.cameras import load_rig, load_seed
from l2e_studio.io.lidar import load_lidar
from l2e_studio.io.maps import load_map
from l2e_studio.scenes import Scene, load_scene_folder

#: ``L2E_REALDATA`` overrides where the data sits (a worktree is one level deeper than the repo).
REALDATA = Path(os.environ.get("L2E_REALDATA", Path(__file__).resolve().parents[2] / "shared" / "realdata"))
OPENCALIB = REALDATA / "opencalib_lidar2camera"
KITTI = REALDATA / "kitti_mmdet3d_000008"
#: Scene folders of several scenes each (the reference in each folder's reference.yaml).
FOLDERS = ("kitti_odometry_00", "hitsz_vlp16", "lcecalib_rlfs01", "lcecalib_rles01_frame", "lcecalib_rles01_event")
SINGLE = ("manual", "1+2", "3", "kitti")
ALL = SINGLE + FOLDERS


@dataclass(frozen=True)
class Rig:
    name: str
    camera: CameraModel
    reference: Extrinsic
    scenes: tuple[Scene, ...]
    board: Path | None = None  # the folder's target.yaml, when a checkerboard is in view


def _image(folder: Path) -> Path:
    return next(p for p in sorted(folder.iterdir()) if p.suffix in (".jpg", ".png"))


def _scene(name: str, lidar: Path, image: Path) -> tuple[Scene, np.ndarray]:
    scan = load_lidar(lidar)
    grey, kind = load_map(image)
    return Scene(name, scan.points, scan.intensity, grey, kind, lidar, image), grey


def load_rigs(names: list[str] | None = None) -> list[Rig]:
    """The dev rigs that are present: the four single-scene ones (OpenCalib manual, OpenCalib
    1+2, OpenCalib 3, KITTI 000008) and the scene folders of :data:`FOLDERS` (``all``: every one)."""
    rigs: list[Rig] = []
    want = set(names or SINGLE)
    if "all" in want:
        want |= set(ALL)
    if "manual" in want and (OPENCALIB / "manual_calib").is_dir():
        d = OPENCALIB / "manual_calib" / "data"
        sc, grey = _scene("manual", d / "0.pcd", d / "0.png")
        rig = load_rig(d / "center_camera-intrinsic.json")  # its json says 1080 rows; the image wins
        rigs.append(Rig("manual", rig.camera(grey.shape[1], grey.shape[0]),
                        load_seed(d / "top_center_lidar-to-center_camera-extrinsic.json"), (sc,)))
    for group in (["1", "2"], ["3"]):
        if "+".join(group) not in want:
            continue
        root = OPENCALIB / "auto_calib_v2.0" / "data" / "ours"
        if not all((root / n).is_dir() for n in group):
            continue
        scenes = []
        for n in group:
            sc, grey = _scene(n, root / n / "calib.pcd", _image(root / n))
            scenes.append(sc)
        rig = load_rig(root / group[0] / "calib.txt")
        rigs.append(Rig("+".join(group), rig.camera(grey.shape[1], grey.shape[0]), rig.seed, tuple(scenes)))
    if "kitti" in want and KITTI.is_dir():
        c = json.loads((KITTI / "calib_derived.json").read_text())
        camera = CameraModel(np.array(c["K"]), c["image_width"], c["image_height"], np.array(c["D"], float))
        sc, _ = _scene("000008", KITTI / "000008.bin", KITTI / "000008.png")
        rigs.append(Rig("kitti", camera, Extrinsic.from_matrix(np.array(c["T_cam_lidar"])), (sc,)))
    for name in FOLDERS:
        if name in want and (REALDATA / name / "reference.yaml").is_file():
            folder = load_scene_folder(REALDATA / name, REALDATA / name / "reference.yaml", use_cache=False)
            board = REALDATA / name / "target.yaml"
            rigs.append(Rig(name, folder.camera, folder.seed, tuple(folder.scenes), board if board.is_file() else None))
    return rigs


def split(rigs: list[Rig], k: int = 1) -> list[Rig]:
    """Every ``k`` consecutive scenes of ``rigs`` as a rig of their own (``<rig>/<first scene>``,
    ``+<n>`` for more than one; the same camera and reference; a short last group is dropped):
    one rig's scans, calibrated apart, are as many rigs whose answers must agree with each other,
    the sharper test of a verdict than one scan's reference."""
    return [Rig(f"{r.name}/{r.scenes[i].name}" + (f"+{k - 1}" if k > 1 else ""), r.camera, r.reference,
                r.scenes[i:i + k], r.board)
            for r in rigs for i in range(0, len(r.scenes) - k + 1, k)]


def _elevations_deg(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(elevation in deg, range in m) of each of the (N, 3) lidar-frame points (0 deg at range 0)."""
    P = np.asarray(points, dtype=np.float64)
    r = np.linalg.norm(P, axis=1)
    return np.degrees(np.arcsin(np.clip(P[:, 2] / np.where(r > 0, r, 1.0), -1.0, 1.0))), r


def ring_elevations(points: np.ndarray, bin_deg: float = 0.02, min_range_m: float = 5.0,
                    min_gap_deg: float = 0.25) -> np.ndarray:
    """The elevations (deg, descending) of a spinning lidar's rings: the peaks, at least
    ``min_gap_deg`` apart, of the histogram of its points' elevations beyond ``min_range_m``
    (nearer, the lasers' offsets on the head blur the rings as seen from the origin)."""
    from scipy.signal import find_peaks

    el, r = _elevations_deg(points)
    el = el[r > min_range_m]
    edges = np.arange(el.min() - bin_deg, el.max() + 2 * bin_deg, bin_deg)
    h = np.histogram(el, edges)[0].astype(float)
    peaks, _ = find_peaks(h, distance=max(int(min_gap_deg / bin_deg), 1), prominence=0.1 * h.max())
    return np.sort(edges[peaks] + bin_deg / 2)[::-1]


def sparse(rigs: list[Rig], spacing_deg: float) -> list[Rig]:
    """Each rig's scans with only the rings at least ``spacing_deg`` apart (from the top ring
    down; each kept ring's points within half the scan's median ring gap of it): a
    64-beam drive seen as a 16-beam lidar would see it (``<rig>~<spacing>deg``), the same camera,
    images and reference. Whether a sparse lidar fails for its rings or for its rigs' static
    scenes can then be told apart."""
    out = []
    for rig in rigs:
        rings = ring_elevations(rig.scenes[0].points)
        kept = [rings[0]]
        for e in rings[1:]:
            if kept[-1] - e >= spacing_deg - 1e-6:
                kept.append(e)
        gaps = np.abs(np.diff(rings))
        half = 0.5 * float(np.median(gaps))  # the scan's own ring gap bounds how far a ring spreads
        scenes = []
        for sc in rig.scenes:
            el, _ = _elevations_deg(sc.points)
            keep = np.min(np.abs(el[:, None] - np.asarray(kept)[None, :]), axis=1) < half
            scenes.append(replace(sc, points=sc.points[keep], intensity=sc.intensity[keep]))
        out.append(Rig(f"{rig.name}~{spacing_deg:g}deg", rig.camera, rig.reference, tuple(scenes), rig.board))
    return out


def resized(rigs: list[Rig], width: int) -> list[Rig]:
    """Each rig's images (and camera) resized to ``width`` pixels across (``<rig>@<width>px``): a
    drive seen by a camera as small as a DAVIS346 (346 x 260), the scans and reference the same."""
    out = []
    for rig in rigs:
        factor = width / rig.camera.width
        camera = rig.camera.scaled(factor)
        scenes = tuple(replace(sc, event_map=cv2.resize(sc.event_map, (camera.width, camera.height),
                                                        interpolation=cv2.INTER_AREA)) for sc in rig.scenes)
        out.append(Rig(f"{rig.name}@{width}px", camera, rig.reference, scenes, rig.board))
    return out


def cropped(rigs: list[Rig], hfov_deg: float) -> list[Rig]:
    """Each rig's images cut to the central ``hfov_deg`` degrees across (``<rig>|<hfov>deg``; the
    rows kept whole): a drive seen through a lens as narrow as HITSZ's (34 deg), the scans and
    reference the same."""
    out = []
    for rig in rigs:
        cam = rig.camera
        half = cam.K[0, 0] * np.tan(np.radians(hfov_deg) / 2)
        u0, u1 = max(int(round(cam.K[0, 2] - half)), 0), min(int(round(cam.K[0, 2] + half)), cam.width)
        K = cam.K.copy()
        K[0, 2] -= u0
        camera = CameraModel(K, u1 - u0, cam.height, cam.D, cam.model)
        scenes = tuple(replace(sc, event_map=np.ascontiguousarray(sc.event_map[:, u0:u1])) for sc in rig.scenes)
        out.append(Rig(f"{rig.name}|{hfov_deg:g}deg", camera, rig.reference, scenes, rig.board))
    return out


def perturbations(n: int, deg: float, m: float, rng_seed: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """``n`` (dt, drotvec) offsets of exactly ``m`` metres and ``deg`` degrees, random axes and directions."""
    rng = np.random.default_rng(rng_seed)
    out = []
    for _ in range(n):
        a, b = rng.normal(size=3), rng.normal(size=3)
        out.append((m * a / np.linalg.norm(a), np.radians(deg) * b / np.linalg.norm(b)))
    return out


def synthetic_rigs(lidars: list[str], scene_counts: list[int], seed: int = 11, revolutions: int = 1,
                   phase_locked: bool = False) -> list[Rig]:
    """Rigs of synthetic garage scenes with a known truth, as an unseen rig's stand-in: camera
    images with every failure mode of real ones (``--realism``), seen by the spinning lidar
    ``lidars`` (``synth.lidars.LIDARS`` names) in ``scene_counts`` scenes each (built in memory;
    the reference is the truth); each scene's cloud ``revolutions`` of the lidar accumulated (at
    phases of their own, or one with ``phase_locked``), as a static rig records."""
    from l2e_studio.synth.dataset import SynthConfig, make_rig, make_scene

    rigs = []
    tag = "" if revolutions == 1 else f"_x{revolutions}" + ("locked" if phase_locked else "")
    for lidar in lidars:
        for n in scene_counts:
            config = SynthConfig(n_scenes=n, map_kind="image", realism=True, lidar=lidar, seed=seed,
                                 lidar_sweeps=revolutions, lidar_phase_locked=phase_locked)
            camera, truth, _ = make_rig(config)
            scenes = []
            for i in range(n):
                points, intensity, grey = make_scene(config, i, truth, camera)
                scenes.append(Scene(f"scene_{i:03d}", points, intensity, grey.astype(np.float32), "image"))
            rigs.append(Rig(f"synth_{lidar}_{n}{tag}", camera, truth, tuple(scenes)))
    return rigs

