"""Uncertainty of one calibration: a standard deviation per parameter.

Two estimates, both about how much the answer depends on which scenes were recorded:

* **curvature** (:func:`curvature`): the Hessian ``H`` of the differentiable MI at the optimum
  (central differences of its analytic gradient) and, for each scene ``s``, the gradient
  ``g_-s`` of the MI of the other scenes. One Newton step ``-H^-1 (g_-s - g)`` is where the
  optimum moves without scene ``s``; the jackknife over those steps gives the covariance
  (an infinitesimal-jackknife / sandwich estimate: the curvature says how much a tilt of the
  landscape moves the peak, the scenes say how much the landscape tilts from scene to scene).
  Costs ``S + 12`` gradient evaluations, no optimisation.
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

STEP_M = 1e-3  # Hessian finite-difference steps
STEP_RAD = np.radians(0.02)
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


def hessian(stack: SceneStack, centre: Extrinsic) -> np.ndarray:
    """Hessian of the differentiable MI with respect to ``(dt m, dw rad)`` at ``centre``."""
    obj = stack.objective(centre)
    H = np.zeros((6, 6))
    for k in range(6):
        h = STEP_M if k < 3 else STEP_RAD
        d = np.zeros(6)
        d[k] = h
        gp = obj.value_and_grad(d)[1]
        gm = obj.value_and_grad(-d)[1]
        H[:, k] = (np.asarray(gp) - np.asarray(gm)) / (2 * h)
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
