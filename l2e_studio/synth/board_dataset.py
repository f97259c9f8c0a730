"""Synthetic checkerboard sequences with a known answer (``l2e-studio synth --target checkerboard``).

A static rig (a 16-beam lidar and a camera ``camera_offset_m`` apart) and a board held up at a
different pose in each scene. The folder is laid out like the real checkerboard sets::

    DIR/image/<stem>.png   (frame, e2vid)   or   DIR/event/<stem>.png   (events, events-moving)
    DIR/lidar/<stem>.pcd   binary PCD: x y z intensity ring
    DIR/camera.yaml        the camera and the seed (the truth perturbed by seed_error_*)
    DIR/target.yaml        the board (kind, squares [columns, rows], square_m, size_m)
    DIR/truth.yaml         the true T_cam_lidar, each scene's true T_cam_board, the generator

Everything comes from ``seed``: the same seed writes the same folder.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from ..atomic import atomic_write_bytes
from ..camera import CameraModel
from ..errors import InputError
from ..geometry import LIDAR_TO_CAMERA_AXES, Extrinsic
from .board import Board, pixel_rays
from .board_views import IMAGE_MODALITIES, MODALITIES, render_view
from .board_world import board_in_view, board_pose, lidar_scan, make_board_scene
from .lidars import LIDARS, LidarModel
from .dataset import clear_out_dir, perturb, scene_stem

LENSES = ("radtan", "equidistant")


@dataclass(frozen=True)
class TargetConfig:
    """Everything that shapes a synthetic board sequence. ``width``/``height`` 0: the
    modality's sensor (1280 x 720 for ``frame``, the DAVIS346's 346 x 260 otherwise)."""

    n_scenes: int = 10
    modality: str = "frame"
    lens: str = "radtan"
    width: int = 0
    height: int = 0
    squares: tuple[int, int] = (10, 7)
    square_m: float = 0.068
    size_m: tuple[float, float] = (0.8, 0.6)
    distance_m: tuple[float, float] = (1.5, 4.0)
    seed: int = 0
    seed_error_deg: float = 2.0
    seed_error_m: float = 0.05
    range_noise_m: float = 0.015
    camera_offset_m: tuple[float, float] = (0.05, 0.15)
    lidar: str = "vlp16"

    def __post_init__(self) -> None:
        if self.modality not in MODALITIES:
            raise ValueError(f"modality must be one of {', '.join(MODALITIES)}")
        if self.lens not in LENSES:
            raise ValueError(f"lens must be one of {', '.join(LENSES)}")
        if self.lidar not in LIDARS:
            raise ValueError(f"lidar must be one of {', '.join(LIDARS)}")
        if self.n_scenes < 1:
            raise ValueError("need at least 1 scene")
        if (self.width or self.height) and (self.width < 64 or self.height < 48):
            raise ValueError("the image must be at least 64 x 48 pixels")
        if not 0.5 <= self.distance_m[0] <= self.distance_m[1] <= 20:
            raise ValueError("distance_m must be an increasing pair within 0.5..20 m")
        if self.seed_error_deg < 0 or self.seed_error_m < 0 or self.range_noise_m < 0:
            raise ValueError("seed errors and range noise must be >= 0")
        Board(tuple(self.squares), self.square_m, tuple(self.size_m))  # checks the board

    @property
    def board(self) -> Board:
        return Board(tuple(self.squares), self.square_m, tuple(self.size_m))

    @property
    def size(self) -> tuple[int, int]:
        if self.width and self.height:
            return self.width, self.height
        return (1280, 720) if self.modality == "frame" else (346, 260)


def target_config_with(config: TargetConfig, **changes) -> TargetConfig:
    """A copy of ``config`` with ``changes`` (None values are ignored)."""
    return replace(config, **{k: v for k, v in changes.items() if v is not None})


def make_target_rig(config: TargetConfig) -> tuple[CameraModel, Extrinsic, Extrinsic]:
    """The camera, the true ``T_cam_lidar`` and the seed, all from ``config.seed``."""
    rng = np.random.default_rng(np.random.SeedSequence(config.seed, spawn_key=(2, 0)))
    w, h = config.size
    hfov = np.radians(70.0 if config.modality == "frame" else 53.0)
    f = (w / 2) / np.tan(hfov / 2) * rng.uniform(0.98, 1.02)
    K = np.array([[f, 0, (w - 1) / 2 + rng.uniform(-0.01, 0.01) * w],
                  [0, f * rng.uniform(0.998, 1.002), (h - 1) / 2 + rng.uniform(-0.01, 0.01) * h], [0, 0, 1]])
    if config.lens == "equidistant":
        D = np.array([0.02, -0.01, 0.004, -0.001]) * rng.uniform(0.8, 1.2)
    else:
        D = np.array([-0.32, 0.12, 6e-4, -3e-4, 0.0]) * rng.uniform(0.8, 1.2)
    camera = CameraModel(K, w, h, D, config.lens)
    # the lidar turned about its axis on the mount (real rigs are often not aligned), small tilts
    mount = Rotation.from_euler("zyx", [rng.uniform(-40, 40), rng.uniform(-3, 3), rng.uniform(-3, 3)], degrees=True)
    R = LIDAR_TO_CAMERA_AXES @ mount.as_matrix()
    offset = rng.normal(size=3)
    offset *= rng.uniform(*config.camera_offset_m) / np.linalg.norm(offset)  # camera centre, lidar frame
    truth = Extrinsic(Rotation.from_matrix(R).as_rotvec(), -R @ offset)
    seed = perturb(truth, config.seed_error_deg, config.seed_error_m, rng)
    return camera, truth, seed


def make_target_scene(config: TargetConfig, index: int, camera: CameraModel, truth: Extrinsic,
                      rays: np.ndarray | None = None):
    """Scene ``index``: ``(image, points, intensity, ring, on_board, scene)`` with the board
    fully in the image and crossed by at least 3 lidar rings."""
    rng = np.random.default_rng(np.random.SeedSequence(config.seed, spawn_key=(2, 1, index)))
    board = config.board
    rays = pixel_rays(camera) if rays is None else rays
    lidar = LidarModel(range_noise_m=config.range_noise_m, **LIDARS[config.lidar])
    for _ in range(200):
        pose = board_pose(rng, index, config.n_scenes, config.distance_m, camera)
        if not board_in_view(board, camera, pose):
            continue
        scene = make_board_scene(rng, board, pose, truth)
        points, intensity, ring, on_board = lidar_scan(scene, board, lidar, rng)
        rings_on_board = np.bincount(ring[on_board], minlength=len(lidar.elevations_deg))
        if np.count_nonzero(rings_on_board >= 8) >= 3:
            break
    else:  # pragma: no cover - the pose ranges always leave room
        raise ValueError(f"no board pose found in view of both sensors for scene {index}")
    image = render_view(config.modality, board, camera, rays, scene, truth, rng)
    return image, points, intensity, ring, on_board, scene


def write_pcd_with_ring(path: Path, points: np.ndarray, intensity: np.ndarray, ring: np.ndarray) -> None:
    """A binary PCD with float32 x y z intensity and uint16 ring (as Velodyne drivers write)."""
    n = int(points.shape[0])
    rec = np.zeros(n, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"), ("ring", "<u2")])
    rec["x"], rec["y"], rec["z"] = np.asarray(points, np.float32).T
    rec["intensity"], rec["ring"] = intensity, ring
    header = (f"# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z intensity ring\n"
              f"SIZE 4 4 4 4 2\nTYPE F F F F U\nCOUNT 1 1 1 1 1\nWIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\n"
              f"POINTS {n}\nDATA binary\n")
    atomic_write_bytes(path, header.encode("ascii") + rec.tobytes())


def write_target_dataset(out_dir: str | Path, config: TargetConfig = TargetConfig(),
                         on_scene: Callable[[int, int], None] | None = None, overwrite: bool = False) -> Path:
    """Write ``config.n_scenes`` board scenes and the rig, board and truth files into ``out_dir``
    (refuses a non-empty folder unless ``overwrite``; then old ``scene_*`` files go first)."""
    import cv2

    out = Path(out_dir)
    clear_out_dir(out, overwrite)
    map_dir = "image" if config.modality in IMAGE_MODALITIES else "event"
    for sub in (map_dir, "lidar"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    camera, truth, seed = make_target_rig(config)
    rays = pixel_rays(camera)
    boards = {}
    for i in range(config.n_scenes):
        image, points, intensity, ring, _, scene = make_target_scene(config, i, camera, truth, rays)
        stem = scene_stem(i)
        ok, png = cv2.imencode(".png", image)
        if not ok:
            raise InputError(out / map_dir / f"{stem}.png", "could not encode the PNG")
        atomic_write_bytes(out / map_dir / f"{stem}.png", png.tobytes())
        write_pcd_with_ring(out / "lidar" / f"{stem}.pcd", points, intensity, ring)
        boards[stem] = {"T_cam_board": scene.pose_cam.matrix.tolist(), "holder": scene.holder}
        if on_scene:
            on_scene(i + 1, config.n_scenes)
    _write_rig_files(out, camera, truth, seed, config, boards)
    return out


def _write_rig_files(out: Path, camera: CameraModel, truth: Extrinsic, seed: Extrinsic, config: TargetConfig,
                     boards: dict) -> None:
    def dump(name: str, header: str, doc: dict) -> None:
        atomic_write_bytes(out / name, (header + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None)).encode())

    dump("camera.yaml", "# Synthetic board rig written by `l2e-studio synth --target`; seed = truth perturbed.\n",
         {"camera": {"model": camera.model, "width": camera.width, "height": camera.height,
                     "K": camera.K.tolist(), "D": [float(x) for x in camera.D]},
          "seed": {"translation": seed.translation.tolist(), "rotvec": seed.rotvec.tolist()}})
    dump("target.yaml", "", config.board.to_yaml())
    err_deg, err_m = seed.error_to(truth)
    dump("truth.yaml", "# Ground truth T_cam_lidar (X_cam = R X_lidar + t) and each scene's board pose T_cam_board\n"
                       "# (board frame: origin at the outline's centre, x along the columns, y along the rows, z into "
                       "the board).\n",
         {"T_cam_lidar": truth.matrix.tolist(), "translation": truth.translation.tolist(),
          "rotvec": truth.rotvec.tolist(), "rpy_deg": truth.rpy(degrees=True).tolist(),
          "seed_error": {"rotation_deg": err_deg, "translation_m": err_m},
          "boards": boards, "generator": asdict(config)})


def read_board_poses(path: str | Path) -> dict[str, Extrinsic]:
    """Each scene's true T_cam_board from a ``truth.yaml`` written by :func:`write_target_dataset`."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
        return {stem: Extrinsic.from_matrix(np.asarray(b["T_cam_board"], float)) for stem, b in data["boards"].items()}
    except FileNotFoundError:
        raise InputError(path, "no truth file") from None
    except (yaml.YAMLError, KeyError, TypeError, ValueError, AttributeError) as exc:
        raise InputError(path, f"expected a board truth file with 'boards: {{stem: {{T_cam_board}}}}' ({exc})") from None

