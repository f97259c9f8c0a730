"""Runs: one calibration at a time, in a thread of its own, whatever the method.

A :class:`Method` says what a run does (solve from a seed over the included scenes) and how its
answer is judged. The :class:`Runner` owns the rest, the same for every method: the thread, the
cancel flag, the 5 Hz progress ticker, the judging step and the end of a run (Result tab,
before/after, notification). The score climb is :func:`targetless`; another method (the
checkerboard solve) is another :class:`Method`, not a second pipeline.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

import numpy as np

from ..calibrate import CalibrationResult, CalibrationSettings, Progress, calibrate
from ..geometry import Extrinsic
from ..verdict import JudgeProgress, JudgingCancelled, Verdict, judge
from .text import change, score_label, score_num
from .workers import Ticker

if TYPE_CHECKING:
    from typing import Sequence

    from ..camera import CameraModel
    from ..objective import SceneStack
    from ..scenes import Scene
    from .server import App

log = logging.getLogger(__name__)

PROGRESS_PERIOD = 0.2  # s; GUI updates during a run are throttled to 5 Hz

OnProgress = Callable[[Progress], None]
OnJudging = Callable[[JudgeProgress], None]


@dataclass(frozen=True)
class Method:
    """One way to calibrate. ``solve(stack, seed, on_progress, cancel)`` returns the result over
    the included scenes (``stack``); ``judge(stack, result, cancel, on_judging)`` its verdict, or
    None when it cannot be judged (raising :class:`JudgingCancelled` once ``cancel`` is set;
    ``on_judging`` takes its :class:`JudgeProgress`). ``judging`` is the status line shown while
    the verdict is computed."""

    name: str
    solve: Callable[["SceneStack", Extrinsic, OnProgress, threading.Event], CalibrationResult]
    judge: Callable[["SceneStack", CalibrationResult, threading.Event, OnJudging], Verdict | None]
    judging: str = "Judging the result..."
    label: str = ""  # the score's name in the progress line ("": the readout's)


#: The methods the Optimise tab offers (:func:`targetless`, :func:`checkerboard`).
METHOD_NAMES = ("score climb (targetless)", "checkerboard")
CHECKERBOARD = METHOD_NAMES[1]


#: More evidence on a verdict: ``(stack, verdict, seed) -> verdict`` (e.g. the boards in view).
Evidence = Callable[["SceneStack", Verdict, Extrinsic], Verdict]


def targetless(settings: CalibrationSettings, evidence: Evidence | None = None) -> Method:
    """The paper's method: maximise the score over all included scenes, then judge the result
    (and weigh ``evidence`` the optimiser never climbed, when given)."""

    def solve(stack: "SceneStack", seed: Extrinsic, on_progress: OnProgress, cancel: threading.Event) -> CalibrationResult:
        return calibrate(stack, None, seed, settings, on_progress, cancel)

    def judge_it(stack: "SceneStack", result: CalibrationResult, cancel: threading.Event,
                 on_judging: OnJudging) -> Verdict | None:
        verdict = judge(stack, result, settings, cancel=cancel, on_progress=on_judging)
        return verdict if evidence is None or cancel.is_set() else evidence(stack, verdict, result.seed)

    return Method("Optimisation", solve, judge_it,
                  "Judging the result: halves, a second start, a second score...")


def checkerboard(scenes: "Sequence[Scene]", camera: "CameraModel", board, detections: list | None = None) -> Method:
    """The target method: the board in every included frame's image and scan, all frames solved
    together (:func:`l2e_studio.target.calibrate_target`), judged by
    :func:`l2e_studio.target_verdict.judge_target`. Frames left out of the run (the scenes not
    included) are still detected and listed, marked as left out by the user. ``detections``:
    the Target tab's, when they are of this board (else the run detects, from the cache)."""
    from ..target import calibrate_target

    def solve(stack: "SceneStack", seed: Extrinsic, on_progress: OnProgress, cancel: threading.Event) -> CalibrationResult:
        included = set(stack.names)
        exclude = [sc.name for sc in scenes if sc.name not in included]
        return calibrate_target(scenes, camera, seed, board, exclude=exclude, on_progress=on_progress, cancel=cancel,
                                detections=detections)

    def judge_it(stack: "SceneStack", result: CalibrationResult, cancel: threading.Event,
                 on_judging: OnJudging) -> Verdict | None:
        from ..target_verdict import judge_target

        return judge_target(result)

    return Method("Checkerboard calibration", solve, judge_it,
                  "Judging the result: residuals against the sensors' noise, leave-one-frame-out, board orientations...",
                  label="−board plane RMS (mm)")


class Runner:
    """Starts, cancels and finishes the workbench's runs (one at a time)."""

    def __init__(self, app: "App") -> None:
        self.app = app
        self._cancel: threading.Event | None = None
        self._thread: threading.Thread | None = None
        self._ticker: Ticker | None = None
        self._method: Method | None = None
        self._run_id, self._mask = 0, np.zeros(0, dtype=bool)
        #: the last best point put on the common-scale curve, and its score there
        self._scored_best: tuple[Extrinsic | None, float] = (None, float("nan"))
        # the curve points the run's thread asks for (each stage's start, the result), in order,
        # scored by the ticker: the run's thread never waits on the readout, so Cancel stops it at once
        self._pending: list[tuple[Extrinsic, int]] = []
        self._pending_lock = threading.Lock()

    def start(self, method: Method) -> int:
        """Start ``method`` on the included scenes from the current extrinsic (RuntimeError while
        event maps are being rebuilt)."""
        app = self.app
        with app.ui_lock:
            if app.rebuilding():
                raise RuntimeError("event maps are being rebuilt; start when that is done")
            run_id = app.state.begin_run()
            maps = {sc.name: sc.map_record() for sc in app.scene_set.scenes}
        snap = app.state.snapshot()
        cancel = threading.Event()
        self._cancel, self._method = cancel, method
        self._run_id, self._mask, self._scored_best = run_id, np.asarray(snap.included, dtype=bool), (None, float("nan"))
        self._pending = []
        self._score_best()  # the curve starts at the seed, on the readout's scale

        stage = [-1]

        def on_progress(p: Progress) -> None:
            app.state.record_progress(run_id, p.evaluations, p.mi, p.best_mi, p.best, p.fraction, p.stage, p.stages,
                                     p.phase)
            if p.stage != stage[0]:  # every stage (and start) begins with a point on the curve
                stage[0] = p.stage
                self._ask_curve_point(p.best, p.evaluations)

        def work() -> None:
            try:
                # the readout's stack already holds every scene: no second load or stacking
                stack = app.readout.stack.subset(np.asarray(snap.included, dtype=bool))
                result = method.solve(stack, snap.extrinsic, on_progress, cancel)
                app.result_maps = maps
                self._ask_curve_point(result.extrinsic, result.evaluations)  # the curve ends on the result
                verdict, judging_cancelled = self._judge(method, stack, result, cancel, run_id)
                app.state.finish_run(run_id, result, verdict=verdict, judging_cancelled=judging_cancelled)
            except Exception as exc:  # shown to the user; the app keeps running
                log.exception("%s failed", method.name.lower())
                app.state.finish_run(run_id, error=f"{type(exc).__name__}: {exc}")
            self._finished()

        app.optimise.show_running(True)
        app.event_maps.check()  # Rebuild waits for the run's end
        self._ticker = Ticker("progress", self._push_progress, lambda: app.state.snapshot().run.active, PROGRESS_PERIOD)
        self._thread = threading.Thread(target=work, name="l2e-calibrate", daemon=True)
        self._thread.start()
        return run_id

    def _judge(self, method: Method, stack: "SceneStack", result: CalibrationResult,
               cancel: threading.Event, run_id: int) -> tuple[Verdict | None, bool]:
        """The verdict on a finished run (none for a cancelled one: it is not an answer), and
        whether its judging was cancelled (then it is not judged either)."""
        if result.cancelled:
            return None, False
        self.app.optimise.show_status(method.judging)
        try:
            verdict = method.judge(stack, result, cancel, lambda p: self.app.state.record_judging(run_id, p))
        except JudgingCancelled:
            return None, True
        except Exception:  # the result stands without a verdict rather than being lost
            log.exception("judging the result failed")
            return None, False
        return (None, True) if cancel.is_set() else (verdict, False)

    def label(self) -> str:
        """The score's name of the last run started ("" for the readout's)."""
        return self._method.label if self._method is not None else ""

    def cancel(self) -> bool:
        """Ask the running calibration to stop (it returns its best point so far)."""
        if self._cancel is None or not self.app.state.snapshot().run.active:
            return False
        self._cancel.set()
        self.app.optimise.show_progress(self.app.state.snapshot().run)  # "Cancelling..." at once
        return True

    def cancel_requested(self) -> bool:
        """True once Cancel was pressed for the run in progress."""
        return self._cancel is not None and self._cancel.is_set() and self.app.state.snapshot().run.active

    def wait(self, timeout: float = 60.0) -> bool:
        """Wait up to ``timeout`` s for the run to end; True when none is running."""
        t = self._thread
        if t is not None:
            t.join(timeout)
            return not t.is_alive()
        return True

    def _score_best(self, best: Extrinsic | None = None, evaluations: int | None = None) -> None:
        """Put the run's best point on the curve, scored like the readout (final smoothing,
        every point of the included scenes): one scale for every stage and start (each stage's
        own objective scores the same point differently: its smoothing, map scale and points)."""
        run = self.app.state.snapshot().run
        best = best if best is not None else run.best
        if best is None:
            return
        if best is self._scored_best[0]:  # the search's best stands (a multi-start search keeps it
            if evaluations is not None:  # through later climbs): asked for a point, it stays level
                self.app.state.record_best_score(self._run_id, evaluations, self._scored_best[1])
            return
        try:
            score = self.app.readout.read(best, self._mask).total
        except Exception:  # a curve point is not worth failing the run over
            log.exception("scoring the best point failed")
            return
        self._scored_best = (best, score)
        self.app.state.record_best_score(self._run_id, run.evaluations if evaluations is None else evaluations, score)

    def _ask_curve_point(self, best: Extrinsic, evaluations: int) -> None:
        with self._pending_lock:
            self._pending.append((best, evaluations))

    def _score_pending(self) -> bool:
        """Score the curve points the run's thread asked for, in order; True if there were any."""
        with self._pending_lock:
            pending, self._pending = self._pending, []
        for best, evaluations in pending:
            self._score_best(best, evaluations)
        return bool(pending)

    def _push_progress(self) -> None:
        # once Cancel is pressed the run's thread has the machine to itself: no curve point is
        # scored and no overlay drawn beside it (the end of the run does both)
        cancelling = self._cancel is not None and self._cancel.is_set()
        if not cancelling and not self._score_pending() and self.app.state.snapshot().run.judging is None:
            self._score_best()
        snap = self.app.state.snapshot()
        self.app.optimise.show_progress(snap.run)
        if snap.follow_best and not cancelling:
            self.app.views.overlay_worker.poke()

    def _finished(self) -> None:
        app = self.app
        if self._ticker is not None:
            self._ticker.stop(2.0)
        app.optimise.show_progress(app.state.snapshot().run)  # "Cancelled" / "finished" at once
        app.optimise.show_running(False)
        self._score_pending()  # then the points the ticker did not get to (the result's at least)
        snap = app.state.snapshot()
        app.optimise.show_progress(snap.run)
        app.event_maps.check()
        app.result_shown(snap)
        run = snap.run
        name = self._method.name if self._method is not None else "Run"
        if run.status == "failed":
            app.notify_all(f"{name} failed", run.error, color="red")
        elif snap.result is not None:
            r: CalibrationResult = snap.result
            v = snap.verdict
            verb = ("cancelled" if r.cancelled else "finished, judging cancelled: not judged" if snap.judging_cancelled
                    else "finished")
            scores = app.result_scores  # on the readout's scale, as the Seed and Result tabs show them
            label, before, at = ((scores.label, scores.seed.score, scores.accepted.score) if scores is not None
                                 else (score_label(r.objective), r.score_seed, r.score_result))
            app.notify_all(
                f"{name} {verb}",
                f"{label} {score_num(before)} -> {score_num(at)} ({change(at, before)}) "
                f"after {r.evaluations} evaluations ({r.seconds:.1f} s)."
                + (f" Verdict: {v.summary()}." if v is not None else " Verdict: not judged.")
                + " See the Result tab and Before / after.",
                color="yellow" if v is None or v.status == "trusted-rotation"
                else "red" if not v.trusted else "green",
            )
