"""Uncertainty of one calibration: a standard deviation per parameter.

Two estimates, both about how much the answer depends on which scenes were recorded:

* **curvature** (:func:`curvature`): the Hessian ``H`` of the differentiable MI at the optimum
  (the least-squares slope of its analytic gradient over a box of a few pixels) and, for each scene ``s``, the gradient
  ``g_-s`` of the MI of the other scenes. One Newton step ``-H^-1 (g_-s - g)`` is where the
  optimum moves without scene ``s``; the jackknife over those steps gives the covariance
  (an infinitesimal-jackknife / sandwich estimate: the curvature says how much a tilt of the
  landscape moves the peak, the scenes say how much the landscape tilts from scene to scene).
  Costs ``S + 49`` gradient evaluations, no optimisation.
* **bootstrap** (:func:`half_sample_specs`): recalibrate from the result on random halves of the
  scenes (through the study executor). For half-samples drawn without replacement the spread
  of the half-sample answers equals the spread of the full-set answer, so their standard
  deviation is reported as is.

Units: ``x, y, z`` in mm and ``rx, ry, rz`` in degrees, camera frame (:data:`l2e_studio.qa.AXES`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..geometry import Extrinsic
from ..objective import SceneStack
from . import AXES
from .studies import RunSpec

BOX_PX = 1.0  # the Hessian is fitted over offsets that move the image by about this many pixels
HESSIAN_SAMPLES = 24  # antithetic pairs of gradient evaluations
TO_REPORT = np.array([1000.0] * 3 + [np.degrees(1.0)] * 3)  # m, rad -> mm, deg


@dataclass
class Uncertainty:
    method: str
    std: np.ndarray  # (6,) mm and deg
    covariance: np.ndarray | None = None  # (6, 6) in mm / deg units
    hessian: np.ndarray | None = None  # (6, 6) of the MI in m / rad units
    samples: int = 0

    def to_dict(self) -> dict:
        out = {"method": self.method, "std": {a: round(float(v), 6) for a, v in zip(AXES, self.std)}, "samples": self.samples}
        if self.hessian is not None:
            out["hessian_eigenvalues"] = np.round(np.linalg.eigvalsh(self.hessian), 6).tolist()
        return out


def _grad(stack: SceneStack, centre: Extrinsic, delta: np.ndarray | None = None) -> np.ndarray:
    obj = stack.objective(centre)
    _, g = obj.value_and_grad(np.zeros(6) if delta is None else delta)
    return np.asarray(g, dtype=float)


def hessian_box(stack: SceneStack, centre: Extrinsic, px: float | None = None) -> np.ndarray:
    """Half sizes (m, m, m, rad, rad, rad) of offsets that move the projected points by about
    ``px`` pixels: ``px / f`` radians, and ``px / f`` times the median depth in metres."""
    px = BOX_PX if px is None else px
    cam = stack.full_camera or stack.camera
    f = float(np.sqrt(cam.K[0, 0] * cam.K[1, 1]))
    pts = stack.points[:, :: max(1, stack.n_points // 20000)].T.astype(np.float64)
    z = centre.transform(pts)[:, 2]
    depth = float(np.median(z[z > 0.05])) if np.any(z > 0.05) else 5.0
    return np.array([px * depth / f] * 3 + [px / f] * 3)


def hessian(stack: SceneStack, centre: Extrinsic, samples: int = HESSIAN_SAMPLES, rng_seed: int = 0) -> np.ndarray:
    """Hessian of the differentiable MI with respect to ``(dt m, dw rad)`` at ``centre``.

    The map lookup is bilinear, so the gradient is piecewise smooth at the scale of a pixel and
    a finite difference over a fraction of a pixel measures that roughness, not the curvature.
    The Hessian is instead the least-squares slope of the analytic gradient over ``samples``
    random offsets in a box that moves the image by about ``BOX_PX`` pixels (see :func:`hessian_box`)."""
    obj = stack.objective(centre)
    rng = np.random.default_rng(rng_seed)
    box = hessian_box(stack, centre)
    deltas = rng.uniform(-1.0, 1.0, (samples, 6)) * box
    deltas = np.vstack([np.zeros(6), deltas, -deltas])  # antithetic pairs cancel the odd terms
    grads = np.array([np.asarray(obj.value_and_grad(d)[1], dtype=float) for d in deltas])
    X = np.hstack([np.ones((len(deltas), 1)), deltas / box])
    coef, *_ = np.linalg.lstsq(X, grads, rcond=None)
    H = (coef[1:] / box[:, None]).T  # d g_i / d delta_j
    return 0.5 * (H + H.T)


def curvature(stack: SceneStack, centre: Extrinsic, rotation_only: bool = False) -> Uncertainty:
    """Per-parameter std of the optimum at ``centre`` over scene resampling (see module doc)."""
    S = stack.n_scenes
    if S < 3:
        raise InputError(None, f"the curvature estimate needs at least 3 scenes, got {S}")
    from ..objective import single_threaded_blas

    with single_threaded_blas():
        free = np.array([not rotation_only] * 3 + [True] * 3)
        H = hessian(stack, centre)
        g_all = _grad(stack, centre)
        steps = []
        Hf = H[np.ix_(free, free)]
        if not np.all(np.linalg.eigvalsh(Hf) < 0):
            # not a maximum along every axis: the Newton step is meaningless along the others
            Hf = -np.abs(Hf)  # fall back to the curvature magnitudes (warned about by the guardrails)
        for s in range(S):
            keep = np.delete(np.arange(S), s)
            g = _grad(stack.subset(keep), centre) - g_all
            step = np.zeros(6)
            step[free] = -np.linalg.solve(Hf, g[free])
            steps.append(step)
    steps = np.array(steps) * TO_REPORT
    dev = steps - steps.mean(0)
    cov = (S - 1) / S * dev.T @ dev
    return Uncertainty("curvature (Hessian + scene jackknife)", np.sqrt(np.diag(cov)), cov, H, S)


def half_sample_specs(result: Extrinsic, n_scenes: int, n: int = 20, rng_seed: int = 0, method: str = "SLSQP") -> list[RunSpec]:
    """``n`` recalibrations from ``result`` on random halves of the scenes (run them with
    :func:`l2e_studio.qa.studies.study`; :func:`from_half_samples` turns them into an estimate)."""
    if n_scenes < 4:
        raise InputError(None, f"the scene bootstrap needs at least 4 scenes, got {n_scenes}")
    rng = np.random.default_rng(rng_seed)
    half = n_scenes // 2
    return [RunSpec(i, method, result, tuple(sorted(rng.choice(n_scenes, half, replace=False).tolist()))) for i in range(n)]


def from_half_samples(params: np.ndarray) -> Uncertainty:
    """Std per parameter of half-sample recalibrations ((n, 6) in mm / deg)."""
    p = np.asarray(params, dtype=float).reshape(-1, 6)
    if len(p) < 2:
        raise InputError(None, "the scene bootstrap needs at least 2 runs")
    return Uncertainty("scene bootstrap (random halves)", p.std(0, ddof=1), np.cov(p.T), None, len(p))
