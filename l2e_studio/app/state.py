"""The workbench's shared session state: one per server, seen by every browser tab.

A plain object guarded by one lock, with no viser import, so that its rules can be unit
tested: the current extrinsic, the selected and included scenes, the optimisation run and the
last result. GUI callbacks and the optimisation worker change it only through these methods;
each change bumps ``version`` so that renderers can tell stale work from fresh.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..geometry import Extrinsic
from .history import History

@dataclass(frozen=True)
class RunState:
    """Where the optimisation stands. ``history`` holds (evaluation, score, best score, stage)
    rows on the stage's own smoothing; ``best_curve`` (evaluation, score) rows of the best point
    so far scored on one common scale (the readout's: final smoothing, every point), which is
    what the curve plots; ``judging``: the verdict's progress once the optimiser is done (a
    :class:`l2e_studio.verdict.JudgeProgress`, None before)."""

    status: str = "idle"
    evaluations: int = 0
    fraction: float = 0.0
    stage: int = 0
    stages: int = 0
    phase: str = ""  # which climb of a multi-start search (calibrate.Progress.phase)
    mi: float = float("nan")
    best_mi: float = float("nan")
    best: Extrinsic | None = None
    history: tuple[tuple[int, float, float, int], ...] = ()
    best_curve: tuple[tuple[int, float], ...] = ()
    judging: Any = None
    error: str = ""
    started: float = 0.0
    finished: float = 0.0
    run_id: int = 0

    @property
    def active(self) -> bool:
        return self.status == "running"


@dataclass(frozen=True)
class Snapshot:
    """A consistent copy of the state at one moment (what the renderers draw from)."""

    version: int
    extrinsic: Extrinsic
    reference: Extrinsic
    selected: int
    included: tuple[bool, ...]
    run: RunState
    result: Any
    follow_best: bool
    showing_result: bool = False
    verdict: Any = None  # the verdict.Verdict on ``result`` (None: cancelled, failed, or not judged)
    judging_cancelled: bool = False  # the run finished but its judging was cancelled (not judged)

    @property
    def shown_extrinsic(self) -> Extrinsic:
        """The pose the overlay draws: the best estimate while a run is followed, the run's
        result after it (until the extrinsic is changed, accepted or discarded), else ours."""
        if self.run.active and self.follow_best and self.run.best is not None:
            return self.run.best
        if self.showing_result and self.result is not None:
            return self.accepted
        return self.extrinsic

    @property
    def handed_back(self) -> Extrinsic | None:
        """What the result hands back in the saved file and the exports: the verdict's extrinsic
        (for ``trusted-rotation`` the rotation with the seed's translation, for ``not-trusted``
        the seed), else the optimiser's own answer; None without a result."""
        if self.result is None:
            return None
        return self.verdict.extrinsic if self.verdict is not None else self.result.extrinsic

    @property
    def accepted(self) -> Extrinsic | None:
        """What Accept sets (and Before / after shows as "result"): what a trusting verdict hands
        back, else the optimiser's own answer (accepting an untrusted one is the user's call)."""
        if self.result is None:
            return None
        if self.verdict is not None and self.verdict.trusted:
            return self.verdict.extrinsic
        return self.result.extrinsic


@dataclass
class SessionState:
    """Mutable state shared by all tabs. ``reference`` is the file's seed (reset target)."""

    scene_names: list[str]
    reference: Extrinsic
    extrinsic: Extrinsic | None = None
    selected: int = 0
    included: list[bool] = field(default_factory=list)
    run: RunState = field(default_factory=RunState)
    result: Any = None  # a calibrate.CalibrationResult once a run finishes
    verdict: Any = None  # its verdict.Verdict, when it was judged
    judging_cancelled: bool = False  # its judging was cancelled: not judged
    follow_best: bool = True
    showing_result: bool = False  # the overlay stays on a run's result until the next change
    version: int = 0
    history: History = field(default_factory=History, repr=False)
    _lock: threading.RLock = field(default_factory=threading.RLock, repr=False)

    def __post_init__(self) -> None:
        if not self.scene_names:
            raise ValueError("a session needs at least one scene")
        if self.extrinsic is None:
            self.extrinsic = self.reference
        if not self.included:
            self.included = [True] * len(self.scene_names)
        if len(self.included) != len(self.scene_names):
            raise ValueError("included must have one flag per scene")

    # --- reading -------------------------------------------------------------------------
    def snapshot(self) -> Snapshot:
        with self._lock:
            assert self.extrinsic is not None
            return Snapshot(
                self.version,
                self.extrinsic,
                self.reference,
                self.selected,
                tuple(self.included),
                self.run,
                self.result,
                self.follow_best,
                self.showing_result,
                self.verdict,
                self.judging_cancelled,
            )

    # --- the extrinsic ---------------------------------------------------------------------
    def set_extrinsic(self, extrinsic: Extrinsic, source: str = "") -> int:
        """Make ``extrinsic`` the current one (an undo step); returns the new version."""
        with self._lock:
            if extrinsic is not self.extrinsic:
                assert self.extrinsic is not None
                self.history.record(self.extrinsic, source)
            self.extrinsic = extrinsic
            self.showing_result = False
            return self._bump()

    def reset_extrinsic(self) -> Extrinsic:
        """Back to the file's seed (an undo step)."""
        with self._lock:
            self.set_extrinsic(self.reference, "reset")
            return self.reference

    def undo(self) -> Extrinsic | None:
        """Back one extrinsic change; None when there is nothing to undo."""
        with self._lock:
            earlier = self.history.undo(self.extrinsic)
            if earlier is not None:
                self.extrinsic, self.showing_result = earlier, False
                self._bump()
            return earlier

    def redo(self) -> Extrinsic | None:
        """Forward one undone change; None when there is nothing to redo."""
        with self._lock:
            later = self.history.redo(self.extrinsic)
            if later is not None:
                self.extrinsic, self.showing_result = later, False
                self._bump()
            return later

    # --- scenes ----------------------------------------------------------------------------
    def select(self, index: int) -> int:
        with self._lock:
            if not 0 <= index < len(self.scene_names):
                raise IndexError(f"scene index {index} out of range 0..{len(self.scene_names) - 1}")
            self.selected = index
            return self._bump()

    def set_included(self, index: int, flag: bool) -> int:
        with self._lock:
            self.included[index] = bool(flag)
            return self._bump()

    def set_all_included(self, flag: bool) -> int:
        with self._lock:
            self.included = [bool(flag)] * len(self.scene_names)
            return self._bump()

    def set_follow_best(self, flag: bool) -> int:
        with self._lock:
            self.follow_best = bool(flag)
            self.showing_result = self.showing_result and self.follow_best
            return self._bump()

    # --- the optimisation run ---------------------------------------------------------------
    def begin_run(self) -> int:
        """Mark a run as started; raises if one is already running or no scene is included."""
        with self._lock:
            if self.run.active:
                raise RuntimeError("an optimisation is already running")
            if not any(self.included):
                raise RuntimeError("no scene is included in the optimisation")
            run_id = self.run.run_id + 1
            self.run = RunState(status="running", started=time.time(), run_id=run_id, best=self.extrinsic)
            self.showing_result = False
            self._bump()
            return run_id

    def record_progress(
        self, run_id: int, evaluations: int, mi: float, best_mi: float, best: Extrinsic,
        fraction: float, stage: int = 0, stages: int = 1, phase: str = "",
    ) -> bool:
        """Add one evaluation to the running run; False (ignored) if ``run_id`` is stale."""
        with self._lock:
            if run_id != self.run.run_id or not self.run.active:
                return False
            row = (int(evaluations), float(mi), float(best_mi), int(stage))
            self.run = replace(
                self.run,
                evaluations=int(evaluations),
                mi=float(mi),
                best_mi=float(best_mi),
                best=best,
                fraction=float(np.clip(fraction, 0.0, 1.0)),
                stage=int(stage),
                stages=int(stages),
                phase=str(phase),
                history=self.run.history + (row,),
            )
            self._bump()
            return True

    def record_best_score(self, run_id: int, evaluations: int, score: float) -> bool:
        """Add a point of the best-so-far curve on the common scale; False if ``run_id`` is stale."""
        with self._lock:
            curve = self.run.best_curve
            if run_id != self.run.run_id or not np.isfinite(score) or (curve and evaluations < curve[-1][0]):
                return False  # stale, or older than the last point (two threads add points)
            self.run = replace(self.run, best_curve=curve + ((int(evaluations), float(score)),))
            self._bump()
            return True

    def record_judging(self, run_id: int, progress: Any) -> bool:
        """The verdict's progress (a ``JudgeProgress``) on the running run; False if stale."""
        with self._lock:
            if run_id != self.run.run_id or not self.run.active:
                return False
            self.run = replace(self.run, judging=progress)
            self._bump()
            return True

    def finish_run(self, run_id: int, result: Any = None, error: str = "", verdict: Any = None,
                   judging_cancelled: bool = False) -> bool:
        """Close the run with its result (``result.cancelled`` marks a cancel) and its verdict,
        or an error; ``judging_cancelled``: the run finished, its judging was cancelled."""
        with self._lock:
            if run_id != self.run.run_id:
                return False
            if error:
                status = "failed"
            elif result is not None and (getattr(result, "cancelled", False) or judging_cancelled):
                status = "cancelled"
            else:
                status = "done"
            best = getattr(result, "extrinsic", None) or self.run.best
            self.run = replace(self.run, status=status, error=error, finished=time.time(), best=best,
                               fraction=1.0 if status == "done" else self.run.fraction)
            if result is not None:
                self.result = result
                self.verdict = verdict
                self.judging_cancelled = bool(judging_cancelled)
                self.showing_result = self.follow_best
            self._bump()
            return True

    # --- the result ---------------------------------------------------------------------------
    def accept_result(self) -> Extrinsic:
        """The result becomes the current extrinsic (the seed of the next run): what a trusting
        verdict hands back (for ``trusted-rotation``, the rotation with the seed's translation),
        else the optimiser's answer as it is (accepting an untrusted result is the user's call)."""
        with self._lock:
            if self.result is None:
                raise RuntimeError("there is no result to accept")
            chosen = self.snapshot().accepted
            self.set_extrinsic(chosen, "accept")
            return chosen

    def discard_result(self) -> None:
        with self._lock:
            self.result = None
            self.verdict = None
            self.judging_cancelled = False
            self.showing_result = False
            self._bump()

    def _bump(self) -> int:
        self.version += 1
        return self.version
