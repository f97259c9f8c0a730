"""Bounded MI maximisation over one or many scenes, coarse to fine.

:func:`calibrate` is blocking and GUI-free: run it in a worker thread, follow it through
``on_progress`` (called from that thread after every objective evaluation) and stop it from any
thread by setting the ``cancel`` event; it then returns the best extrinsic found so far.

The search is over a correction ``(dt, dw)`` of the seed (camera frame; ``R = exp(dw) R_seed``,
``t = t_seed + dt``) bounded per axis by ``translation_bound`` metres and
``rotation_bound_deg`` degrees. Stages run from wide to narrow map smoothing (and from a thinned
point set on downsampled maps to the full set at full resolution): the 20 px stage sees a basin
several degrees across, the last one climbs the paper's objective at ``sigma``. Stages thin the
points to a budget (500k for the last: 40 full-size scenes put ~1.3M in the image, and all of them
move the optimum by less than the spread of repeated runs while costing 3x).

Why the last stage smooths by 2 px and not the reference code's 5 px: heavy smoothing flattens
the MI along the direction where a small rotation and a translation compensate each other, and
shifts its peak there. On synthetic scenes with a known answer the optimum at 5 px sat
0.13 deg / 15 mm from the truth, at 2 px within 0.01 deg / 1 mm (benchmarks/bench_engine.py).
The reference's +-5 deg bound is widened to +-10 deg so seeds 0.1 rad off per axis still hold
the truth inside the box.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
from scipy.optimize import minimize

from .camera import CameraModel
from .geometry import Extrinsic
from .objective import SceneStack, SmoothObjective, single_threaded_blas
from .scenes import Scene

METHODS = ("SLSQP", "L-BFGS-B", "Powell", "Nelder-Mead")
GRADIENT_METHODS = ("SLSQP", "L-BFGS-B")
#: SLSQP stopping tolerance on the MI (nats): loose for the coarse stages, tight for the last
FTOL_COARSE, FTOL_FINAL = 1e-5, 1e-7


@dataclass(frozen=True)
class Stage:
    """One pass of the optimiser: map smoothing ``sigma`` (full-resolution px), at most
    ``max_points`` of the points in the image (evenly thinned; None = all), maps resized by
    ``scale`` (coarse stages need no full resolution)."""

    sigma: float
    max_points: int | None = None
    scale: float = 1.0


@dataclass(frozen=True)
class CalibrationSettings:
    """What the optimiser does. The defaults reach seeds 0.1 m / 0.1 rad per axis away."""

    method: str = "SLSQP"
    translation_bound: float = 0.2  # m, per axis, around the seed
    rotation_bound_deg: float = 10.0  # deg, per axis, around the seed
    sigma: float = 2.0  # px, map smoothing of the final stage and of the reported MI
    coarse_to_fine: bool = True
    rotation_only: bool = False
    max_iterations: int = 100  # per stage
    stages: tuple[Stage, ...] | None = None  # overrides the schedule derived from sigma

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"unknown optimiser {self.method!r}; expected one of {', '.join(METHODS)}")
        if self.translation_bound < 0 or self.rotation_bound_deg <= 0:
            raise ValueError("bounds must be positive")
        if self.sigma < 0:
            raise ValueError("sigma must be >= 0")

    def schedule(self, image_width: int = 1280) -> tuple[Stage, ...]:
        """The stages for maps ``image_width`` pixels wide.

        Coarse smoothing is set for the paper's 1280-pixel sensor and scaled with the width, so
        that a stage sees the same angular blur whatever the camera; coarse maps are downsampled
        no further than 320 pixels wide.
        """
        if self.stages:
            return self.stages
        if not self.coarse_to_fine:
            return (Stage(self.sigma),)
        w = image_width / 1280.0
        return (
            Stage(max(20.0 * w, self.sigma), 150_000, min(1.0, max(0.25, 320.0 / image_width))),
            Stage(max(8.0 * w, self.sigma), 400_000, min(1.0, max(0.5, 640.0 / image_width))),
            Stage(self.sigma, 500_000, 1.0),
        )


@dataclass(frozen=True)
class Progress:
    """A snapshot sent to ``on_progress`` after each objective evaluation."""

    evaluations: int
    stage: int  # 0-based
    stages: int
    mi: float  # objective value of this evaluation (the stage's smoothing)
    best_mi: float  # best objective value in this stage
    best: Extrinsic
    fraction: float  # 0..1, a rough share of the work done
    elapsed: float  # seconds


@dataclass
class CalibrationResult:
    extrinsic: Extrinsic
    seed: Extrinsic
    settings: CalibrationSettings
    scene_names: list[str]
    mi_seed: float
    mi_result: float
    mi_seed_per_scene: np.ndarray
    mi_result_per_scene: np.ndarray
    evaluations: int
    seconds: float  # optimisation wall time
    cancelled: bool = False
    history: list[tuple[int, float, int]] = field(default_factory=list)  # (evaluation, MI, stage)
    message: str = ""
    stages: tuple[Stage, ...] = ()  # the schedule that ran


class _Cancelled(Exception):
    pass


def calibrate(
    scenes: Sequence[Scene] | SceneStack,
    camera: CameraModel | None,
    seed: Extrinsic,
    settings: CalibrationSettings = CalibrationSettings(),
    on_progress: Callable[[Progress], None] | None = None,
    cancel: threading.Event | None = None,
) -> CalibrationResult:
    """Maximise the MI of all ``scenes`` together, starting from ``seed``.

    ``scenes`` may be a prepared :class:`SceneStack` (then ``camera`` is ignored), which is how
    callers that evaluate MI themselves avoid stacking the scenes twice.
    """
    with single_threaded_blas():
        return _calibrate(scenes, camera, seed, settings, on_progress, cancel)


def stack_scenes(
    scenes: Sequence[Scene], camera: CameraModel, seed: Extrinsic, settings: CalibrationSettings = CalibrationSettings()
) -> SceneStack:
    """The scenes stacked for :func:`calibrate`: points that cannot reach the image from
    anywhere within twice the bounds around ``seed`` are left out."""
    return SceneStack.build(scenes, camera, settings.sigma, seed, 2 * settings.translation_bound, 2 * settings.rotation_bound_deg)


def _calibrate(scenes, camera, seed, settings, on_progress, cancel) -> CalibrationResult:
    t0 = time.perf_counter()
    if isinstance(scenes, SceneStack):
        stack = scenes
    elif camera is None:
        raise ValueError("camera is required when scenes are not stacked")
    else:
        stack = stack_scenes(scenes, camera, seed, settings)
    final = stack.with_sigma(settings.sigma)
    stages = settings.schedule(stack.camera.width)
    scale = np.array([settings.translation_bound] * 3 + [np.radians(settings.rotation_bound_deg)] * 3)
    free = np.array([not settings.rotation_only] * 3 + [True] * 3)
    if settings.translation_bound == 0:
        free[:3] = False

    # the seed's score first: a cancelled run then only has its result left to score
    mi_seed, per_seed = final.mi(seed)
    history: list[tuple[int, float, int]] = []
    count = 0
    current = seed
    cancelled = False
    message = ""
    for k, stage in enumerate(stages):
        if cancel is not None and cancel.is_set():
            cancelled, message = True, "cancelled"
            break
        obj = stack.with_sigma(stage.sigma, stage.scale).objective(seed, start=current, max_points=stage.max_points)
        tracker = _Tracker(obj, scale, free, k, len(stages), on_progress, cancel, t0, count, history)
        try:
            res = _run_stage(obj, tracker, settings, final=k == len(stages) - 1)
            message = str(res.message)
            x = tracker.full(res.x)
            if -res.fun < tracker.best_mi:  # keep the best point seen, whatever the optimiser says
                x = tracker.best_delta
        except _Cancelled:
            cancelled = True
            x = tracker.best_delta
            message = "cancelled"
        count = tracker.count
        current = obj.extrinsic(x)
        if cancelled:
            break

    mi_res, per_res = (mi_seed, per_seed) if current is seed else final.mi(current)
    if mi_res < mi_seed and not cancelled:
        # The smooth objective climbed somewhere the paper's MI scores below the seed (seen on
        # street scenes of frame cameras, where the landscape misleads): never hand back worse.
        current, mi_res, per_res = seed, mi_seed, per_seed
        message = "no extrinsic within the bounds scored above the seed; the seed is kept"
    return CalibrationResult(
        extrinsic=current,
        seed=seed,
        settings=settings,
        scene_names=list(stack.names),
        mi_seed=mi_seed,
        mi_result=mi_res,
        mi_seed_per_scene=per_seed,
        mi_result_per_scene=per_res,
        evaluations=count,
        seconds=time.perf_counter() - t0,
        cancelled=cancelled,
        history=history,
        message=message,
        stages=stages,
    )


class _Tracker:
    """Wraps the objective for scipy: scaling, fixed axes, counting, best point, progress, cancel."""

    #: A stage typically takes this many evaluations; progress approaches the stage's end by it.
    TYPICAL_EVALUATIONS = 25.0

    def __init__(self, obj: SmoothObjective, scale, free, stage, stages, on_progress, cancel, t0, count, history):
        self.obj, self.scale, self.free = obj, scale, free
        self.stage, self.stages = stage, stages
        self.on_progress, self.cancel, self.t0 = on_progress, cancel, t0
        self.count, self.history = count, history
        self.start_count = count
        self.fixed = obj.start.copy()
        self.best_mi = -np.inf
        self.best_delta = obj.start.copy()

    def z0(self) -> np.ndarray:
        return (self.obj.start / self.scale)[self.free]

    def full(self, z: np.ndarray) -> np.ndarray:
        delta = self.fixed.copy()
        delta[self.free] = np.asarray(z) * self.scale[self.free]
        return delta

    def _check_cancel(self) -> None:
        if self.cancel is not None and self.cancel.is_set():
            raise _Cancelled

    def _record(self, delta: np.ndarray, mi: float) -> None:
        self.count += 1
        self.history.append((self.count, mi, self.stage))
        if mi > self.best_mi:
            self.best_mi, self.best_delta = mi, delta.copy()
        if self.on_progress is not None:
            done = 1.0 - np.exp(-(self.count - self.start_count) / self.TYPICAL_EVALUATIONS)
            self.on_progress(
                Progress(
                    evaluations=self.count,
                    stage=self.stage,
                    stages=self.stages,
                    mi=mi,
                    best_mi=self.best_mi,
                    best=self.obj.extrinsic(self.best_delta),
                    fraction=(self.stage + done) / self.stages,
                    elapsed=time.perf_counter() - self.t0,
                )
            )

    def fun(self, z: np.ndarray) -> float:
        self._check_cancel()
        delta = self.full(z)
        mi = self.obj.value(delta)
        self._record(delta, mi)
        return -mi

    def fun_and_grad(self, z: np.ndarray) -> tuple[float, np.ndarray]:
        self._check_cancel()
        delta = self.full(z)
        mi, g = self.obj.value_and_grad(delta)
        self._record(delta, mi)
        return -mi, -(g * self.scale)[self.free]


def _run_stage(obj: SmoothObjective, tr: _Tracker, settings: CalibrationSettings, final: bool = True):
    n = int(tr.free.sum())
    bounds = [(-1.0, 1.0)] * n
    z0 = np.clip(tr.z0(), -1.0, 1.0)
    method = settings.method
    if method in GRADIENT_METHODS:
        options = {"maxiter": settings.max_iterations}
        if method == "SLSQP":
            options["ftol"] = FTOL_FINAL if final else FTOL_COARSE
        else:
            options.update(ftol=1e-12, gtol=1e-8)
        return minimize(tr.fun_and_grad, z0, jac=True, method=method, bounds=bounds, options=options)
    options = {"maxiter": settings.max_iterations * n, "xtol": 1e-4, "ftol": 1e-9}
    if method == "Nelder-Mead":
        options = {"maxiter": settings.max_iterations * n, "xatol": 1e-4, "fatol": 1e-9}
    return minimize(tr.fun, z0, method=method, bounds=bounds, options=options)
