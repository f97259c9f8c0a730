"""A small synthetic camera scene with structure: boxes in front of a wall, the image a rendering
of the boxes' edges (the edge objective's and the translation probes' tests share it)."""

from __future__ import annotations

import cv2
import numpy as np

from l2e_studio.camera import CameraModel
from l2e_studio.geometry import Extrinsic
from l2e_studio.scenes import Scene


#: (unused, y centre, half size, depth) of each box: a face at x = depth spanning y in cy +- half, z in +-half
BOXES = ((0.0, 2.0, 1.0, 6.0), (0.0, -2.5, 0.8, 8.0), (0.0, 0.5, 0.5, 4.0))


def box_world(rng: np.random.Generator, boxes: tuple = BOXES, wall: float = 12.0) -> tuple[Scene, CameraModel, Extrinsic]:
    """Boxes in front of a wall (``wall`` m away), seen by a camera whose image is a rendering of
    the boxes' edges."""
    cam = CameraModel(np.array([[400.0, 0, 320], [0, 400.0, 240], [0, 0, 1]]), 640, 480)
    truth = Extrinsic.from_matrix(np.array([[0, -1, 0, 0.05], [0, 0, -1, -0.1], [1, 0, 0, 0.02], [0, 0, 0, 1.0]]))
    pts, inten = [], []
    az = np.radians(np.arange(-40, 40, 0.15))
    for el in np.radians(np.arange(-25, 25, 0.8)):
        for a in az:
            d = np.array([np.cos(el) * np.cos(a), np.cos(el) * np.sin(a), np.sin(el)])
            r = wall
            for cx, cy, half, depth in boxes:
                t = depth / max(d[0], 1e-6)
                y, z = t * d[1], t * d[2]
                if abs(y - cy) < half and abs(z) < half and t < r:
                    r = t
            pts.append(r * d)
            inten.append(200.0 if r < wall else 40.0)
    P = np.array(pts, dtype=np.float32)
    inten = np.array(inten, dtype=np.float32) + rng.normal(0, 3, len(P)).astype(np.float32)
    # the image: mid-grey wall, bright boxes, textured noise; plus a saturated "sky" band
    uv = cam.K @ truth.transform(P).T
    uv = (uv[:2] / uv[2]).T
    img = np.full((480, 640), 90.0, np.float32)
    near = inten > 120
    for (u, v) in uv[near].astype(int):
        if 0 <= u < 640 and 0 <= v < 480:
            cv2.circle(img, (u, v), 3, 170.0, -1)
    img += rng.normal(0, 4, img.shape).astype(np.float32)
    img[:40] = 255.0
    return Scene("boxes", P, np.clip(inten, 0, 255), np.clip(img, 0, 255), "image"), cam, truth
