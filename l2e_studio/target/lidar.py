"""The board in a lidar scan: its points, its plane and its edge points.

Two ways, used in turn by :func:`l2e_studio.target.calibrate_target`:

* :func:`search_board` -- from a seed that may be 5 deg / 20 cm off: the camera's board pose,
  carried into the lidar frame through the seed, says roughly where the board is. Within a
  generous sphere around that spot, planes are found by RANSAC one after the other (the wall and
  the floor usually first); each plane's inliers are split into connected patches, and the patch
  whose extent and area match the board (not the wall's, not a leg's) and whose normal and centre
  are nearest the prediction is the board.
* :func:`crop_board` -- from an extrinsic already close (the first solve): the points within the
  board's outline (plus a margin) and near its plane, as the camera sees it. The person holding
  the board, its stand and the wall behind fall outside the outline or the plane.

Edge points are where each ring enters and leaves the board (the first and last point of the
ring on the board by azimuth). Rings come from the scan's ``ring`` field when it has one, else
from the board points' elevation angles (split where consecutive elevations jump); a board whose
points form no rings at all (a solid-state lidar's non-repetitive pattern) gets the points along
the convex hull of its points instead (:func:`outline_points`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..geometry import Extrinsic
from .board import Board
from .detect import Detection

#: inlier distance to a plane (m), plus this share of the range (VLP-16 noise grows with range)
PLANE_TOL_M, PLANE_TOL_PER_M = 0.03, 0.005
#: a board is at least this many points, on at least this many rings
MIN_POINTS, MIN_RINGS = 20, 2
#: elevation gap (deg) that separates two rings when the scan has no ring field: the rings are
#: told apart on the board's points alone, where a ring's points share one elevation to a few
#: thousandths of a degree (one range, one beam origin) and rings are 0.1-2 deg apart (an OS1-128
#: 0.35, an HDL-64E's upper block 0.33: a gap of 0.4 over the whole scan merged them into one)
RING_GAP_DEG = 0.08
#: the widest elevation band one ring's points on a board may span (deg)
RING_WIDTH_DEG = 0.3


@dataclass(frozen=True)
class LidarBoard:
    """The board in one scan (lidar frame). ``found`` False: ``reason`` says why.

    ``indices`` index the scan's points; ``normal``/``offset``: the fitted plane ``n . p = d``
    (n towards the sensor); ``edges``: (M, 3) edge points; ``rms_m``: RMS distance of the
    board points to their plane; ``azimuth_step_rad``: the rings' median azimuth step on the board."""

    found: bool
    reason: str = ""
    indices: np.ndarray | None = None
    points: np.ndarray | None = None
    normal: np.ndarray | None = None
    offset: float = float("nan")
    edges: np.ndarray | None = None
    rms_m: float = float("nan")
    azimuth_step_rad: float = float("nan")

    @property
    def n_points(self) -> int:
        return 0 if self.points is None else int(len(self.points))


def ring_ids(points: np.ndarray, rings: np.ndarray | None = None) -> np.ndarray:
    """A ring number per point: the scan's own ``rings`` when given, else elevation clusters
    (meant for the points of one board: see ``RING_GAP_DEG``)."""
    if rings is not None and len(rings) == len(points):
        return np.asarray(rings).astype(np.int64)
    p = np.asarray(points, dtype=np.float64)
    elev = np.degrees(np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1])))
    order = np.argsort(elev)
    jumps = np.concatenate([[0], (np.diff(elev[order]) > RING_GAP_DEG).astype(np.int64)])
    out = np.empty(len(p), dtype=np.int64)
    out[order] = np.cumsum(jumps)
    return out


def fit_plane(points: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Least-squares plane ``(n, d, rms)`` with ``n . p = d``, n pointing to the origin (the sensor)."""
    p = np.asarray(points, dtype=np.float64)
    c = p.mean(axis=0)
    _, _, vt = np.linalg.svd(p - c, full_matrices=False)
    n = vt[2]
    if n @ c > 0:
        n = -n
    d = float(n @ c)
    return n, d, float(np.sqrt(np.mean((p @ n - d) ** 2)))


def edge_points(points: np.ndarray, rings: np.ndarray) -> tuple[np.ndarray, float]:
    """``(edges, step)``: (M, 3) the first and last point by azimuth of every ring with 3 or more
    points on the board (azimuth taken about the points' mean direction, so a board behind the
    sensor does not wrap), and the rings' median azimuth step there (rad; NaN without edges):
    a ring leaves the board somewhere between its last hit and its first miss, so an edge point
    is known to a step along its ring. The points are not moved out by half a step: a zero-width
    beam's last hit sits half a step inside the outline on average, but a real beam (3 mrad for
    a VLP-16, about the step) already returns from the board's rim before its centre reaches it;
    measured, moving them out made the real sets agree worse (rles01 frame vs event 0.36 ->
    0.39 deg, rlfs01 against LCE-Calib's estimate 0.16 -> 0.18 deg)."""
    c = points.mean(axis=0)
    az = np.angle(np.exp(1j * (np.arctan2(points[:, 1], points[:, 0]) - np.arctan2(c[1], c[0]))))
    out, steps = [], []
    for r in np.unique(rings):
        m = np.flatnonzero(rings == r)
        if len(m) < 3:
            continue
        idx = m[np.argsort(az[m])]
        steps.append(float(np.median(np.diff(az[idx]))))
        out.extend([points[idx[0]], points[idx[-1]]])
    return np.asarray(out, dtype=np.float64).reshape(-1, 3), float(np.median(steps)) if steps else float("nan")


def _ring_like(points: np.ndarray, ring: np.ndarray) -> bool:
    """Whether elevation clusters ``ring`` of a board's points are rings: at least
    ``MIN_RINGS`` of them, each a thin band of elevation (a spinning lidar's beam), not a
    scatter over the board split only where its sparse tips leave gaps."""
    ids = np.unique(ring)
    if len(ids) < MIN_RINGS:
        return False
    elev = np.degrees(np.arctan2(points[:, 2], np.hypot(points[:, 0], points[:, 1])))
    return all(np.ptp(elev[ring == r]) <= RING_WIDTH_DEG for r in ids)


def outline_points(points: np.ndarray, normal: np.ndarray) -> tuple[np.ndarray, float]:
    """``(edges, step)`` of a board seen without rings (a solid-state lidar's non-repetitive
    pattern, or a cloud whose rings cannot be told apart): the points within one point spacing
    of the convex hull of the points in their plane (the board is convex, and a dense pattern
    fills it to within a spacing of its outline), and that spacing as an angle at the board's
    range (rad), the edge points' uncertainty along the outline."""
    from scipy.spatial import cKDTree

    xy = _in_plane(points, normal)
    spacing = float(np.median(cKDTree(xy).query(xy, k=2)[0][:, 1]))
    hull = cv2.convexHull(xy)
    inside = np.array([cv2.pointPolygonTest(hull, (float(a), float(b)), True) for a, b in xy])
    edges = points[inside <= spacing]
    return edges, spacing / max(float(np.linalg.norm(points.mean(axis=0))), 1e-6)


def _finish(points: np.ndarray, rings: np.ndarray | None, idx: np.ndarray, what: str) -> LidarBoard:
    """A :class:`LidarBoard` from the chosen indices (``rings``: the scan's ring field, or None to
    tell them from the board points' elevations), or the reason they do not make one."""
    if len(idx) < MIN_POINTS:
        return LidarBoard(False, f"{what}: {len(idx)} points on the board (at least {MIN_POINTS})")
    pts = np.asarray(points[idx], dtype=np.float64)
    ring = ring_ids(pts, None if rings is None else np.asarray(rings)[idx])
    ringless = rings is None and not _ring_like(pts, ring)  # a scan pattern without rings (solid state)
    if len(np.unique(ring)) < MIN_RINGS and not ringless:
        return LidarBoard(False, f"{what}: the board points lie on {len(np.unique(ring))} ring(s) (at least {MIN_RINGS})")
    n, d, rms = fit_plane(pts)
    edges, step = outline_points(pts, n) if ringless else edge_points(pts, ring)
    return LidarBoard(True, "", idx, pts, n, d, edges, rms, step)


def predicted(detection: Detection, extrinsic: Extrinsic) -> tuple[np.ndarray, np.ndarray]:
    """The board's centre and normal in the lidar frame where ``extrinsic`` puts the camera's board."""
    inv = extrinsic.inverse()
    centre = inv.transform(detection.pose.translation[None])[0].astype(np.float64)
    return centre, inv.R @ detection.normal


def search_board(points: np.ndarray, rings: np.ndarray | None, detection: Detection, board: Board,
                 seed: Extrinsic, seed_deg: float = 6.0, seed_m: float = 0.25, rng_seed: int = 0) -> LidarBoard:
    """The board found around where ``seed`` puts the camera's board (seed off by up to
    ``seed_deg`` / ``seed_m``): RANSAC planes, connected patches, the one of the board's size."""
    if not detection.found:
        return LidarBoard(False, "no board in the image")
    p = np.asarray(points, dtype=np.float64)
    ring = rings if rings is not None and len(rings) == len(p) else None
    centre, n_pred = predicted(detection, seed)
    dist = float(np.linalg.norm(centre))
    radius = 0.5 * board.diagonal_m + seed_m + dist * np.tan(np.radians(seed_deg)) + 0.1
    region = np.flatnonzero(np.linalg.norm(p - centre, axis=1) <= radius)
    if len(region) < MIN_POINTS:
        return LidarBoard(False, f"{len(region)} lidar points within {radius:.2f} m of where the seed puts the board")
    tol = PLANE_TOL_M + PLANE_TOL_PER_M * dist
    rng = np.random.default_rng(rng_seed)
    left = region.copy()
    best, best_score, seen = None, np.inf, []
    area = board.size_m[0] * board.size_m[1]
    for _ in range(8):  # planes, largest first
        if len(left) < MIN_POINTS:
            break
        inl = _ransac_plane(p[left], tol, rng)
        if inl is None:
            break
        plane_idx = left[inl]
        left = left[~inl]
        for patch in _patches(p[plane_idx], link=0.1 + 0.05 * dist):
            idx = plane_idx[patch]
            if len(idx) < MIN_POINTS:
                continue
            n, d, _ = fit_plane(p[idx])
            length, width, hull = _extent(p[idx], n)
            seen.append(f"{len(idx)} points {length:.2f} x {width:.2f} m")
            if length > board.diagonal_m + 0.1 or hull < 0.25 * area or hull > 1.3 * area:
                continue
            angle = np.degrees(np.arccos(np.clip(abs(n @ n_pred), 0, 1)))
            if angle > 3 * seed_deg:
                continue
            off = float(np.linalg.norm(p[idx].mean(axis=0) - centre))
            score = abs(hull / area - 0.8) + angle / (3 * seed_deg) + off / radius
            if score < best_score:
                best, best_score = idx, score
    if best is None:
        return LidarBoard(False, f"no planar patch of the board's size near where the seed puts it "
                                 f"(patches seen: {'; '.join(seen[:4]) or 'none'})")
    # the patch's own plane, refitted: keep its points within the tolerance
    n, d, _ = fit_plane(p[best])
    best = best[np.abs(p[best] @ n - d) <= tol]
    return _finish(p, ring, best, "searched around the seed")


def crop_board(points: np.ndarray, rings: np.ndarray | None, detection: Detection, board: Board,
               extrinsic: Extrinsic, margin_m: float = 0.05) -> LidarBoard:
    """The points inside the board's outline (+ ``margin_m``) and near its plane where
    ``extrinsic`` (already close) carries the camera's board into the scan."""
    if not detection.found:
        return LidarBoard(False, "no board in the image")
    p = np.asarray(points, dtype=np.float64)
    ring = rings if rings is not None and len(rings) == len(p) else None
    centre, _ = predicted(detection, extrinsic)
    near = np.flatnonzero(np.sum((p - centre) ** 2, axis=1) <= (0.5 * board.diagonal_m + 2 * margin_m) ** 2)
    to_board = detection.pose.inverse().compose(extrinsic)  # lidar -> board frame
    q = to_board.transform(p[near])
    dist = float(np.linalg.norm(detection.pose.translation))
    tol = PLANE_TOL_M + PLANE_TOL_PER_M * dist + margin_m
    w, h = board.size_m[0] / 2.0 + margin_m, board.size_m[1] / 2.0 + margin_m
    idx = near[(np.abs(q[:, 0]) <= w) & (np.abs(q[:, 1]) <= h) & (np.abs(q[:, 2]) <= tol)]
    if len(idx) < MIN_POINTS:
        return _finish(p, ring, idx, "inside the board's outline")
    # the board's own plane among them (a hand or the stand may be near it): RANSAC, then refit
    inl = _ransac_plane(p[idx], PLANE_TOL_M + PLANE_TOL_PER_M * dist, np.random.default_rng(0), iterations=100)
    if inl is not None:
        idx = idx[inl]
    return _finish(p, ring, idx, "inside the board's outline")


def _ransac_plane(p: np.ndarray, tol: float, rng: np.random.Generator, iterations: int = 300) -> np.ndarray | None:
    """Inlier mask of the plane with the most points within ``tol`` (vectorised RANSAC), refitted once."""
    n_pts = len(p)
    if n_pts < 3:
        return None
    tri = rng.integers(0, n_pts, size=(iterations, 3))
    a, b, c = p[tri[:, 0]], p[tri[:, 1]], p[tri[:, 2]]
    normals = np.cross(b - a, c - a)
    norm = np.linalg.norm(normals, axis=1)
    ok = norm > 1e-9
    if not ok.any():
        return None
    normals, a = normals[ok] / norm[ok, None], a[ok]
    d = np.einsum("ij,ij->i", normals, a)
    sample = p if n_pts <= 1500 else p[rng.choice(n_pts, 1500, replace=False)]
    counts = (np.abs(sample @ normals.T - d) <= tol).sum(axis=0)
    k = int(np.argmax(counts))
    mask = np.abs(p @ normals[k] - d[k]) <= tol
    if mask.sum() >= 3:
        n2, d2, _ = fit_plane(p[mask])
        mask = np.abs(p @ n2 - d2) <= tol
    return mask if mask.sum() >= 3 else None


def _patches(p: np.ndarray, link: float) -> list[np.ndarray]:
    """Connected groups of points (single linkage at ``link`` metres), largest first. Linked on
    voxels of ``link / 3`` (a scan line holds a point every few millimetres: linking every
    pair within ``link`` would cost quadratically), then handed back to the points."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    if len(p) == 0:
        return []
    voxel = link / 3.0
    _, first, inverse = np.unique(np.floor(p / voxel).astype(np.int64), axis=0, return_index=True, return_inverse=True)
    centres = p[first]
    pairs = cKDTree(centres).query_pairs(link, output_type="ndarray")
    g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(centres), len(centres)))
    _, labels = connected_components(g, directed=False)
    labels = labels[inverse.ravel()]
    groups = [np.flatnonzero(labels == k) for k in np.unique(labels)]
    return sorted(groups, key=len, reverse=True)


def _in_plane(p: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(N, 2) float32 coordinates of the points ``p`` in a basis of the plane with normal ``n``."""
    u = np.cross(n, [0.0, 0.0, 1.0] if abs(n[2]) < 0.9 else [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    return np.column_stack([p @ u, p @ np.cross(n, u)]).astype(np.float32)


def _extent(p: np.ndarray, n: np.ndarray) -> tuple[float, float, float]:
    """(length, width, area) of the points' minimum-area rectangle and convex hull in their plane."""
    xy = _in_plane(p, n)
    (_, _), (a, b), _ = cv2.minAreaRect(xy)
    hull = cv2.convexHull(xy)
    return float(max(a, b)), float(min(a, b)), float(cv2.contourArea(hull))
