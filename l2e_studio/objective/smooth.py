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
from ..geometry import Extrinsic, left_jacobian
from ..pool import CHUNK, run_chunks
from ..score_maps import CLIP
from ..scoring import edges
from ..scoring.mi import N_BINS, entropy, kernel_matrix, kernel_taps, silverman_bandwidth, weighted_std

if TYPE_CHECKING:
    from .stack import SceneStack

MIN_DEPTH = 0.05  # m; points closer to the camera plane than this are ignored
E_MAX = np.float32(CLIP["image"] - 1e-3)  # keeps bin b + 1 inside the histogram


class MapObjective:
    """A smooth score of a fixed point set as a function of a local correction ``delta`` of
    ``base``: the bilinear map lookup and its derivatives, shared by the concrete scores.

    ``delta = (dt_x, dt_y, dt_z, dw_x, dw_y, dw_z)``: ``R = exp(dw) R0``, ``t = t0 + dt``.
    Points are processed in cache-sized chunks on the engine's threads, each chunk in compiled
    loops (:class:`l2e_studio.compiled.Lookup`): the values at the points (and the lookup's
    derivatives), then, for the gradient, their derivatives summed weighted by d score / d value.
    """

    def __init__(self, stack: SceneStack, base: Extrinsic, start: Extrinsic | None = None) -> None:
        if stack.n_points == 0:
            raise ValueError("no lidar point lands in the image at the starting extrinsic")
        self.stack = stack
        self.base = base
        dt, dw = base.delta_to(base if start is None else start)
        self.start = np.concatenate([dt, dw])  # ``start`` as a correction of ``base``
        S, Hp, Wp = stack.maps.shape
        # the last column and row a lookup may start from, less a hair: its neighbour at +1 exists
        self._lookup = compiled.Lookup(stack.camera, stack.maps.reshape(-1),
                                       stack.scene_of.astype(np.int64) * (Hp * Wp), Wp,
                                       Wp - 1 - 1e-3, Hp - 1 - 1e-3, MIN_DEPTH, E_MAX)
        self.n = float(stack.n_points)

    def extrinsic(self, delta: np.ndarray) -> Extrinsic:
        return self.base.perturbed(delta[:3], delta[3:])

    def value(self, delta: np.ndarray) -> float:  # pragma: no cover - abstract
        raise NotImplementedError

    def value_and_grad(self, delta: np.ndarray) -> tuple[float, np.ndarray]:  # pragma: no cover - abstract
        raise NotImplementedError

    # --- internals -----------------------------------------------------------------------
    def _pose(self, delta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``R``, ``t`` (float32) at ``base`` corrected by ``delta``."""
        ext = self.extrinsic(np.asarray(delta, dtype=np.float64))
        return ext.R.astype(np.float32), ext.translation.astype(np.float32)

    def _sample(self, pose: tuple[np.ndarray, np.ndarray], derivatives: bool = False
                ) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray] | None]:
        """Bilinear map values e (N,) float32 at the points projected at ``pose`` (:meth:`_pose`;
        at most E_MAX) and, with ``derivatives``, the lookup's (de/du, de/dv) for :meth:`_gradient`."""
        R, t = pose
        n = self.stack.n_points
        e = np.empty(n, dtype=np.float32)
        d = (np.empty(n, dtype=np.float32), np.empty(n, dtype=np.float32)) if derivatives else (None, None)
        run_chunks(lambda a, b: self._lookup.values(self.stack.points, a, b, R, t, e, *d), n)
        return e, d if derivatives else None

    def _gradient(self, delta: np.ndarray, pose: tuple[np.ndarray, np.ndarray], dscore_de: np.ndarray,
                  de_duv: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
        """Gradient with respect to ``delta`` (at ``pose``, its :meth:`_pose`) of a score whose
        derivative by each point's value is ``dscore_de`` (N,), the lookup's derivatives being
        ``de_duv`` (:meth:`_sample`'s)."""
        R, t = pose
        w = dscore_de.astype(np.float32, copy=False)
        n = self.stack.n_points
        parts = np.zeros((-(-n // CHUNK), 6))  # one row per chunk: summed in a fixed order
        run_chunks(lambda a, b: self._lookup.gradient(self.stack.points, a, b, R, t, w, *de_duv, parts[a // CHUNK]), n)
        g = parts.sum(axis=0)
        g[3:] = left_jacobian(np.asarray(delta, dtype=np.float64)[3:]).T @ g[3:]
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
        return float(self._w @ (self._sample(self._pose(delta))[0] - np.float32(edges.OFFSET)))

    def value_and_grad(self, delta: np.ndarray) -> tuple[float, np.ndarray]:
        pose = self._pose(delta)
        e, d = self._sample(pose, derivatives=True)
        return float(self._w @ (e - np.float32(edges.OFFSET))), self._gradient(delta, pose, self._w, d)


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
        joint = self._soft_histogram(self._sample(self._pose(self.start))[0])
        self.h_e = silverman_bandwidth(weighted_std(joint.sum(axis=0)), stack.n_points)
        self._H_l = entropy(kernel_matrix(self.h_l) @ (hist_l / self.n))

    def value(self, delta: np.ndarray) -> float:
        """MI (nats) at ``base`` corrected by ``delta``."""
        return self._mi_and_weights(self._soft_histogram(self._sample(self._pose(delta))[0]), need_weights=False)[0]

    def value_and_grad(self, delta: np.ndarray) -> tuple[float, np.ndarray]:
        """MI and its gradient with respect to ``delta``."""
        pose = self._pose(delta)
        e, d = self._sample(pose, derivatives=True)
        mi, W = self._mi_and_weights(self._soft_histogram(e), need_weights=True)
        # d MI / d e_i: the soft bin moves weight from bin b to bin b + 1 as e grows
        slopes = np.empty_like(e)
        run_chunks(lambda a, b: compiled.bin_slopes(W, self._l_offset[a:b], e[a:b], slopes[a:b]), e.size)
        return mi, self._gradient(delta, pose, slopes, d)

    def _soft_histogram(self, e: np.ndarray) -> np.ndarray:
        """(256, 256) joint histogram with E linearly split between its two nearest bins."""
        return compiled.soft_histogram(self._l_offset, e, N_BINS * N_BINS).reshape(N_BINS, N_BINS)

    def _mi_and_weights(self, joint: np.ndarray, need_weights: bool):
        """MI of the (256, 256) soft joint histogram and, with ``need_weights``, d MI / d joint
        (flat, one trailing 0 for the bin past the last)."""
        n = self.n
        p_le = smooth_joint(joint / n, self.h_l, self.h_e)
        p_e = p_le.sum(axis=0)  # smoothing commutes with marginalisation (A_l's columns sum to one)
        log_le, log_e = _log(p_le), _log(p_e)
        mi = self._H_l - float(p_e @ log_e) + float(np.sum(p_le * log_le))
        if not need_weights:
            return mi, None
        # dH/dp = -(log p + 1) (MI has +H(E), -H(L, E)) taken back through the smoothing
        W = (smooth_joint(log_le + 1.0, self.h_l, self.h_e, adjoint=True)
             - smooth_joint((log_e + 1.0)[None, :], 0.0, self.h_e, adjoint=True)) / n
        return mi, np.append(W.reshape(-1), 0.0)


def smooth_joint(joint: np.ndarray, h_l: float, h_e: float, adjoint: bool = False) -> np.ndarray:
    """``A_l @ joint @ A_e.T`` (``A = kernel_matrix(h)``) for a float64 (256, 256) ``joint``
    (rows: L bins; or one row, ``h_l`` 0), or with ``adjoint`` ``A_l.T @ joint @ A_e``, as a
    separable filter (:func:`l2e_studio.compiled.separable`): a tenth of the dense products' work,
    and its own adjoint, the kernel matrices being symmetric while a kernel's radius stays under
    the bin count. Past that (reflected twice, under ~30 points) the matrices."""
    taps_l, taps_e = kernel_taps(h_l), kernel_taps(h_e)
    if taps_l.size // 2 >= joint.shape[0] or taps_e.size // 2 >= joint.shape[1]:
        A_l, A_e = kernel_matrix(h_l, joint.shape[0]), kernel_matrix(h_e)
        return A_l.T @ joint @ A_e if adjoint else A_l @ joint @ A_e.T
    return compiled.separable(joint, taps_l, taps_e)


def _log(p: np.ndarray) -> np.ndarray:
    """``log p`` where p > 0, a large negative number where p == 0 (there ``p log p`` is 0)."""
    return np.log(np.maximum(p, 1e-300))


def single_threaded_blas():
    """Context in which BLAS runs on one thread.

    The matrix products here are small (3xN, 256x256). Multi-threaded OpenBLAS gains nothing on
    them, and when the cores are busy (the web UI, other processes) its thread hand-offs made
    each 256x256 product take tens of milliseconds instead of one.
    """
    return threadpool_limits(limits=1, user_api="blas")
