"""Bounded maximisation of a scene score (the paper's MI, or the edge score) over one or many
scenes, coarse to fine.

:func:`calibrate` is blocking and GUI-free: run it in a worker thread, follow it through
``on_progress`` (called from that thread after every objective evaluation) and stop it from any
thread by setting the ``cancel`` event; it then returns the best extrinsic found so far.

The search is over a correction ``(dt, dw)`` of the seed (camera frame; ``R = exp(dw) R_seed``,
``t = t_seed + dt``) bounded per axis by ``translation_bound`` metres and
``rotation_bound_deg`` degrees. Stages run from wide to narrow map smoothing (and from a thinned
point set on downsampled maps to the full set at full resolution): the 20 px stage sees a basin
several degrees across, the last one climbs the paper's objective at ``sigma``. The edge score,
whose landscape holds side peaks, is searched from many starts: the seed, and the best ends of
climbs from a grid of rotations around it (:func:`_grid_starts`). Stages thin the
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
from typing import Any, Callable, Sequence

import numpy as np
from scipy.optimize import minimize

from .camera import CameraModel
from .geometry import Extrinsic
from .objective import MapObjective, SceneStack, single_threaded_blas
from .scenes import Scene
from .scoring import EDGE_GRADIENTS, OBJECTIVES, objective_for

METHODS = ("SLSQP", "L-BFGS-B", "Powell", "Nelder-Mead")
GRADIENT_METHODS = ("SLSQP", "L-BFGS-B")
#: SLSQP stopping tolerance on the MI (nats): loose for the coarse stages, tight for the last
FTOL_COARSE, FTOL_FINAL = 1e-5, 1e-7
#: The edge score's 4 px stage (at 1280x720) runs where it blurs at least this many times the
#: final smoothing (not on small images, where 4 px scaled down is the final blur).
MIN_STEP_DOWN = 1.5
#: The global stage: from every rotation correction of the seed on a grid of this step (deg)
#: within this radius (deg: the seed's +-5 deg box, its far corners left out), a climb of the
#: middle stage on at most ``GRID_POINTS`` of the points, the same for every start so that their
#: ends compare; the ``GRID_STARTS`` best ends at least ``GRID_APART_DEG`` apart climb on. Four, not
#: two (stop 43): from a 5 deg / 20 cm seed of the synthetic HDL-64E the grid's third end is the
#: truth, and with two the search ended on a side peak scoring a third of it, trusted 22.5 cm off.
GRID_STEP_DEG, GRID_RADIUS_DEG, GRID_POINTS, GRID_STARTS, GRID_APART_DEG = 2.5, 5.6, 10_000, 4, 1.0
#: The shares of a global search's progress the seed's two climbs and the grid's climbs take (about
#: their shares of the time); the climbs from the grid's ends take the rest.
SEED_SHARE, GRID_SHARE = 0.25, 0.5


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
    objective: str = "auto"  # "mi", "edges", or "auto": chosen from the map kinds (scoring.objective_for)
    global_search: bool | None = None  # multi-start from a rotation grid; None: for the edges objective
    edge_gradient: str = "magnitude"  # what the edge maps read: "magnitude" or "scan-lines" (scoring.EDGE_GRADIENTS)

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"unknown optimiser {self.method!r}; expected one of {', '.join(METHODS)}")
        if self.objective != "auto" and self.objective not in OBJECTIVES:
            raise ValueError(f"unknown objective {self.objective!r}; expected auto or one of {', '.join(OBJECTIVES)}")
        if self.edge_gradient not in EDGE_GRADIENTS:
            raise ValueError(f"unknown edge gradient {self.edge_gradient!r}; expected one of {', '.join(EDGE_GRADIENTS)}")
        if self.translation_bound < 0 or self.rotation_bound_deg <= 0:
            raise ValueError("bounds must be positive")
        if self.sigma < 0:
            raise ValueError("sigma must be >= 0")

    def schedule(self, image_width: int = 1280, image_height: int | None = None, objective: str = "mi"
                 ) -> tuple[Stage, ...]:
        """The stages for maps ``image_width`` x ``image_height`` pixels scored by ``objective``.

        Coarse smoothing is set for the paper's 1280x720 sensor and scaled with the image's
        smaller relative side, so that a stage sees the same angular blur whatever the camera
        and a letterbox image (KITTI's 1242x375) is not blurred to a few rows; coarse maps are
        downsampled no further than 320 pixels wide. The edge score steps down through 4 px
        before its final blur: its peak at 2 px is a degree or less across, narrower than where
        the 8 px stage ends from a start degrees away (on the OpenCalib manual rig, ends 0.6-0.75
        deg off the reference that the final stage alone did not climb from); the MI of event
        maps, smooth at 2 px, needs no such step (and it would cost the 40-scene case a third).
        """
        if self.stages:
            return self.stages
        if not self.coarse_to_fine:
            return (Stage(self.sigma),)
        w = min(image_width / 1280.0, (image_height or 720) / 720.0)
        half = min(1.0, max(0.5, 640.0 / image_width))  # the middle stages' maps: no finer than 640 px wide
        stages = [
            Stage(max(20.0 * w, self.sigma), 150_000, min(1.0, max(0.25, 320.0 / image_width))),
            Stage(max(8.0 * w, self.sigma), 400_000, half),
        ]
        if objective == "edges" and 4.0 * w >= MIN_STEP_DOWN * self.sigma:
            stages.append(Stage(4.0 * w, 500_000, half))
        return (*stages, Stage(self.sigma, 500_000, 1.0))

    def stages_for(self, stack: SceneStack) -> tuple[Stage, ...]:
        """The stages for ``stack``: its maps' size and objective."""
        return self.schedule(stack.camera.width, stack.camera.height, stack.objective_name)


@dataclass(frozen=True)
class Progress:
    """A snapshot sent to ``on_progress`` after each objective evaluation."""

    evaluations: int
    stage: int  # 0-based
    stages: int
    mi: float  # objective value of this evaluation (the stage's smoothing)
    best_mi: float  # best objective value of this climb in this stage
    #: the search's best point so far: this climb's, or in a multi-start search once a climb has
    #: finished, the best finished climb's end on the final score (a climb under way, or the
    #: grid's on thinned points, is not comparable with it)
    best: Extrinsic
    fraction: float  # 0..1, a rough share of the work done
    elapsed: float  # seconds
    #: which climb of a multi-start search this is ("seed climb 1/2", "grid start 12/56", "climb from
    #: grid end 3/4"; "" for one climb): the grid's starts all climb the middle stage, and each
    #: other climb begins its stages again
    phase: str = ""


@dataclass
class CalibrationResult:
    extrinsic: Extrinsic
    seed: Extrinsic
    settings: CalibrationSettings
    scene_names: list[str]
    score_seed: float
    score_result: float
    score_seed_per_scene: np.ndarray
    score_result_per_scene: np.ndarray
    evaluations: int
    seconds: float  # optimisation wall time
    cancelled: bool = False
    history: list[tuple[int, float, int]] = field(default_factory=list)  # (evaluation, MI, stage)
    message: str = ""
    stages: tuple[Stage, ...] = ()  # the schedule that ran
    objective: str = "mi"  # the score climbed and reported in ``score_*``
    edge_gradient: str = "magnitude"  # what the edge maps read (the stack's; meaningless for ``mi``)
    #: where each start of the global search ended, with its final score (empty without it)
    ends: tuple[tuple[Extrinsic, float], ...] = ()
    #: the calibration method: "targetless" (the score climb above) or "target" (a checkerboard,
    #: :func:`l2e_studio.target.calibrate_target`)
    method: str = "targetless"
    #: the target method's per-frame table and uncertainty (:class:`l2e_studio.target.TargetDetail`)
    target: Any = None


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
    """The scenes stacked for :func:`calibrate` and its objective (``settings.objective``, or
    the one the map kinds call for): points that cannot reach the image from anywhere within
    twice the bounds around ``seed`` are left out."""
    objective = objective_for([sc.map_kind for sc in scenes], settings.objective)
    return SceneStack.build(
        scenes, camera, settings.sigma, seed, 2 * settings.translation_bound, 2 * settings.rotation_bound_deg, objective,
        settings.edge_gradient,
    )


def _calibrate(scenes, camera, seed, settings, on_progress, cancel) -> CalibrationResult:
    t0 = time.perf_counter()
    if isinstance(scenes, SceneStack):
        stack = scenes.aimed_at(seed)
    elif camera is None:
        raise ValueError("camera is required when scenes are not stacked")
    else:
        stack = stack_scenes(scenes, camera, seed, settings)
    final = stack.with_sigma(settings.sigma)
    # the seed's score first: a cancelled run then only has its result left to score
    score_seed, per_seed = final.score(seed)
    run = _search(stack, seed, settings, on_progress, cancel, t0)
    current = run.end
    cancelled, message, count, history = run.cancelled, run.message, run.count, run.history

    score_res, per_res = (score_seed, per_seed) if current is seed else final.score(current)
    if score_res < score_seed and not cancelled:
        # The smooth objective climbed somewhere its reporting form scores below the seed:
        # never hand back worse by the objective's own measure.
        current, score_res, per_res = seed, score_seed, per_seed
        message = "no extrinsic within the bounds scored above the seed; the seed is kept"
    return CalibrationResult(
        extrinsic=current,
        seed=seed,
        settings=settings,
        scene_names=list(stack.names),
        score_seed=score_seed,
        score_result=score_res,
        score_seed_per_scene=per_seed,
        score_result_per_scene=per_res,
        evaluations=count,
        seconds=time.perf_counter() - t0,
        cancelled=cancelled,
        history=history,
        message=message,
        stages=run.stages,
        objective=stack.objective_name,
        edge_gradient=stack.gradient,
        ends=run.ends,
    )


def refine(
    stack: SceneStack, start: Extrinsic, settings: CalibrationSettings, cancel: threading.Event | None = None,
    on_progress: Callable[[Progress], None] | None = None,
) -> Extrinsic:
    """Where the search of :func:`calibrate` ends from ``start``, without its bookkeeping
    (no scores at the seed and the result, no never-worse rule): the probe the verdict uses."""
    with single_threaded_blas():
        return _search(stack, start, settings, on_progress, cancel, time.perf_counter()).end


def _search(stack, seed, settings, on_progress, cancel, t0) -> "_Run":
    """Climb the schedule from ``seed`` (from several starts with the global search); the run,
    its best end point in ``run.end``."""
    stages = settings.stages_for(stack)
    scale = np.array([settings.translation_bound] * 3 + [np.radians(settings.rotation_bound_deg)] * 3)
    free = np.array([not settings.rotation_only] * 3 + [True] * 3)
    if settings.translation_bound == 0:
        free[:3] = False
    run = _Run(stack, seed, settings, scale, free, stages, on_progress, cancel, t0)
    if _global_search(settings, stack) and len(stages) > 1:
        # the seed climbs every stage and, as a seed already in the fine basin should not be
        # dragged to a side peak of the coarsest blur, every stage but the coarsest; then the
        # grid's best ends climb on from the middle stage; the final score picks the answer.
        # The seed's climbs run first, so that the search's best point is theirs while the grid
        # explores poses degrees away (what a user watching the overlay expects to see).
        final = stack.with_sigma(settings.sigma)
        explore = bool(free[3:].all())  # (no grid with the rotation held)
        seed_share = SEED_SHARE if explore else 1.0
        for j, first in enumerate((0, 1)):
            run.finish(run.climb(seed, stages[first:], first=first, part=(j * seed_share / 2, (j + 1) * seed_share / 2),
                                 phase=f"seed climb {j + 1}/2"), final)
            if run.cancelled:
                break
        starts = _grid_starts(run, seed, (seed_share, seed_share + GRID_SHARE)) if explore and not run.cancelled else []
        lo = seed_share + GRID_SHARE
        step = (1.0 - lo) / max(len(starts), 1)
        for j, start in enumerate(starts):
            run.finish(run.climb(start, stages[1:], first=1, part=(lo + j * step, lo + (j + 1) * step),
                                 phase=f"climb from grid end {j + 1}/{len(starts)}"), final)
            if run.cancelled:
                break
        run.end = max(run.ends, key=lambda es: es[1])[0]
    else:
        run.end = run.climb(seed, stages)
    return run


def _global_search(settings: CalibrationSettings, stack: SceneStack) -> bool:
    """Whether to run the multi-start global stage: on request, else (``None``) for the edge
    objective, whose coarse landscape can hold side peaks; the MI of event maps is smooth
    enough to reach seeds 0.1 rad per axis off from one start."""
    if settings.global_search is not None:
        return settings.global_search
    return stack.objective_name == "edges"


def grid_rotations() -> np.ndarray:
    """(56, 3) the global stage's rotation corrections (rad, rotation vectors in the camera
    frame): the ``GRID_STEP_DEG`` grid within ``GRID_RADIUS_DEG``, the zero correction left out."""
    n = np.floor(GRID_RADIUS_DEG / GRID_STEP_DEG)
    steps = np.radians(GRID_STEP_DEG) * np.arange(-n, n + 1)
    grid = np.stack(np.meshgrid(steps, steps, steps, indexing="ij"), axis=-1).reshape(-1, 3)
    norms = np.linalg.norm(grid, axis=1)
    return grid[(norms > 0) & (norms <= np.radians(GRID_RADIUS_DEG))]


def _grid_starts(run: "_Run", seed: Extrinsic, part: tuple[float, float] = (0.0, 1.0)) -> list[Extrinsic]:
    """Where the best of the grid's climbs end: each rotation correction of ``seed`` on the grid
    climbs the middle stage on one thinned point set, and the ``GRID_STARTS`` highest ends at
    least ``GRID_APART_DEG`` apart are returned (none with the rotation held, none once cancelled).

    Why climbs and not the grid's own scores: a blurred score at a point degrees from any peak
    ranks the points poorly (on a KITTI scan 5 deg off, the grid point nearest the reference
    ranked 1st to 62nd of 124 at the coarsest blur), while the climbs from the points within a
    degree or two of the reference end there and score highest among the ends
    (benchmarks/study_search.py)."""
    if not run.free[3:].all():
        return []
    starts = [np.concatenate([np.zeros(3), dw]) for dw in grid_rotations()]
    stage = run.stages[1]
    obj = run.stack.with_sigma(stage.sigma, stage.scale).objective(
        seed, max_points=GRID_POINTS, seen_from=[seed.perturbed(d[:3], d[3:]) for d in starts])
    ends = []
    step = (part[1] - part[0]) / len(starts)
    for i, start in enumerate(starts):
        x, value = run.climb_objective(obj, 1, start, part=(part[0] + i * step, part[0] + (i + 1) * step),
                                       phase=f"grid start {i + 1}/{len(starts)}")
        if run.cancelled:
            return []
        ends.append((value, obj.extrinsic(x)))
    chosen: list[Extrinsic] = []
    for _, end in sorted(ends, key=lambda ve: -ve[0]):
        if all(end.error_to(c)[0] >= GRID_APART_DEG for c in chosen):
            chosen.append(end)
        if len(chosen) == GRID_STARTS:
            break
    return chosen


class _Run:
    """One calibration's climbs: evaluation count, history, progress and cancel across stages
    and starts."""

    def __init__(self, stack, seed, settings, scale, free, stages, on_progress, cancel, t0) -> None:
        self.stack, self.seed, self.settings = stack, seed, settings
        self.scale, self.free, self.stages, self.n_stages = scale, free, tuple(stages), len(stages)
        self.on_progress, self.cancel, self.t0 = on_progress, cancel, t0
        self.count = 0
        self.history: list[tuple[int, float, int]] = []
        self.cancelled = False
        self.message = ""
        self.end = seed  # where the search ended (set by _search)
        self.ends: tuple[tuple[Extrinsic, float], ...] = ()  # every start's end and final score
        #: the best finished climb's end of a multi-start search (None before the first has
        #: finished): the progress's best point, as a climb under way does not compare with it
        self.leader: Extrinsic | None = None

    def finish(self, end: Extrinsic, final: SceneStack) -> None:
        """Record the end of one climb of a multi-start search, scored on ``final``."""
        self.ends += ((end, final.score(end, per_scene=False)[0]),)
        self.leader = max(self.ends, key=lambda es: es[1])[0]

    def climb(self, start: Extrinsic, stages: Sequence[Stage], first: int = 0,
              part: tuple[float, float] = (0.0, 1.0), phase: str = "") -> Extrinsic:
        """Climb ``stages`` (numbered from ``first``) from ``start``, the progress reported
        across ``part`` of the whole search as ``phase``; the best point reached."""
        current = start
        lo, step = part[0], (part[1] - part[0]) / max(len(stages), 1)
        for i, stage in enumerate(stages):
            k = first + i
            if self.cancel is not None and self.cancel.is_set():
                self.cancelled, self.message = True, "cancelled"
                break
            prepared = self.stack.with_sigma(stage.sigma, stage.scale)  # the stage's set-up: ~0.3 s at 40 full-size maps
            if self.cancel is not None and self.cancel.is_set():
                self.cancelled, self.message = True, "cancelled"
                break
            obj = prepared.objective(self.seed, start=current, max_points=stage.max_points)
            current = obj.extrinsic(self.climb_objective(obj, k, part=(lo + i * step, lo + (i + 1) * step), phase=phase)[0])
            if self.cancelled:
                break
        return current

    def climb_objective(self, obj: MapObjective, k: int, start: np.ndarray | None = None,
                        part: tuple[float, float] = (0.0, 1.0), phase: str = "") -> tuple[np.ndarray, float]:
        """Climb ``obj`` as stage ``k`` from the correction ``start`` (default: the objective's
        own start), the progress reported across ``part`` of the search as ``phase``; the best
        correction reached and its value (the best so far once cancelled)."""
        tracker = _Tracker(obj, self.scale, self.free, k, self.n_stages, self.on_progress, self.cancel, self.t0,
                           self.count, self.history, start, part, phase, self.leader)
        try:
            res = _run_stage(obj, tracker, self.settings, final=k == self.n_stages - 1)
            self.message = str(res.message)
            x, value = tracker.full(res.x), -float(res.fun)
            if value < tracker.best_mi:  # keep the best point seen, whatever the optimiser says
                x, value = tracker.best_delta, tracker.best_mi
        except _Cancelled:
            self.cancelled, self.message = True, "cancelled"
            x, value = tracker.best_delta, tracker.best_mi
        self.count = tracker.count
        return x, value


class _Tracker:
    """Wraps the objective for scipy: scaling, fixed axes, counting, best point, progress, cancel."""

    #: A stage typically takes this many evaluations; progress approaches the stage's end by it.
    TYPICAL_EVALUATIONS = 25.0

    def __init__(self, obj: MapObjective, scale, free, stage, stages, on_progress, cancel, t0, count, history,
                 start: np.ndarray | None = None, part: tuple[float, float] = (0.0, 1.0), phase: str = "",
                 leader: Extrinsic | None = None):
        self.obj, self.scale, self.free = obj, scale, free
        self.leader = leader
        self.stage, self.stages = stage, stages
        self.on_progress, self.cancel, self.t0 = on_progress, cancel, t0
        self.count, self.history = count, history
        self.part, self.phase = part, phase
        self.start_count = count
        self.fixed = (obj.start if start is None else np.asarray(start, float)).copy()
        self.best_mi = -np.inf
        self.best_delta = self.fixed.copy()

    def z0(self) -> np.ndarray:
        return (self.fixed / self.scale)[self.free]

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
                    best=self.leader or self.obj.extrinsic(self.best_delta),
                    fraction=self.part[0] + (self.part[1] - self.part[0]) * done,
                    elapsed=time.perf_counter() - self.t0,
                    phase=self.phase,
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


def _run_stage(obj: MapObjective, tr: _Tracker, settings: CalibrationSettings, final: bool = True):
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
