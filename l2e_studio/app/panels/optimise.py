"""The optimisation: settings, Start / Cancel, and live progress (bar, score curve, best pose),
then the judging's own steps.

The curve is on one scale: the optimiser's best point (5 times a second) scored like the readout
(the final smoothing, every point of the included scenes), the best of those so far, with the
stage on a second axis (with the edge score's multi-start search, each new start climbs the
stages again). Each stage's own objective scores the same point differently (its smoothing, map
scale and points), and each start's search begins below the best so far: plotted raw, a "best"
fell at every stage change and every new start.

The run itself is :func:`l2e_studio.calibrate.calibrate` in a worker thread (see
:meth:`App.start_run`); this panel only reads settings and shows :class:`RunState`.
"""

from __future__ import annotations

import time
import numpy as np
import viser
import viser.uplot

from ..context import Workbench
from ...calibrate import METHODS, CalibrationSettings
from ...limits import MAX_ROTATION_BOUND_DEG, MAX_SIGMA_PX, MAX_TRANSLATION_BOUND_M
from ..runs import CHECKERBOARD, METHOD_NAMES
from ..checks import Checked, check_rotation_bound, check_sigma, check_translation_bound, start_blocker
from ..exact import format_value
from ..pose import describe
from ..text import change, score_num
from ..state import RunState

IDLE_TEXT = "Idle. Start optimises the included scenes from the current extrinsic."
STATUS_WORDS = {
    "running": "**Running**",
    "done": "✓ **Finished**",
    "cancelled": "■ **Cancelled**: the best point so far, not a converged result",
    "failed": "✗ **Failed**",
    "idle": "**Idle**",
}


class OptimisePanel:
    def __init__(self, app: Workbench) -> None:
        self.app = app
        gui = app.server.gui
        defaults = CalibrationSettings()
        self.calibration = gui.add_dropdown("Method", METHOD_NAMES, initial_value=METHOD_NAMES[0],
                                            hint="score climb: the paper's method, no target needed; checkerboard: "
                                                 "the board of the Target tab in every frame (the settings below are "
                                                 "the score climb's)")
        self.method = gui.add_dropdown("Optimiser", METHODS, initial_value=defaults.method,
                                       hint="SLSQP is fastest; L-BFGS-B and Powell are robust")
        # Text fields, checked on the server: a number box would clamp or drop what is typed.
        self.t_bound = gui.add_text("± translation (m)", format_value(defaults.translation_bound),
                                    hint=f"Search bound per axis around the start, metres: [0, {MAX_TRANSLATION_BOUND_M:g}] "
                                         "(as calibrate --bound-m; 0 keeps it fixed)")
        self.t_problem = gui.add_markdown("", visible=False)
        self.r_bound = gui.add_text("± rotation (°)", format_value(defaults.rotation_bound_deg),
                                    hint=f"Search bound per axis around the start, degrees: (0, {MAX_ROTATION_BOUND_DEG:g}] "
                                         "(as calibrate --bound-deg)")
        self.r_problem = gui.add_markdown("", visible=False)
        self.sigma_in = gui.add_text("Smoothing σ (px)", format_value(defaults.sigma),
                                     hint=f"Gaussian smoothing of the event maps in pixels, [0, {MAX_SIGMA_PX:g}] "
                                          "(as calibrate --sigma); the paper uses 5")
        self.s_problem = gui.add_markdown("", visible=False)
        self._sigma = float(defaults.sigma)
        self.rotation_only = gui.add_checkbox("Rotation only", defaults.rotation_only,
                                              hint="Keep the translation fixed; search the rotation only")
        self.coarse = gui.add_checkbox("Coarse to fine", defaults.coarse_to_fine,
                                       hint="Start on wider smoothing and fewer points: a wider basin")
        self.start = gui.add_button("Start", color="green", icon=viser.Icon.PLAYER_PLAY)
        self.blocker = gui.add_markdown("", visible=False)
        self.cancel = gui.add_button("Cancel", color="red", icon=viser.Icon.PLAYER_STOP, disabled=True)
        self.follow = gui.add_checkbox("Overlay follows best", True,
                                       hint="While running, draw the optimiser's best estimate in the overlay")
        self.progress = gui.add_progress_bar(0.0, animated=False)
        self.status = gui.add_markdown(IDLE_TEXT)
        # viser 1.1's client never redraws a uPlot created with empty data, so the plot starts
        # with one placeholder point and stays hidden until a run has history.
        label = app.readout.label
        self.plot = gui.add_uplot(
            (np.zeros(1), np.zeros(1), np.zeros(1)),
            (
                viser.uplot.Series(label="evaluation"),
                viser.uplot.Series(label=f"best {label} so far (any start, as the readout)", stroke="#e8590c", width=2),
                viser.uplot.Series(label="stage", stroke="#868e96", width=1, dash=[4, 3], scale="stage"),
            ),
            title=f"best {label} so far, one scale (final σ, all points) · stage",
            scales={"x": viser.uplot.Scale(time=False, auto=True), "y": viser.uplot.Scale(auto=True),
                    "stage": viser.uplot.Scale(auto=False, range=(0.5, 3.5))},
            axes=(viser.uplot.Axis(), viser.uplot.Axis(label=label),
                  viser.uplot.Axis(scale="stage", side=1, label="stage", grid={"show": False})),
            aspect=1.6,
            visible=False,
        )
        self.best_text = gui.add_markdown("")
        self.start.on_click(self._on_start)
        self.cancel.on_click(self._on_cancel)
        self.follow.on_update(lambda _: app.follow_changed(bool(self.follow.value)))
        for handle in (self.t_bound, self.r_bound, self.sigma_in, self.calibration):
            handle.on_update(lambda _: self.check())
        self.check()

    def sigma(self) -> float:
        """The last valid smoothing sigma (the readout and the smoothed map view use it)."""
        return self._sigma

    def checked(self) -> tuple[Checked, Checked, Checked]:
        return (check_translation_bound(self.t_bound.value), check_rotation_bound(self.r_bound.value),
                check_sigma(self.sigma_in.value))

    def check(self) -> list[str]:
        """Show each field's problem beside it, follow a valid sigma, and enable Start or say why not."""
        results = self.checked()
        for c, note in zip(results, (self.t_problem, self.r_problem, self.s_problem)):
            note.content = f"⚠ {c.problem}" if c.problem else ""
            note.visible = bool(c.problem)
        sigma = results[2].value
        if sigma is not None and sigma != self._sigma:
            self._sigma = sigma
            self.app.sigma_changed(sigma)
        problems = [c.problem for c in results if c.problem]
        self.show_start(problems)
        return problems

    def show_start(self, problems: list[str] | None = None) -> None:
        """Start is enabled only when a run can start; otherwise the reason shows below it."""
        if problems is None:
            problems = [c.problem for c in self.checked() if c.problem]
        snap = self.app.state.snapshot()
        reason = start_blocker(sum(snap.included), problems, snap.run.active, self.app.rebuilding())
        if not reason and self.calibration.value == CHECKERBOARD:
            reason = self.app.target_problem()
            reason = f"{reason} (Target tab)" if reason else ""
        self.start.disabled = bool(reason)
        self.blocker.content = f"Start is disabled: {reason}." if reason and not snap.run.active else ""
        self.blocker.visible = bool(self.blocker.content)

    def settings(self) -> CalibrationSettings:
        t, r, sigma = self.checked()
        if not (t.ok and r.ok and sigma.ok):
            raise ValueError("; ".join(c.problem for c in (t, r, sigma) if c.problem))
        return CalibrationSettings(
            method=self.method.value,
            translation_bound=float(t.value),
            rotation_bound_deg=float(r.value),
            sigma=float(sigma.value),
            rotation_only=bool(self.rotation_only.value),
            coarse_to_fine=bool(self.coarse.value),
            edge_gradient=self.app.edge_gradient,
        )

    def _on_start(self, event) -> None:
        try:
            self.app.start_run(self.settings(), self.calibration.value)
        except (RuntimeError, ValueError) as exc:
            self.app.notify(event.client, "Cannot start", str(exc), color="red")

    def _on_cancel(self, event) -> None:
        if self.app.cancel_run():
            self.cancel.disabled = True
            self.status.content = "**Cancelling...** the optimiser stops at its next evaluation and keeps its best point"

    def show_status(self, text: str) -> None:
        """A status line of the run's own (e.g. while its result is being judged)."""
        self.status.content = text

    def show_running(self, running: bool) -> None:
        self.cancel.disabled = not running
        for handle in (self.calibration, self.method, self.t_bound, self.r_bound, self.sigma_in, self.rotation_only,
                       self.coarse):
            handle.disabled = running
        self.progress.animated = running
        self.show_start()

    def show_handed_back(self, scores) -> None:
        """After the run: what is handed back and its score, as the Result tab and the readout show it."""
        if scores is None:
            return
        a = scores.accepted
        self.status.content += (f"  \n**After Accept**: {a.what} · {self.app.readout.label} {score_num(a.score)} "
                                f"({change(a.score, scores.seed.score)} vs the seed; details in the Result tab)")

    def show_progress(self, run: RunState) -> None:
        label = self.app.readout.label
        if run.best_curve:
            self.plot.data = curve_data(run)
            self.plot.visible = True
        elapsed = (run.finished or time.time()) - run.started if run.started else 0.0
        cancelling = run.active and self.app.cancel_requested()
        head = "**Cancelling...**" if cancelling else STATUS_WORDS[run.status]
        if run.status == "cancelled" and run.judging is not None:
            head = "■ **Cancelled while judging**: the optimiser finished, its result is **not judged**"
        best, seed = (run.best_curve[-1][1], run.best_curve[0][1]) if run.best_curve else (None, None)
        scored = (f"{label} of the best point {score_num(best)} ({change(best, seed)} vs the seed {score_num(seed)}; "
                  f"final σ, all points: the readout's scale)")
        j = run.judging
        if run.active and j is not None:  # the optimiser is done, the verdict is being computed
            self.progress.value = float(np.clip(100.0 * j.fraction, 0.0, 100.0))
            text = (f"{'**Cancelling...**' if cancelling else '**Judging the result**'} · step {j.step}/{j.steps}: "
                    f"{j.label} · {j.elapsed:.1f} s  \n{scored}")
        else:
            self.progress.value = float(np.clip(100.0 * run.fraction, 0.0, 100.0))
            stage = (f"{run.phase} · " if run.phase else "") + (f"stage {run.stage + 1}/{run.stages} · " if run.stages else "")
            text = (f"{head} · {stage}{run.evaluations} evaluations · {elapsed:.1f} s  \n{scored}  \n"
                    f"<small>this stage's own objective, {self.app.run_label()} (its smoothing, its points; "
                    f"not comparable across stages): {score_num(run.mi)}, best {score_num(run.best_mi)}</small>")
        if run.error:
            text += f"  \n{run.error}"
        self.status.content = text
        if run.best is not None:
            self.best_text.content = f"Best so far: {describe(run.best, self.app.state.reference)}"


def curve_data(run: RunState) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(evaluation, best score so far on the common scale, stage number 1..) for the plot."""
    c = np.asarray(run.best_curve, dtype=np.float64)
    if run.history:
        h = np.asarray(run.history, dtype=np.float64)
        k = np.clip(np.searchsorted(h[:, 0], c[:, 0], side="right") - 1, 0, len(h) - 1)
        stage = h[k, 3] + 1.0
    else:
        stage = np.ones(len(c))
    return c[:, 0], np.maximum.accumulate(c[:, 1]), stage
