"""What the optimiser climbs: a score of a fixed point set as a smooth function of a local
correction ``(dt, dw)`` of a base extrinsic, ``R = exp(dw) R0, t = t0 + dt``, with its analytic
gradient.

* :class:`MIObjective`: the paper's MI made differentiable (bilinear map lookup, linear
  soft-binning of E, Silverman widths frozen for the stage), for event maps;
* :class:`EdgeObjective`: the edge score's weighted mean of the band-passed edge map.

The point set is fixed for the stage (:meth:`l2e_studio.objective.SceneStack.objective` picks
it), so the plug-in estimate cannot grow by pushing points off the image: a point that leaves
reads the maps' zero padding.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from threadpoolctl import threadpool_limits

from .. import compiled
from ..geometry import Extrinsic, distort, left_jacobian
from ..pool import run_chunks
from ..score_maps import CLIP
from ..scoring import edges
from ..scoring.mi import N_BINS, entropy, kernel_matrix, silverman_bandwidth, weighted_std

if TYPE_CHECKING:
    from .stack import SceneStack

MIN_DEPTH = 0.05  # m; points closer to the camera plane than this are ignored
E_MAX = np.float32(CLIP["image"] - 1e-3)  # keeps bin b + 1 inside the histogram


class MapObjective:
    """A smooth score of a fixed point set as a function of a local correction ``delta`` of
    ``base``: the bilinear map lookup and its Jacobian, shared by the concrete scores.

    ``delta = (dt_x, dt_y, dt_z, dw_x, dw_y, dw_z)``: ``R = exp(dw) R0``, ``t = t0 + dt``.
    Points are processed in cache-sized chunks; the projection and its Jacobian are numpy,
    the bilinear lookup of the float32 maps is compiled (:func:`l2e_studio.compiled.bilinear`).
    """

    def __init__(self, stack: SceneStack, base: Extrinsic, start: Extrinsic | None = None) -> None:
        if stack.n_points == 0:
            raise ValueError("no lidar point lands in the image at the starting extrinsic")
        self.stack = stack
        self.base = base
        dt, dw = base.delta_to(base if start is None else start)
        self.start = np.concatenate([dt, dw])  # ``start`` as a correction of ``base``
        S, Hp, Wp = stack.maps.shape
        self._maps = stack.maps.reshape(-1)
        self._qw = Wp - 1  # the last column and row a lookup may start from (+1 for its neighbour)
        self._qh = Hp - 1
        self._scene_base = stack.scene_of.astype(np.int64) * (Hp * Wp)
        self._K = stack.camera.K.astype(np.float32)
        self.n = float(stack.n_points)

    def extrinsic(self, delta: np.ndarray) -> Extrinsic:
        return self.base.perturbed(delta[:3], delta[3:])

    def value(self, delta: np.ndarray) -> float:  # pragma: no cover - abstract
        raise NotImplementedError

    def value_and_grad(self, delta: np.ndarray) -> tuple[float, np.ndarray]:  # pragma: no cover - abstract
        raise NotImplementedError

    # --- internals -----------------------------------------------------------------------
    def _sample(self, delta: np.ndarray, jacobian: bool) -> tuple[np.ndarray, np.ndarray | None]:
        """Bilinear map values e (N,) at the projected points and, with ``jacobian``, de/d(delta)
        as (6, N) (its rotation rows still to be multiplied by the left Jacobian's transpose)."""
        ext = self.extrinsic(np.asarray(delta, dtype=np.float64))
        R = ext.R.astype(np.float32)
        t = ext.translation.astype(np.float32)
        n = self.stack.n_points
        e = np.empty(n, dtype=np.float32)
        d = np.empty((6, n), dtype=np.float32) if jacobian else None
        run_chunks(lambda a, b: self._sample_chunk(R, t, a, b, e, d), n)
        np.minimum(e, E_MAX, out=e)
        return e, d

    def _sample_chunk(self, R, t, a, b, e_out, d_out) -> None:
        P = self.stack.points[:, a:b]
        Q = R @ P  # rotated points
        Z = Q[2] + t[2]
        front = Z > MIN_DEPTH
        inv_z = 1.0 / np.maximum(Z, np.float32(MIN_DEPTH))
        x = (Q[0] + t[0]) * inv_z
        y = (Q[1] + t[1]) * inv_z
        cam = self.stack.camera
        if np.isfinite(cam.max_r2):  # beyond the lens's fold: not in the image
            front &= x * x + y * y <= np.float32(cam.max_r2)
        xd, yd, Jd = distort(x, y, cam, d_out is not None)
        K = self._K
        # packed-map coordinates: map pixel (0, 0) sits at (1, 1) of the zero-padded map
        u = K[0, 0] * xd + (K[0, 2] + 1.0)
        if K[0, 1] != 0:
            u += K[0, 1] * yd
        v = K[1, 1] * yd + (K[1, 2] + 1.0)
        u_max = np.float32(self._qw - 1e-3)
        v_max = np.float32(self._qh - 1e-3)
        uc = np.clip(u, 0.0, u_max)
        vc = np.clip(v, 0.0, v_max)
        uc[~front] = 0.0
        e = e_out[a:b]
        de_du = np.empty_like(uc) if d_out is not None else None
        de_dv = np.empty_like(vc) if d_out is not None else None
        compiled.bilinear(self._maps, self._scene_base[a:b], self._qw + 1, uc, vc, e, de_du, de_dv)
        if d_out is None:
            return
        # the lookup's derivatives are zero where the point was clamped to the border
        de_du[(u <= 0.0) | (u >= u_max) | ~front] = 0.0
        de_dv[(v <= 0.0) | (v >= v_max) | ~front] = 0.0
        dxd_dx, dxd_dy, dyd_dx, dyd_dy = Jd
        # chain through d(u, v)/d(x, y) and d(x, y)/d(X, Y, Z)
        gx = de_du * (K[0, 0] * dxd_dx + K[0, 1] * dyd_dx) + de_dv * (K[1, 1] * dyd_dx)
        gy = de_du * (K[0, 0] * dxd_dy + K[0, 1] * dyd_dy) + de_dv * (K[1, 1] * dyd_dy)
        gX = gx * inv_z
        gY = gy * inv_z
        gZ = -(gx * x + gy * y) * inv_z
        out = d_out[:, a:b]
        out[0], out[1], out[2] = gX, gY, gZ
        # rotation: d X_cam / d dw = -[Q]x J_l(dw), so de/d(dw) = J_l^T (Q x g)
        out[3] = Q[1] * gZ - Q[2] * gY
        out[4] = Q[2] * gX - Q[0] * gZ
        out[5] = Q[0] * gY - Q[1] * gX

    def _chain(self, de_ddelta: np.ndarray, dscore_de: np.ndarray, delta: np.ndarray) -> np.ndarray:
        """Gradient with respect to ``delta`` from d score / d e per point."""
        g = (de_ddelta @ dscore_de.astype(np.float32)).astype(np.float64)
        g[3:] = left_jacobian(delta[3:]).T @ g[3:]
        return g


class EdgeObjective(MapObjective):
    """The edge score (:mod:`l2e_studio.scoring.edges`) made smooth: bilinear lookup of the
    band-passed edge map, weighted mean over the stage's fixed set of edge points."""

    def __init__(self, stack: SceneStack, base: Extrinsic, start: Extrinsic | None = None) -> None:
        super().__init__(stack, base, start)
        if stack.weights is None:
            raise ValueError("the edges objective needs a stack built for it")
        total = float(stack.weights.sum())
        self._w = (stack.weights / (edges.SCALE * max(total, 1e-12))).astype(np.float32)

    def value(self, delta: np.ndarray) -> float:
        e, _ = self._sample(np.asarray(delta, dtype=np.float64), jacobian=False)
        return float(self._w @ (e - np.float32(edges.OFFSET)))

    def value_and_grad(self, delta: np.ndarray) -> tuple[float, np.ndarray]:
        delta = np.asarray(delta, dtype=np.float64)
        e, de_ddelta = self._sample(delta, jacobian=True)
        return float(self._w @ (e - np.float32(edges.OFFSET))), self._chain(de_ddelta, self._w, delta)


class MIObjective(MapObjective):
    """Differentiable MI (the paper's estimator made smooth) of the stage's fixed point set.

    The Silverman widths are fixed when the objective is made (at ``start``) so that the
    value and the gradient describe one and the same smooth function.
    """

    def __init__(self, stack: SceneStack, base: Extrinsic, start: Extrinsic | None = None) -> None:
        super().__init__(stack, base, start)
        self._l_offset = (stack.l_bins * N_BINS).astype(np.int32)
        hist_l = np.bincount(stack.l_bins, minlength=N_BINS).astype(np.float64)
        self.h_l = silverman_bandwidth(weighted_std(hist_l), stack.n_points)
        joint = self._soft_histogram(self._sample(self.start, jacobian=False)[0])
        self.h_e = silverman_bandwidth(weighted_std(joint.sum(axis=0)), stack.n_points)
        self._A_l = kernel_matrix(self.h_l)
        self._A_e = kernel_matrix(self.h_e)
        self._H_l = entropy(self._A_l @ (hist_l / self.n))

    def value(self, delta: np.ndarray) -> float:
        """MI (nats) at ``base`` corrected by ``delta``."""
        e, _ = self._sample(delta, jacobian=False)
        return self._mi_and_weights(self._soft_histogram(e), need_weights=False)[0]

    def value_and_grad(self, delta: np.ndarray) -> tuple[float, np.ndarray]:
        """MI and its gradient with respect to ``delta``."""
        delta = np.asarray(delta, dtype=np.float64)
        e, de_ddelta = self._sample(delta, jacobian=True)
        mi, W = self._mi_and_weights(self._soft_histogram(e), need_weights=True)
        # d MI / d e_i: the soft bin moves weight from bin b to bin b + 1 as e grows
        j = self._l_offset + e.astype(np.int32)
        return mi, self._chain(de_ddelta, W[j + 1] - W[j], delta)

    def _soft_histogram(self, e: np.ndarray) -> np.ndarray:
        """(256, 256) joint histogram with E linearly split between its two nearest bins."""
        b = e.astype(np.int32)
        frac = e - b
        j = self._l_offset + b
        size = N_BINS * N_BINS
        h = np.bincount(j, weights=1.0 - frac, minlength=size + 1)
        h[1:] += np.bincount(j, weights=frac, minlength=size + 1)[:-1]
        return h[:size].reshape(N_BINS, N_BINS)

    def _mi_and_weights(self, joint: np.ndarray, need_weights: bool):
        n = self.n
        A_l, A_e = self._A_l, self._A_e
        p_le = A_l @ (joint / n) @ A_e.T
        p_e = A_e @ (joint.sum(axis=0) / n)
        mi = self._H_l + entropy(p_e) - entropy(p_le)
        if not need_weights:
            return mi, None
        tiny = 1e-300
        g_le = -(np.log(np.maximum(p_le, tiny)) + 1.0)  # dH/dp
        g_e = -(np.log(np.maximum(p_e, tiny)) + 1.0)
        W = ((A_e.T @ g_e)[None, :] - A_l.T @ g_le @ A_e) / n
        return mi, np.append(W.reshape(-1), 0.0)


def single_threaded_blas():
    """Context in which BLAS runs on one thread.

    The matrix products here are small (3xN, 256x256). Multi-threaded OpenBLAS gains nothing on
    them, and when the cores are busy (the web UI, other processes) its thread hand-offs made
    each 256x256 product take tens of milliseconds instead of one.
    """
    return threadpool_limits(limits=1, user_api="blas")
