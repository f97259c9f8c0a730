"""The maps the scores read, prepared from the scenes' raw maps.

* For the paper's MI (accumulated event maps): clipped at the kind's ceiling and smoothed.
* For the edge score (camera images): the image gradient, smoothed and band-passed
  (:func:`l2e_studio.scoring.edges.edge_map`); every orientation, or only across the lidar's
  scan lines. Which way the scan lines run in the image is the seed's business, not the
  image's: :func:`scan_directions` projects the lidar's rings through the seed extrinsic and
  the lens, so a camera mounted on its side, a tilted lidar or a fisheye (where the rings
  curve) read the gradient that crosses the rings where they really run.

Every stacked map has a one-pixel border that reads "nothing" (zero counts for MI, "no edge"
for edges), so a point that leaves the image cannot raise the score.
"""

from __future__ import annotations

from typing import Sequence

import cv2
import numpy as np
from scipy.ndimage import distance_transform_edt

from .camera import CameraModel
from .geometry import Extrinsic, project_with_jacobian, undistort_normalised
from .io.maps import MAP_CLIP
from .scoring import edges
from .pool import run_tasks

#: Maps of accumulated events are clipped here (the paper); camera images keep their 0..255.
CLIP = MAP_CLIP
#: Pixels between the rays at which the scan direction is computed (it is smooth; the rest is interpolated).
SCAN_GRID = 16
#: A lens whose two stretches at a pixel differ more than this (smaller over larger) has no
#: trustworthy direction there: the squeeze of a distortion polynomial past its fitted range.
#: An equidistant fisheye passes out to about 73 deg off its axis.
MIN_LENS_CONDITION = 0.2


def prepare_map(event_map: np.ndarray, sigma: float = 5.0, clip: float = 127.0) -> np.ndarray:
    """Clip an accumulated event map to [0, clip] and Gaussian-smooth it (sigma in pixels)."""
    m = np.clip(np.asarray(event_map, dtype=np.float32), 0.0, clip)
    if sigma > 0:
        m = cv2.GaussianBlur(m, (0, 0), sigmaX=sigma, sigmaY=sigma, borderType=cv2.BORDER_REFLECT)
    return m


def scan_directions(camera: CameraModel, extrinsic: Extrinsic, grid: int = SCAN_GRID) -> np.ndarray:
    """(H, W, 2) float32: at every pixel, the unit image direction in which the lidar's scan line
    through that pixel runs, for the lidar placed by ``extrinsic`` (lidar to camera).

    A spinning lidar's rings are cones about its z axis, and the edge weights compare neighbours
    in azimuth about that axis; at a pixel whose ray is ``r`` (camera frame) the ring runs along
    ``a x r`` (``a`` the lidar's z axis in the camera frame), which the lens's Jacobian carries
    into the image. Rays come from the lens model's own inverse (:func:`undistort_normalised`,
    the one the board solve uses) on a grid every ``grid`` pixels, and the field is
    interpolated between them. Where the ray runs along the lidar's axis (no ring passes) the
    direction is zero: no edge can be matched there.
    """
    W, H = camera.width, camera.height
    us = np.unique(np.r_[np.arange(0, W, grid), W - 1]).astype(np.float64)
    vs = np.unique(np.r_[np.arange(0, H, grid), H - 1]).astype(np.float64)
    uu, vv = np.meshgrid(us, vs)
    px = np.stack([uu.ravel(), vv.ravel()], axis=1)
    rays = np.column_stack([undistort_normalised(px, camera), np.ones(len(px))])
    axis = extrinsic.R[:, 2]
    uv, _, J = project_with_jacobian(rays, camera)
    d = np.einsum("nij,nj->ni", J, np.cross(axis, rays))
    length = np.linalg.norm(d, axis=1)
    # a ray is good when it projects back onto its pixel through a lens that still maps well
    # there: toward the radius where a strong lens's polynomial turns back (beyond the range it
    # was fitted on), undistortion finds no ray or the lens squeezes one direction to nothing
    # and the ring's direction with it; those pixels take the nearest good direction
    finite = np.isfinite(J).all(axis=(1, 2))  # (a ray past the lens's fold projects nowhere: nan)
    sv = np.zeros((len(J), 2))
    sv[finite] = np.linalg.svd(J[finite, :, :2] / np.diag(camera.K)[None, :2, None], compute_uv=False)
    good = (finite & np.isfinite(length) & (np.linalg.norm(uv - px, axis=1) < 0.5)
            & (sv[:, 1] > MIN_LENS_CONDITION * sv[:, 0]))
    ok = good & (length > 1e-9 * np.max(length[good], initial=1.0))
    d = np.where(ok[:, None], d / np.where(ok, length, 1.0)[:, None], 0.0).reshape(len(vs), len(us), 2)
    if not good.all() and good.any():
        _, (iv, iu) = distance_transform_edt(~good.reshape(d.shape[:2]), return_indices=True)
        d = d[iv, iu]
    wv, wu = _hat_weights(vs, H), _hat_weights(us, W)  # bilinear, as two small matrix products
    field = np.stack([wv @ d[..., c] @ wu.T for c in range(2)], axis=2)
    length = np.linalg.norm(field, axis=2, keepdims=True)
    return np.where(length > 1e-6, field / np.maximum(length, 1e-6), 0.0).astype(np.float32)


def rows(camera: CameraModel) -> np.ndarray:
    """The scan-line field of a lidar whose rings run along the image rows (no seed to project):
    one direction, broadcast (read-only, no memory per pixel)."""
    return np.broadcast_to(np.array([1.0, 0.0], np.float32), (camera.height, camera.width, 2))


def _hat_weights(knots: np.ndarray, n: int) -> np.ndarray:
    """(n, k) weights of linear interpolation from values at ``knots`` to the points 0..n-1."""
    return np.stack([np.interp(np.arange(n), knots, row) for row in np.eye(len(knots))], axis=1)


def stack_maps(
    raw: Sequence[np.ndarray],
    kinds: Sequence[str],
    sigma: float,
    size: tuple[int, int] | None = None,
    objective: str = "mi",
    scan: np.ndarray | None = None,
) -> np.ndarray:
    """(S, h+2, w+2) float32: ``raw`` maps prepared for ``objective``, resized to ``size`` (w, h)
    before smoothing (``sigma`` in full-resolution pixels), with a one-pixel border that reads
    "nothing". ``scan``: the full-resolution scan direction field, for edge maps that read the
    gradient across the scan lines only."""
    h, w = raw[0].shape
    out_w, out_h = size or (w, h)
    factor = out_w / w
    if objective == "edges":
        out = np.full((len(raw), out_h + 2, out_w + 2), edges.OFFSET, dtype=np.float32)

        def prepare(i: int) -> None:
            out[i, 1:-1, 1:-1] = edges.edge_map(raw[i], sigma * factor, (out_w, out_h), scan)
    else:
        out = np.zeros((len(raw), out_h + 2, out_w + 2), dtype=np.float32)

        def prepare(i: int) -> None:
            m = np.clip(raw[i], 0.0, CLIP[kinds[i]])
            if (out_w, out_h) != (w, h):
                m = cv2.resize(m, (out_w, out_h), interpolation=cv2.INTER_AREA)
            out[i, 1:-1, 1:-1] = prepare_map(m, sigma * factor, CLIP[kinds[i]])
    run_tasks(prepare, range(len(raw)))  # OpenCV releases the GIL: one map per core
    return out
