"""Repeatability and scene-count studies (the paper's noise experiment and its scene-count figure).

A study is a list of independent calibrations (:class:`RunSpec`: a perturbed seed, an optional
scene subset, an optimiser). They run through a :class:`concurrent.futures.Executor`: local
processes by default (:class:`~concurrent.futures.ProcessPoolExecutor`), or an existing Dask
cluster (``distributed.Client(address).get_executor()``) when a scheduler address is given --
one code path, :func:`run_study`, for both. Each worker builds the scene stack once (from the
scene folder, or from the stack sent with the task) and keeps it for the following runs.

Parameters are reported as the local correction of each extrinsic relative to a reference
(the study's centre, or the truth when known): ``x, y, z`` in mm and ``rx, ry, rz`` in degrees,
camera frame (:data:`l2e_studio.qa.AXES`).
"""

from __future__ import annotations

import contextlib
import os
import threading
import time
from concurrent.futures import FIRST_COMPLETED, Executor, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass, field, replace
from typing import Callable, Iterator, Sequence

import numpy as np

from ..calibrate import METHODS, CalibrationSettings, calibrate, stack_scenes
from ..errors import InputError
from ..geometry import Extrinsic
from ..objective import SceneStack
from . import AXES


@dataclass(frozen=True)
class StackSource:
    """Where a worker gets its scenes: a scene folder (loaded once per worker process) or a
    prepared stack (sent with every task: for small in-memory scene sets)."""

    folder: str | None = None
    seed_file: str | None = None
    camera_file: str | None = None
    stack: SceneStack | None = None

    def __post_init__(self) -> None:
        if (self.folder is None) == (self.stack is None):
            raise ValueError("give a scene folder or a stack, not both")


@dataclass(frozen=True)
class RunSpec:
    index: int
    method: str
    seed: Extrinsic  # the perturbed seed this run starts from
    subset: tuple[int, ...] | None = None  # scene indices, None = all
    group: int = 0  # e.g. the scene count of a scene-count study


@dataclass
class StudyResult:
    kind: str  # "repeatability" | "scenes"
    reference: Extrinsic  # parameters are corrections relative to this
    reference_name: str  # "centre" | "truth"
    noise_m: float
    noise_deg: float
    runs: list[dict] = field(default_factory=list)  # one dict per finished run (see _run_one)
    cancelled: bool = False
    wall_seconds: float = 0.0
    executor: str = ""

    # --- summaries ---------------------------------------------------------------------------
    def params(self, key: str = "result", method: str | None = None, group: int | None = None) -> np.ndarray:
        """(n, 6) ``key`` ("result" or "seed") parameters of the finished runs, mm and deg."""
        rows = [r[key] for r in self.runs if (method is None or r["method"] == method) and (group is None or r["group"] == group)]
        return np.array(rows, dtype=float).reshape(-1, 6)

    def summary(self) -> dict:
        """Per optimiser: mean and std of each parameter, of the run time and evaluations;
        for a scene-count study, per scene count: the std of each parameter."""
        out: dict = {"kind": self.kind, "runs": len(self.runs), "reference": self.reference_name,
                     "noise": {"translation_m": self.noise_m, "rotation_deg": self.noise_deg},
                     "wall_seconds": round(self.wall_seconds, 3), "executor": self.executor,
                     "cancelled": self.cancelled, "methods": {}}
        for m in sorted({r["method"] for r in self.runs}):
            runs = [r for r in self.runs if r["method"] == m]
            p = self.params(method=m)
            secs = np.array([r["seconds"] for r in runs])
            out["methods"][m] = {
                "runs": len(runs),
                "mean": dict(zip(AXES, _r(p.mean(0)))),
                "std": dict(zip(AXES, _r(p.std(0, ddof=1) if len(p) > 1 else np.full(6, np.nan)))),
                "seconds_mean": round(float(secs.mean()), 3),
                "seconds_std": round(float(secs.std(ddof=1)), 3) if len(secs) > 1 else None,
                "evaluations_mean": round(float(np.mean([r["evaluations"] for r in runs])), 1),
            }
        if self.kind == "scenes":
            out["scene_counts"] = {}
            for g in sorted({r["group"] for r in self.runs}):
                p = self.params(group=g)
                out["scene_counts"][int(g)] = {
                    "runs": len(p),
                    "std": dict(zip(AXES, _r(p.std(0, ddof=1) if len(p) > 1 else np.full(6, np.nan)))),
                    "rms": dict(zip(AXES, _r(np.sqrt((p ** 2).mean(0))))),
                }
        return out

    def to_dict(self) -> dict:
        return {"summary": self.summary(), "reference_T_cam_lidar": np.round(self.reference.matrix, 10).tolist(),
                "runs": self.runs}


def correction(reference: Extrinsic, ext: Extrinsic) -> np.ndarray:
    """``ext`` as a correction of ``reference``: (x, y, z) mm and (rx, ry, rz) deg, camera frame."""
    dt, dw = reference.delta_to(ext)
    return np.concatenate([1000.0 * dt, np.degrees(dw)])


def perturbed_seeds(centre: Extrinsic, n: int, noise_m: float, noise_deg: float, rng: np.random.Generator) -> list[Extrinsic]:
    """``n`` seeds, each axis perturbed uniformly in [-noise, +noise] (camera frame)."""
    out = []
    for _ in range(n):
        dt = rng.uniform(-noise_m, noise_m, 3) if noise_m > 0 else np.zeros(3)
        dw = np.radians(rng.uniform(-noise_deg, noise_deg, 3)) if noise_deg > 0 else np.zeros(3)
        out.append(centre.perturbed(dt, dw))
    return out


def check_study_args(n: int, noise_m: float, noise_deg: float, methods: Sequence[str], subset: int | None = None,
                     n_scenes: int | None = None) -> None:
    """Raise :class:`InputError` (one line) for a study that cannot run."""
    if n < 1:
        raise InputError(None, f"a study needs at least one run, got N={n}")
    if noise_m < 0 or noise_deg < 0 or not np.isfinite(noise_m) or not np.isfinite(noise_deg):
        raise InputError(None, f"noise levels must be finite and >= 0, got {noise_m} m / {noise_deg} deg")
    for m in methods:
        if m not in METHODS:
            raise InputError(None, f"unknown optimiser {m!r}; expected one of {', '.join(METHODS)}")
    if subset is not None and n_scenes is not None and not 1 <= subset <= n_scenes:
        raise InputError(None, f"a scene subset must hold 1..{n_scenes} scenes, got {subset}")


def repeatability_specs(centre: Extrinsic, n: int, noise_m: float, noise_deg: float, methods: Sequence[str] = ("SLSQP",),
                        n_scenes: int = 0, subset: int | None = None, rng_seed: int = 0) -> list[RunSpec]:
    """``n`` runs per optimiser from uniformly perturbed seeds (the same seeds for each
    optimiser), each on a random subset of ``subset`` scenes when given."""
    rng = np.random.default_rng(rng_seed)
    seeds = perturbed_seeds(centre, n, noise_m, noise_deg, rng)
    subsets = [tuple(sorted(rng.choice(n_scenes, subset, replace=False).tolist())) if subset else None for _ in range(n)]
    return [RunSpec(k * n + i, m, seeds[i], subsets[i]) for k, m in enumerate(methods) for i in range(n)]


def scene_count_specs(centre: Extrinsic, counts: Sequence[int], n: int, noise_m: float, noise_deg: float,
                      n_scenes: int, method: str = "SLSQP", rng_seed: int = 0) -> list[RunSpec]:
    """``n`` runs for each scene count, each on a random subset of that many scenes."""
    rng = np.random.default_rng(rng_seed)
    specs = []
    for c in counts:
        if not 1 <= c <= n_scenes:
            raise InputError(None, f"scene counts must be 1..{n_scenes}, got {c}")
        for s in perturbed_seeds(centre, n, noise_m, noise_deg, rng):
            subset = tuple(sorted(rng.choice(n_scenes, c, replace=False).tolist()))
            specs.append(RunSpec(len(specs), method, s, subset, group=int(c)))
    return specs


# --- executors ----------------------------------------------------------------------------------

@contextlib.contextmanager
def open_executor(dask: str | None = None, workers: int | None = None, connect_timeout: float = 10.0) -> Iterator[tuple[Executor, str]]:
    """Local processes, or the Dask cluster at ``dask`` (``tcp://host:8786``) through
    ``Client.get_executor()``; yields ``(executor, description)``."""
    if dask:
        try:
            from distributed import Client
        except ImportError:
            raise InputError(None, "--dask needs the 'distributed' package (pip install 'dask[distributed]')") from None
        try:
            client = Client(dask, timeout=connect_timeout, set_as_default=False)
        except (OSError, TimeoutError) as exc:
            raise InputError(None, f"no Dask scheduler answers at {dask} ({type(exc).__name__}: {exc})".split("\n")[0]) from None
        except ValueError as exc:
            raise InputError(None, f"bad Dask scheduler address {dask!r} ({exc})") from None
        try:
            n = len(client.scheduler_info().get("workers", {}))
            yield client.get_executor(), f"dask {dask} ({n} workers)"
        finally:
            client.close()
        return
    import multiprocessing

    n = workers or max(1, os.cpu_count() or 1)
    threads = max(1, (os.cpu_count() or 1) // n)
    ex = ProcessPoolExecutor(n, mp_context=multiprocessing.get_context("spawn"), initializer=_init_worker, initargs=(threads,))
    try:
        yield ex, f"{n} local processes"
    finally:
        ex.shutdown(wait=True, cancel_futures=True)


def _init_worker(threads: int) -> None:
    from .. import pool

    pool.WORKERS = threads


def run_study(
    executor: Executor,
    source: StackSource,
    centre: Extrinsic,
    settings: CalibrationSettings,
    specs: Sequence[RunSpec],
    on_progress: Callable[[int, int, dict], None] | None = None,
    cancel: threading.Event | None = None,
) -> tuple[list[dict], bool]:
    """Run every spec on ``executor``; return (finished runs ordered by index, cancelled).

    ``on_progress(done, total, run)`` is called in this thread as each run finishes. Setting
    ``cancel`` cancels the runs not started yet and returns what has finished.
    """
    pending: set[Future] = {executor.submit(_run_one, source, centre, settings, s) for s in specs}
    done_runs: list[dict] = []
    cancelled = False
    try:
        while pending:
            if cancel is not None and cancel.is_set():
                cancelled = True
                for f in pending:
                    f.cancel()
                break
            finished, pending = wait(pending, timeout=0.2, return_when=FIRST_COMPLETED)
            for f in finished:
                run = f.result()
                done_runs.append(run)
                if on_progress is not None:
                    on_progress(len(done_runs), len(specs), run)
    except BaseException:
        for f in pending:
            f.cancel()
        raise
    return sorted(done_runs, key=lambda r: r["index"]), cancelled


def study(
    kind: str,
    source: StackSource,
    centre: Extrinsic,
    settings: CalibrationSettings,
    specs: Sequence[RunSpec],
    noise_m: float,
    noise_deg: float,
    truth: Extrinsic | None = None,
    dask: str | None = None,
    workers: int | None = None,
    executor: Executor | None = None,
    on_progress: Callable[[int, int, dict], None] | None = None,
    cancel: threading.Event | None = None,
) -> StudyResult:
    """Run a study (see :func:`repeatability_specs`, :func:`scene_count_specs`) and summarise it
    relative to ``truth`` when given, else to ``centre``."""
    reference = truth if truth is not None else centre
    t0 = time.perf_counter()
    with (contextlib.nullcontext((executor, "given executor")) if executor is not None
          else open_executor(dask, workers)) as (ex, desc):
        runs, cancelled = run_study(ex, source, centre, settings, specs, on_progress, cancel)
    res = StudyResult(kind, reference, "truth" if truth is not None else "centre", noise_m, noise_deg,
                      cancelled=cancelled, wall_seconds=time.perf_counter() - t0, executor=desc)
    for r in runs:
        seed = Extrinsic.from_matrix(np.array(r.pop("seed_T")))
        ext = Extrinsic.from_matrix(np.array(r.pop("result_T")))
        r["seed"] = _r(correction(reference, seed))
        r["result"] = _r(correction(reference, ext))
        r["T_cam_lidar"] = np.round(ext.matrix, 10).tolist()
        res.runs.append(r)
    return res


# --- the worker side ----------------------------------------------------------------------------

_STACKS: dict = {}


def _stack_for(source: StackSource, centre: Extrinsic, settings: CalibrationSettings) -> SceneStack:
    if source.stack is not None:
        return source.stack
    key = (source.folder, source.seed_file, source.camera_file, tuple(np.round(centre.params, 9)),
           settings.translation_bound, settings.rotation_bound_deg, settings.sigma)
    if key not in _STACKS:
        from ..scenes import load_scene_folder

        scene_set = load_scene_folder(source.folder, source.seed_file, source.camera_file)
        _STACKS.clear()  # one scene set per worker at a time
        _STACKS[key] = stack_scenes(scene_set.scenes, scene_set.camera, centre, settings)
    return _STACKS[key]


_MALLOC_TUNED = False


def _tune_malloc() -> None:
    """Undo a fixed ``MALLOC_TRIM_THRESHOLD_`` (Dask's nanny sets 64 KiB in its workers).

    Setting it turns off glibc's dynamic mmap threshold, so every large numpy temporary of an
    objective evaluation is mmap'd, zero-filled and unmapped again: calibrations ran about 3x
    slower in Dask workers than in local processes. A fixed 32 MiB mmap threshold and a 256 MiB
    trim threshold put them back on the heap. Linux/glibc only; a no-op elsewhere.
    """
    global _MALLOC_TUNED
    if _MALLOC_TUNED:
        return
    _MALLOC_TUNED = True
    if "MALLOC_TRIM_THRESHOLD_" not in os.environ:
        return
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6")
        libc.mallopt(-3, 32 * 1024 * 1024)  # M_MMAP_THRESHOLD
        libc.mallopt(-1, 256 * 1024 * 1024)  # M_TRIM_THRESHOLD
    except (OSError, AttributeError):
        pass


def _run_one(source: StackSource, centre: Extrinsic, settings: CalibrationSettings, spec: RunSpec) -> dict:
    """One calibration of a study, in a worker: a plain dict that pickles cheaply back."""
    _tune_malloc()
    stack = _stack_for(source, centre, settings)
    if spec.subset is not None:
        stack = stack.subset(list(spec.subset))
    t0 = time.perf_counter()
    res = calibrate(stack, None, spec.seed, replace(settings, method=spec.method))
    return {
        "index": spec.index,
        "method": spec.method,
        "group": spec.group,
        "scenes": len(stack.names) if spec.subset is None else list(spec.subset),
        "seed_T": spec.seed.matrix.tolist(),
        "result_T": res.extrinsic.matrix.tolist(),
        "score_seed": float(res.score_seed),
        "score_result": float(res.score_result),
        "evaluations": int(res.evaluations),
        "seconds": round(float(res.seconds), 4),
        "wall_seconds": round(time.perf_counter() - t0, 4),
        "worker_pid": os.getpid(),
        "message": res.message,
    }


def _r(a) -> list:
    return [None if not np.isfinite(v) else round(float(v), 6) for v in np.asarray(a, dtype=float).ravel()]


__all__ = ["StackSource", "RunSpec", "StudyResult", "study", "run_study", "open_executor", "repeatability_specs",
           "scene_count_specs", "perturbed_seeds", "correction", "check_study_args"]
