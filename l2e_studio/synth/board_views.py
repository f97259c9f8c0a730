"""What each kind of camera makes of a board scene (``l2e-studio synth --target ... --modality``).

* ``frame``: a frame camera's grey image: the anti-aliased board over the room, uneven light,
  a slight defocus, vignetting, shot and read noise, 8 bits;
* ``e2vid``: an image reconstructed from events as E2VID gives them: low resolution (the
  DAVIS346's 346 x 260), strong blur, low contrast, blotchy low-frequency artefacts and noise;
* ``events``: the accumulated event map of a flashing board (a backlit board whose light
  toggles ``flashes`` times): a pixel fires an event each time its log intensity changes by the
  contrast threshold (per-pixel thresholds, noise events, hot pixels); the unlit black squares
  and the static room fire only noise;
* ``events-moving``: the accumulated event map of a board shaken about its true pose (1.5 cm,
  1.5 deg): events at the pattern's and the outline's edges.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from ..camera import CameraModel
from ..geometry import Extrinsic
from .board import Board, render_board
from .board_world import BoardScene, background_radiance

MODALITIES = ("frame", "e2vid", "events", "events-moving")
IMAGE_MODALITIES = ("frame", "e2vid")  # written under image/; the others under event/


def render_view(modality: str, board: Board, camera: CameraModel, rays: np.ndarray, scene: BoardScene,
                truth: Extrinsic, rng: np.random.Generator) -> np.ndarray:
    """The (H, W) uint8 image or event map of ``scene`` for ``modality``."""
    if modality not in MODALITIES:
        raise ValueError(f"modality must be one of {', '.join(MODALITIES)}")
    h, w = camera.height, camera.width
    background = background_radiance(scene, camera, rays, truth)
    shading = _shading(rng, h, w)
    if modality == "events":
        return _flash_events(board, camera, rays, scene.pose_cam, background, shading, rng)
    if modality == "events-moving":
        return _motion_events(board, camera, rays, scene.pose_cam, background, shading, rng)
    image, _ = render_board(board, camera, rays, scene.pose_cam, background, shading=shading)
    if modality == "frame":
        image = cv2.GaussianBlur(image, (0, 0), rng.uniform(0.4, 0.8))
        image *= _vignette(h, w, 0.25) * rng.uniform(0.8, 1.05)
        electrons = rng.poisson(np.clip(image, 0, None) * 400.0) / 400.0  # shot noise
        image = electrons + rng.normal(0, 0.006, image.shape)
        return _to_uint8(image)
    image = cv2.GaussianBlur(image, (0, 0), rng.uniform(1.0, 1.6))
    blotches = cv2.resize(rng.normal(0, 1, (max(2, h // 24), max(2, w // 24))), (w, h), interpolation=cv2.INTER_CUBIC)
    image = 0.45 + 0.45 * (image - 0.45) + 0.05 * blotches  # low contrast, blotchy
    image = image + rng.normal(0, 0.03, image.shape)
    return _to_uint8(image)


def _shading(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """A smooth light ramp in a random direction (0.7..1.1)."""
    a = rng.uniform(0, 2 * np.pi)
    v, u = np.mgrid[0:h, 0:w]
    ramp = (np.cos(a) * (u / w - 0.5) + np.sin(a) * (v / h - 0.5))
    return 0.9 + 0.4 * ramp


def _vignette(h: int, w: int, strength: float) -> np.ndarray:
    v, u = np.mgrid[0:h, 0:w]
    r2 = ((u - w / 2) / (w / 2)) ** 2 + ((v - h / 2) / (h / 2)) ** 2
    return 1.0 - strength * r2 / 2


def _to_uint8(image: np.ndarray) -> np.ndarray:
    return np.clip(np.round(255.0 * image), 0, 255).astype(np.uint8)


def _accumulate(log_frames: list[np.ndarray], rng: np.random.Generator, cycles: int = 1) -> np.ndarray:
    """Event counts of a pixel array watching ``log_frames`` in turn (``cycles`` times), with
    per-pixel contrast thresholds, noise events and hot pixels; an 8-bit map."""
    h, w = log_frames[0].shape
    threshold = np.clip(rng.normal(0.22, 0.03, (h, w)), 0.1, None)
    counts = np.zeros((h, w))
    for a, b in zip(log_frames, log_frames[1:] + log_frames[:1]):
        counts += np.floor(np.abs(b - a) / threshold)
    counts *= cycles
    counts += rng.poisson(1.0, (h, w))
    hot = rng.choice(h * w, size=max(1, h * w // 2000), replace=False)
    counts.ravel()[hot] += rng.integers(50, 255, hot.size)
    return np.clip(counts, 0, 255).astype(np.uint8)


def _flash_events(board, camera, rays, pose, background, shading, rng) -> np.ndarray:
    lit, _ = render_board(board, camera, rays, pose, background, shading=shading)
    dark, _ = render_board(board, camera, rays, pose, background, white=0.05, shading=shading)
    eps = 0.02
    frames = [np.log(cv2.GaussianBlur(f, (0, 0), 0.7) + eps) for f in (dark, lit)]
    return _accumulate(frames, rng, cycles=int(rng.integers(4, 8)))


def _motion_events(board, camera, rays, pose, background, shading, rng) -> np.ndarray:
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    step = rng.normal(size=3)
    step /= np.linalg.norm(step)
    frames = []
    for phase in np.linspace(0, 2 * np.pi, 9)[:-1]:  # one oscillation about the true pose
        s = np.sin(phase)
        moved = Extrinsic((Rotation.from_rotvec(axis * np.radians(1.5) * s) * Rotation.from_rotvec(pose.rotvec)).as_rotvec(),
                          pose.translation + step * 0.015 * s)
        image, _ = render_board(board, camera, rays, moved, background, shading=shading)
        frames.append(np.log(cv2.GaussianBlur(image, (0, 0), 0.7) + 0.02))
    return _accumulate(frames, rng, cycles=int(rng.integers(4, 8)))
