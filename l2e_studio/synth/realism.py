"""The failure modes of real recordings, on demand (``l2e-studio synth --realism``).

The plain synthetic world is kind to a calibration: every lit pixel is a laser spot, and a
camera image would be brightest where the lidar says the surface is reflective. Real data is
not, and each of these traps has pulled a calibration away from the truth on real recordings:

Camera images (``map_kind="image"``), rendered by casting a ray per pixel into the same world:

* ``shading``: a light from one side and a vignette, so brightness ramps across surfaces whose
  reflectivity is flat (a smooth fall-off the MI can line up with intensity fall-off);
* ``sky``: far surfaces and the ceiling overexposed to 255 (far, dark lidar points lifted onto a
  saturated sky doubled the MI on real street scenes);
* ``texture``: a per-surface brightness pattern unrelated to the lidar's reflectivity;
* ``vegetation``: patches of high-frequency foliage-like texture;
* ``footprint``: the lidar's beam is ``BEAM_DIVERGENCE_MRAD`` wide, not a thin ray: it returns the
  nearest surface anywhere across it, placed on its axis, so an object's edge points lie at its
  boundary or beyond (foreground inflation). With thin rays they lie inside it, up to a step of
  the scan: an edge score that corrects for that fits thin rays and fails real lidars (stop 41).

Event maps (``map_kind="events"``):

* ``falloff``: spot brightness falls faster with range than the (range-compensated) intensity;
* ``flicker``: lit lamps that flicker and fire events with no laser behind them;
* ``blooming``: bright spots bleed into their neighbours;
* ``hot_pixels``: many more hot pixels;
* ``hood``: a band of the image the lidar sees but the camera does not (an occluding hood).
"""

from __future__ import annotations

import cv2
import numpy as np

from ..camera import CameraModel
from ..geometry import Extrinsic
from .world import Box, Hits, cast, surface

TRAPS = {
    "image": ("shading", "sky", "texture", "vegetation", "footprint"),
    "events": ("falloff", "flicker", "blooming", "hot_pixels", "hood"),
}
SKY_RANGE_M = 22.0  # surfaces farther than this are overexposed by the ``sky`` trap
#: The ``footprint`` trap's beam width across the scan (full angle): spinning lidars' data
#: sheets give 2-3 mrad horizontally (Velodyne VLP-16 3.0, Ouster OS1 ~3.1).
BEAM_DIVERGENCE_MRAD = 3.0


def sky_mask(ranges: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Where the ``sky`` trap puts its sky: surfaces farther than ``SKY_RANGE_M``, and the
    ceiling (normals facing down in the world, z up)."""
    return (ranges > SKY_RANGE_M) | (normals[:, 2] < -0.7)


def camera_rays(camera: CameraModel) -> np.ndarray:
    """(H*W, 3) unit ray directions (camera frame) through every pixel centre, lens distortion undone."""
    v, u = np.mgrid[0 : camera.height, 0 : camera.width].astype(np.float64)
    pix = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
    if camera.is_distorted:
        xy = cv2.undistortPoints(pix, camera.K, camera.D[:5] if camera.model == "radtan" else camera.D).reshape(-1, 2)
    else:
        xy = (pix.reshape(-1, 2) - camera.K[:2, 2]) / np.diag(camera.K)[:2]
    rays = np.column_stack([xy, np.ones(len(xy))])
    return rays / np.linalg.norm(rays, axis=1, keepdims=True)


def camera_image(
    camera: CameraModel,
    truth: Extrinsic,
    lidar_R: np.ndarray,
    lidar_pos: np.ndarray,
    boxes: list,
    traps: tuple[str, ...],
    rng: np.random.Generator,
) -> np.ndarray:
    """A grey (H, W) uint8 camera image of the world seen through ``truth``, with ``traps``."""
    w, h = camera.width, camera.height
    cam_in_lidar = truth.inverse()
    origin = lidar_R @ cam_in_lidar.translation + lidar_pos
    dirs = camera_rays(camera) @ (lidar_R @ cam_in_lidar.R).T
    hits = cast(boxes, origin, dirs)
    surf = surface(boxes, origin, dirs, hits)
    hit = hits.index >= 0
    rho = np.clip(np.minimum(surf.rho, 1.0) * 0.8 + 0.1, 0.0, 1.0)  # the camera sees reflectance, mostly
    light = 0.35 + 0.65 * np.abs(np.einsum("ij,ij->i", surf.normals, dirs))  # a headlamp at the camera
    if "shading" in traps:
        sun = rng.normal(size=3)
        sun /= np.linalg.norm(sun)
        light = 0.15 + 0.85 * np.clip(surf.normals @ sun, 0.0, 1.0) ** 0.7
        ramp = np.linspace(rng.uniform(0.4, 0.7), 1.0, w)[None, :].repeat(h, axis=0).ravel()
        light = light * (ramp if rng.random() < 0.5 else ramp[::-1])
    if "texture" in traps:
        # brightness patterns that the lidar's reflectivity does not share
        pattern = cv2.resize(rng.uniform(0.05, 1.0, (max(2, h // 40), max(2, w // 40))).astype(np.float32), (w, h),
                             interpolation=cv2.INTER_CUBIC).ravel()
        rho = 0.25 * rho + 0.75 * np.clip(pattern, 0.0, 1.0)
    grey = 255.0 * rho * light
    if "vegetation" in traps:
        foliage = np.zeros((h, w), np.float32)
        for _ in range(rng.integers(2, 5)):
            cx, cy = rng.integers(0, w), rng.integers(0, h // 2)
            rx, ry = rng.integers(w // 12, w // 5), rng.integers(h // 10, h // 4)
            cv2.ellipse(foliage, (int(cx), int(cy)), (int(rx), int(ry)), 0.0, 0.0, 360.0, 1.0, -1)
        leaves = cv2.GaussianBlur(rng.uniform(0, 255, (h, w)).astype(np.float32), (0, 0), 1.2)
        mask = foliage.ravel() > 0
        grey[mask] = 0.5 * grey[mask] + 0.5 * leaves.ravel()[mask]
    if "sky" in traps:
        grey[~hit | sky_mask(hits.t, surf.normals)] = 255.0
    grey[~hit] = 255.0 if "sky" in traps else 20.0
    grey = grey + rng.normal(0, 3.0, grey.size)
    return np.clip(grey, 0, 255).astype(np.uint8).reshape(h, w)


def event_traps(lam: np.ndarray, shape: tuple[int, int], traps: tuple[str, ...],
                rng: np.random.Generator) -> np.ndarray:
    """Apply the event-map traps to a (H*W,) event-rate map ``lam``; returns the new rates."""
    h, w = shape
    lam = lam.reshape(h, w).astype(np.float64)
    if "blooming" in traps:
        strong = np.where(lam > np.percentile(lam, 99.5), lam, 0.0)
        lam = lam + 0.4 * cv2.GaussianBlur(strong, (0, 0), max(2.0, w / 320))
    if "flicker" in traps:
        for _ in range(rng.integers(2, 5)):
            cx, cy = rng.integers(0, w), rng.integers(0, h // 2)
            r = int(rng.integers(max(3, w // 80), max(4, w // 25)))
            lamp = np.zeros((h, w), np.float32)
            cv2.circle(lamp, (int(cx), int(cy)), r, float(rng.uniform(20, 80)), -1)
            lam = lam + cv2.GaussianBlur(lamp, (0, 0), r / 2)
    if "hood" in traps:
        lam[int(h * 0.88) :] = 0.0
    return lam.ravel()


def first_returns(boxes: list[Box], origin: np.ndarray, dirs_l: np.ndarray, lidar_R: np.ndarray, t_max: float,
                  divergence_mrad: float = BEAM_DIVERGENCE_MRAD) -> tuple[Hits, np.ndarray]:
    """The ``footprint`` trap: each beam (unit directions ``dirs_l``, lidar frame) as three rays
    across its width in azimuth (about the lidar's z axis), the nearest hit of the three. Returns
    the hits and, per beam, the world direction of the ray that made it (its surface's normal and
    reflectivity are that ray's; its point lies on the beam's axis at that range)."""

    def across(a: float) -> np.ndarray:  # the beam's rays turned ``a`` rad about the lidar's z, in the world
        c, s = np.cos(a), np.sin(a)
        return (dirs_l @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T) @ lidar_R.T

    best_dirs = across(0.0)
    best = cast(boxes, origin, best_dirs, t_max)
    for a in (-0.5e-3 * divergence_mrad, 0.5e-3 * divergence_mrad):
        dirs_w = across(a)
        hits = cast(boxes, origin, dirs_w, t_max)
        nearer = (hits.index >= 0) & ((best.index < 0) | (hits.t < best.t))
        best.t[nearer], best.index[nearer], best_dirs[nearer] = hits.t[nearer], hits.index[nearer], dirs_w[nearer]
    return best, best_dirs
