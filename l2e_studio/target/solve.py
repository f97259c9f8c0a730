"""The extrinsic from many boards seen by both sensors: closed form, robust refinement, uncertainty.

For every frame the camera gives the board's pose (its plane and outline in the camera frame)
and the lidar gives points on the board and the board's edge points. ``T_cam_lidar`` must put

* the lidar's board points on the camera's board plane: their mean distance (the board's
  offset) and the lidar plane's tilt against the camera's, and
* every edge point on the board's outline (in-plane distance to the rectangle's border, a
  robust soft-L1 loss per point): the constraint along the plane that a plane alone lacks.

Each board counts as one observation of each (see :func:`_stack` for the scales and why).
:func:`closed_form` estimates the extrinsic from the planes alone (rotation aligning the lidar
normals to the camera normals by SVD, translation by linear least squares on the plane
offsets), so the seed only has to find the boards. :func:`solve` refines all frames together
(``scipy.optimize.least_squares``). Its uncertainty (:func:`covariance_of`) covers two
measures: the frame-clustered sandwich covariance (the residuals of one board share that
board's camera-pose error, so they are not independent: the clustered form counts frames, not
points) and the lidar's own measured noise carried through the solve (a floor: the scatter of
ten frames is itself an estimate of a few degrees of freedom and falls below the true error by
chance). :func:`observability` finds the direction the board normals leave unobserved.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from ..geometry import Extrinsic
from .board import Board

#: per-point scales (m): lidar range noise on the plane (the outlier test of a frame), edge
#: points on the outline (beam width, azimuth step and mixed returns; the soft-L1 scale)
PLANE_SIGMA_M, EDGE_SIGMA_M = 0.02, 0.03
#: how far one whole board may sit off its plane / outline (m): the camera's pose error and the
#: board's motion between the image and the scan (hand-held boards), shared by all its points
FRAME_PLANE_M, FRAME_EDGE_M, FRAME_TILT_DEG = 0.03, 0.01, 1.5
#: below this RMS spread of the board normals along a direction (sin of ~5 deg), that direction
#: is not observed by the planes
MIN_NORMAL_SPREAD = 0.09
AXES = ("x (right)", "y (down)", "z (forward)")


@dataclass(frozen=True)
class TargetFrame:
    """One frame's board as the solver sees it: ``pose`` = ``T_cam_board`` from the camera,
    ``points`` (N, 3) and ``edges`` (M, 3) on the board in the lidar frame, ``edge_step_rad``
    the rings' azimuth step there (an edge point is known to within a step along its ring)."""

    name: str
    pose: Extrinsic
    points: np.ndarray
    edges: np.ndarray
    edge_step_rad: float = 0.0

    @cached_property
    def pose_R(self) -> np.ndarray:
        return self.pose.R

    @cached_property
    def normal(self) -> np.ndarray:
        """The board's normal in the camera frame, towards the camera."""
        n = self.pose_R[:, 2]
        return -n if n @ self.pose.translation > 0 else n

    @cached_property
    def scatter(self) -> tuple[np.ndarray, np.ndarray]:
        """Eigenvalues (ascending) and eigenvectors of the lidar points' scatter about their
        centroid: the weakest axis is the plane's normal, the others span it (one eigen-
        decomposition for :attr:`lidar_plane` and :attr:`normal_spread`; as the SVD's, at a
        third of its cost)."""
        q = self.points - self.centroid
        return np.linalg.eigh(q.T @ q)

    @cached_property
    def lidar_plane(self) -> tuple[np.ndarray, float]:
        """The lidar points' plane ``n . p = d`` (lidar frame, n towards the sensor)."""
        n, c = self.scatter[1][:, 0], self.centroid
        if n @ c > 0:
            n = -n
        return n, float(n @ c)

    @property
    def lidar_normal(self) -> np.ndarray:
        return self.lidar_plane[0]

    @cached_property
    def lidar_rms(self) -> float:
        """RMS distance of the lidar points to their own plane (m): the lidar's range noise there."""
        n, d = self.lidar_plane
        return float(np.sqrt(np.mean((self.points @ n - d) ** 2)))

    @cached_property
    def normal_spread(self) -> tuple[np.ndarray, np.ndarray]:
        """``(T, C)``: a basis of the lidar plane (3, 2) and the covariance (2, 2) of the lidar
        normal's tilt along it that the points' own scatter (``lidar_rms``) leaves: a board seen
        on a few rings (its top above the lidar's highest beam, say) fixes its tilt across them
        only to degrees; a whole board to a tenth of one."""
        w, v = self.scatter
        return v[:, 1:], self.lidar_rms**2 * np.diag(1.0 / np.maximum(w[1:], 1e-12))

    @cached_property
    def centroid(self) -> np.ndarray:
        return self.points.mean(axis=0)

    @cached_property
    def offset(self) -> float:
        return float(self.normal @ self.pose.translation)


@dataclass(frozen=True)
class FrameResiduals:
    """One frame at an extrinsic: RMS and mean point-to-plane distance, RMS edge-to-outline distance (m)."""

    plane_rms_m: float
    plane_mean_m: float
    edge_rms_m: float
    n_points: int
    n_edges: int


@dataclass(frozen=True)
class Solution:
    """What :func:`solve` found: the extrinsic, the per-axis standard deviations of a correction
    of it (camera frame: ``sigma_m`` of x, y, z; ``sigma_deg`` of rotations about x, y, z),
    the 6x6 covariance of that correction (m, rad), the cost and evaluation count."""

    extrinsic: Extrinsic
    covariance: np.ndarray
    sigma_m: np.ndarray
    sigma_deg: np.ndarray
    cost: float
    evaluations: int
    message: str


def residuals_at(ext: Extrinsic, frame: TargetFrame, board: Board) -> tuple[np.ndarray, np.ndarray]:
    """(point-to-plane distances, edge-to-outline distances) of one frame at ``ext`` (m)."""
    return _residuals(ext.R, ext.translation, frame, board)


def _residuals(R, t, frame: TargetFrame, board: Board) -> tuple[np.ndarray, np.ndarray]:
    plane = frame.points @ (R.T @ frame.normal) + (frame.normal @ t - frame.offset)
    return plane, _edge_residuals(R, t, frame, board)


def _edge_residuals(R, t, frame: TargetFrame, board: Board) -> np.ndarray:
    if len(frame.edges) == 0:
        return np.zeros(0)
    q = (frame.edges @ R.T + t - frame.pose.translation) @ frame.pose_R  # board frame
    return outline_distance(q[:, :2], board)


def outline_distance(xy: np.ndarray, board: Board) -> np.ndarray:
    """Signed in-plane distance of board-frame points to the board's outer border (outside > 0)."""
    a, b = board.size_m[0] / 2.0, board.size_m[1] / 2.0
    dx, dy = np.abs(xy[:, 0]) - a, np.abs(xy[:, 1]) - b
    outside = np.hypot(np.maximum(dx, 0.0), np.maximum(dy, 0.0))
    inside = np.minimum(np.maximum(dx, dy), 0.0)
    return outside + inside


def frame_residuals(ext: Extrinsic, frame: TargetFrame, board: Board) -> FrameResiduals:
    plane, edge = residuals_at(ext, frame, board)
    return FrameResiduals(float(np.sqrt(np.mean(plane**2))), float(np.mean(plane)),
                          float(np.sqrt(np.mean(edge**2))) if len(edge) else float("nan"), len(plane), len(edge))


def closed_form(frames: list[TargetFrame], fallback: Extrinsic) -> Extrinsic:
    """The extrinsic from the planes alone: rotation by SVD of the normal pairs, translation by
    linear least squares on the offsets (held weakly to ``fallback``'s along directions the
    normals do not span; the rotation is ``fallback``'s when the normals span too little)."""
    lidar = [f.lidar_plane for f in frames]
    nc = np.array([f.normal for f in frames])
    nl = np.array([n for n, _ in lidar])
    dl = np.array([d for _, d in lidar])
    R = fallback.R
    if len(frames) >= 3 and normal_spread(nc)[0] >= MIN_NORMAL_SPREAD:
        U, _, Vt = np.linalg.svd(nl.T @ nc)
        S = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
        R = Vt.T @ S @ U.T
    A = np.vstack([nc, 0.05 * np.eye(3)])
    b = np.concatenate([np.array([f.offset for f in frames]) - dl, 0.05 * fallback.translation])
    t = np.linalg.lstsq(A, b, rcond=None)[0]
    return Extrinsic(Rotation.from_matrix(R).as_rotvec(), t)


def normal_spread(normals: np.ndarray) -> tuple[float, np.ndarray]:
    """(RMS component of the normals along their weakest direction, that direction)."""
    n = np.asarray(normals, dtype=np.float64)
    w, v = np.linalg.eigh(n.T @ n / max(len(n), 1))
    return float(np.sqrt(max(w[0], 0.0))), v[:, 0]


def _rodrigues(w: np.ndarray) -> np.ndarray:
    """The rotation matrix of a rotation vector (no scipy object: this is the solver's hot path)."""
    th = float(np.sqrt(w @ w))
    W = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if th < 1e-12:
        return np.eye(3) + W
    return np.eye(3) + np.sin(th) / th * W + (1.0 - np.cos(th)) / th**2 * (W @ W)


def _soft_l1(u: np.ndarray) -> np.ndarray:
    """The soft-L1 loss as a residual: ``psi(u)^2 = 2 (sqrt(1 + u^2) - 1)`` (~u near 0, ~sqrt(2|u|) far)."""
    return np.sign(u) * np.sqrt(2.0 * (np.sqrt(1.0 + u * u) - 1.0))


def _stack(x, start: Extrinsic, frames, board, use_edges):
    """Weighted residuals and their frame numbers, three blocks per frame:

    * the board's offset: the mean distance of its lidar points to the camera's plane, over
      ``FRAME_PLANE_M`` (the camera's depth of a board and the board's motion between image and
      scan are the largest errors; measured on the dev sets: APS and E2VID images of one scan
      put the board up to 5 cm apart in depth);
    * its tilt: the lidar plane's normal against the camera's (2 components), over
      ``FRAME_TILT_DEG`` (the two images of one scan disagree by up to 2 deg) combined with what
      the lidar's own scatter leaves of the plane's tilt (:attr:`TargetFrame.normal_spread`:
      a board crossed by a few rings only is one sliver, its tilt across them loose by degrees);
    * its edges: each edge point's distance to the outline, soft-L1 at ``EDGE_SIGMA_M``, the
      frame's block over ``sqrt(m) * FRAME_EDGE_M``: the board's place within its plane, which
      the camera measures best (a pixel at 2 m is 6 mm at 346 px)."""
    R = _rodrigues(x[3:]) @ start.R
    t = start.translation + x[:3]
    out, groups = [], []
    tilt2 = np.sin(np.radians(FRAME_TILT_DEG)) ** 2 * np.eye(2)
    for i, f in enumerate(frames):
        d = R @ f.lidar_normal - f.normal
        Rb = f.pose_R[:, :2]
        T, C = f.normal_spread
        M = Rb.T @ R @ T  # the lidar plane's tilt directions onto the camera board's axes
        L = np.linalg.cholesky(tilt2 + M @ C @ M.T)
        mean = f.normal @ (R @ f.centroid + t) - f.offset  # the mean point-to-plane distance
        out.append([mean / FRAME_PLANE_M, *np.linalg.solve(L, Rb.T @ d)])
        groups.append(np.full(3, i))
        if use_edges and len(f.edges):
            edge = _edge_residuals(R, t, f, board)
            out.append(_soft_l1(edge / EDGE_SIGMA_M) * (EDGE_SIGMA_M / (FRAME_EDGE_M * np.sqrt(len(edge)))))
            groups.append(np.full(len(edge), i))
    return np.concatenate(out), np.concatenate(groups)


def solve(frames: list[TargetFrame], board: Board, start: Extrinsic, use_edges: bool = True,
          covariance: bool = True, also_from: Sequence[Extrinsic] = ()) -> Solution:
    """All ``frames`` together from ``start``: least squares on the robust, frame-weighted plane
    and edge residuals (:func:`_stack`). ``also_from``: further starts, the lowest cost wins. The
    outline's corners make the edge cost piecewise, and a climb that meets a kink can stop in a
    shallow dent beside the minimum (rles01's APS frames: 0.027 deg off at a cost 4e-5 higher);
    a start that does not depend on the seed (:func:`closed_form`) gives every seed one answer."""
    if not frames:
        raise ValueError("no frame to solve from")
    best, ext = None, start
    for s in (start, *also_from):
        res = least_squares(lambda x, s=s: _stack(x, s, frames, board, use_edges)[0], np.zeros(6), method="lm",
                            x_scale=np.array([0.01] * 3 + [0.002] * 3), xtol=1e-12, ftol=1e-12, gtol=1e-12,
                            max_nfev=400)
        if best is None or res.cost < best.cost:
            best, ext = res, s.perturbed(res.x[:3], res.x[3:])
    res = best
    cov = np.full((6, 6), np.nan)
    if covariance:
        cov = covariance_of(ext, frames, board, use_edges)
    sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    return Solution(ext, cov, sd[:3], np.degrees(sd[3:]), float(res.cost), int(res.nfev), str(res.message))


def linearised(ext: Extrinsic, frames, board, use_edges: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(J, r, groups)``: the weighted residuals at ``ext``, their Jacobian with respect to a
    correction ``(dt, dw)`` (central differences) and each residual's frame number."""
    r0, groups = _stack(np.zeros(6), ext, frames, board, use_edges)
    J = np.empty((len(r0), 6))
    for k, h in enumerate([1e-6] * 3 + [1e-7] * 3):
        x = np.zeros(6)
        x[k] = h
        J[:, k] = (_stack(x, ext, frames, board, use_edges)[0] - _stack(-x, ext, frames, board, use_edges)[0]) / (2 * h)
    return J, r0, groups


def covariance_of(ext: Extrinsic, frames, board, use_edges: bool = True) -> np.ndarray:
    """The covariance of a correction ``(dt, dw)`` of the solution ``ext`` (m, rad): the smallest
    that covers both :func:`clustered_covariance` (the frames' actual scatter, which holds
    whatever the error is, but is itself uncertain with few frames) and
    :func:`noise_covariance` (what the lidar's own measured noise alone allows: a floor the
    scatter of 10 frames can fall below by chance)."""
    lin = linearised(ext, frames, board, use_edges)
    return covering(clustered_covariance(ext, frames, board, use_edges, lin),
                    noise_covariance(ext, frames, board, use_edges, lin))


def covering(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest covariance ``C >= a`` and ``C >= b`` along the eigenvectors of ``b^-1/2 a b^-1/2``
    (variances along every direction the larger of the two)."""
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        return np.full((6, 6), np.inf)
    w, v = np.linalg.eigh(b)
    if w.min() <= 0:
        return a
    half = v @ np.diag(np.sqrt(w)) @ v.T
    inv_half = v @ np.diag(1.0 / np.sqrt(w)) @ v.T
    m, u = np.linalg.eigh(inv_half @ a @ inv_half)
    return half @ u @ np.diag(np.maximum(m, 1.0)) @ u.T @ half


def clustered_covariance(ext: Extrinsic, frames, board, use_edges: bool = True, lin=None) -> np.ndarray:
    """The frame-clustered sandwich covariance of a correction ``(dt, dw)`` of ``ext`` (m, rad):
    ``A^-1 B A^-1`` with ``A = J^T J`` and ``B`` the sum over frames of the outer products of
    their gradients ``J_f^T r_f``, with the usual small-sample factor ``k / (k - 1)`` for k
    frames. It takes the frames' actual scatter, not the assumed noise, as the measure.
    ``lin``: :func:`linearised` at ``ext`` when already computed."""
    J, r0, groups = linearised(ext, frames, board, use_edges) if lin is None else lin
    A = J.T @ J
    B = np.zeros((6, 6))
    for g in np.unique(groups):
        m = groups == g
        s = J[m].T @ r0[m]
        B += np.outer(s, s)
    k = len(np.unique(groups))
    try:
        Ai = np.linalg.inv(A)
    except np.linalg.LinAlgError:
        return np.full((6, 6), np.inf)
    return Ai @ B @ Ai * (k / max(k - 1, 1))


def noise_covariance(ext: Extrinsic, frames, board, use_edges: bool = True, lin=None,
                     replicates: int = 64, seed: int = 0) -> np.ndarray:
    """The covariance of the solution under the lidar's own noise alone (m, rad), by simulation:
    each frame's points moved along their rays by Gaussian noise of that frame's measured RMS
    off its own plane, its edge points also along their ring by up to half an azimuth step either
    way (where a ring leaves the board is known to a step), then one Gauss-Newton step from
    ``ext``. ``replicates`` draws (``seed``: the same frames give the same answer)."""
    J, r0, _ = linearised(ext, frames, board, use_edges) if lin is None else lin
    try:
        pinv = np.linalg.solve(J.T @ J, J.T)
    except np.linalg.LinAlgError:
        return np.full((6, 6), np.inf)
    rng = np.random.default_rng(seed)
    models = [_noise_model(f) for f in frames]
    steps = np.empty((replicates, 6))
    for k in range(replicates):
        noisy = [_jittered(f, m, rng) for f, m in zip(frames, models)]
        steps[k] = -pinv @ (_stack(np.zeros(6), ext, noisy, board, use_edges)[0] - r0)
    return np.cov(steps, rowvar=False)


def _noise_model(f: TargetFrame) -> tuple[np.ndarray, np.ndarray, float, float]:
    """What :func:`_jittered` needs of ``f``, once: the unit rays of its points and edge points,
    the range noise along them that puts the points ``f.lidar_rms`` off their plane, the step."""
    rays = f.points / np.maximum(np.linalg.norm(f.points, axis=1, keepdims=True), 1e-9)
    edge_rays = f.edges / np.maximum(np.linalg.norm(f.edges, axis=1, keepdims=True), 1e-9)
    cos = np.sqrt(np.mean((rays @ f.lidar_normal) ** 2))
    step = f.edge_step_rad if np.isfinite(f.edge_step_rad) else 0.0
    return rays, edge_rays, f.lidar_rms / max(cos, 0.2), step


def _jittered(f: TargetFrame, model, rng: np.random.Generator) -> TargetFrame:
    """``f`` with fresh lidar noise (``model``: :func:`_noise_model` of ``f``): range noise along
    the rays, the edge points also moved along their ring by up to half a step either way."""
    rays, edge_rays, sigma, step = model
    points = f.points + rays * rng.normal(0.0, sigma, (len(rays), 1))
    edges = f.edges
    if len(edges):
        a = rng.uniform(-step / 2, step / 2, len(edges))
        c, s = np.cos(a), np.sin(a)
        edges = np.column_stack([c * edges[:, 0] - s * edges[:, 1], s * edges[:, 0] + c * edges[:, 1], edges[:, 2]])
        edges = edges + edge_rays * rng.normal(0.0, sigma, (len(edges), 1))
    return replace(f, points=points, edges=edges)


def leave_one_out(ext: Extrinsic, frames, board, use_edges: bool = True) -> list[tuple[float, float]]:
    """Per frame, (metres, degrees) the solution moves when that frame alone is left out: one
    Gauss-Newton step from ``ext`` (the solution) without the frame's residuals."""
    J, r0, groups = linearised(ext, frames, board, use_edges)
    A, g = J.T @ J, J.T @ r0
    out = []
    for i in range(len(frames)):
        m = groups == i
        try:
            step = -np.linalg.solve(A - J[m].T @ J[m], g - J[m].T @ r0[m])
        except np.linalg.LinAlgError:
            out.append((float("inf"), float("inf")))
            continue
        deg, dist = ext.error_to(ext.perturbed(step[:3], step[3:]))
        out.append((dist, deg))
    return out


@dataclass(frozen=True)
class Observability:
    """How well the boards' orientations pin the extrinsic: the RMS component of the normals
    along their weakest direction (``spread``; 0 = all boards parallel), that direction (camera
    frame), and, when it is too small, what is unobserved and which pose to add."""

    spread: float
    weakest: np.ndarray
    observed: bool
    advice: str

    def to_dict(self) -> dict:
        return {"normal_spread": round(self.spread, 4), "weakest_direction": np.round(self.weakest, 4).tolist(),
                "observed": self.observed, "advice": self.advice}


def observability(frames: list[TargetFrame], limit: float = MIN_NORMAL_SPREAD) -> Observability:
    """Eigen-analysis of the board normals (camera frame); see :class:`Observability`."""
    if len(frames) < 3:
        return Observability(0.0, np.array([1.0, 0.0, 0.0]), False,
                             f"{len(frames)} board(s) used; at least 3 of different orientation are needed")
    normals = np.array([f.normal for f in frames])
    spread, v = normal_spread(normals)
    if spread >= limit:
        return Observability(spread, v, True, "")
    mean = normals.mean(axis=0)
    mean /= np.linalg.norm(mean)
    turn = np.cross(mean, v)
    turn /= max(np.linalg.norm(turn), 1e-12)
    return Observability(spread, v, False,
                         f"the boards are nearly parallel (normals vary by {np.degrees(np.arcsin(min(spread, 1))):.1f} deg "
                         f"RMS along camera {_axis_name(v)}): translation along their normal's side direction "
                         f"{_axis_name(v)} and rotation about their common normal {_axis_name(mean)} are barely "
                         f"observed; add a pose with the board turned 20-30 deg about camera {_axis_name(turn)}")


def _axis_name(v: np.ndarray) -> str:
    """The camera axis nearest ``v`` (in words), or the vector itself when none is within 30 deg."""
    v = np.asarray(v, dtype=np.float64)
    k = int(np.argmax(np.abs(v)))
    if abs(v[k]) >= np.cos(np.radians(30)):
        return AXES[k]
    return "[" + ", ".join(f"{c:+.2f}" for c in v) + "]"
