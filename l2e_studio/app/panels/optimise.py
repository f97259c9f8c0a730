"""The optimisation: settings, Start / Cancel, and live progress (bar, MI curve, best pose).

The run itself is :func:`l2e_studio.calibrate.calibrate` in a worker thread (see
:meth:`App.start_run`); this panel only reads settings and shows :class:`RunState`.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

import numpy as np
import viser
import viser.uplot

from ...calibrate import METHODS, CalibrationSettings
from ..pose import describe
from ..state import RunState

if TYPE_CHECKING:
    from ..server import App

IDLE_TEXT = "Idle. Start optimises the included scenes from the current extrinsic."


class OptimisePanel:
    def __init__(self, app: "App") -> None:
        self.app = app
        gui = app.server.gui
        defaults = CalibrationSettings()
        self.method = gui.add_dropdown("Optimiser", METHODS, initial_value=defaults.method,
                                       hint="SLSQP is fastest; L-BFGS-B and Powell are robust")
        self.t_bound = gui.add_number("± translation (m)", defaults.translation_bound, min=0.0, max=2.0, step=0.01,
                                      hint="Search bound per axis around the start, metres")
        self.r_bound = gui.add_number("± rotation (°)", defaults.rotation_bound_deg, min=0.1, max=45.0, step=0.5,
                                      hint="Search bound per axis around the start, degrees")
        self.sigma_in = gui.add_number("Smoothing σ (px)", defaults.sigma, min=0.0, max=50.0, step=0.5,
                                       hint="Gaussian smoothing of the event maps (the paper uses 5 px)")
        self.rotation_only = gui.add_checkbox("Rotation only", defaults.rotation_only,
                                              hint="Keep the translation fixed; search the rotation only")
        self.coarse = gui.add_checkbox("Coarse to fine", defaults.coarse_to_fine,
                                       hint="Start on wider smoothing and fewer points: a wider basin")
        self.start = gui.add_button("Start", color="green", icon=viser.Icon.PLAYER_PLAY)
        self.cancel = gui.add_button("Cancel", color="red", icon=viser.Icon.PLAYER_STOP, disabled=True)
        self.follow = gui.add_checkbox("Overlay follows best", True,
                                       hint="While running, draw the optimiser's best estimate in the overlay")
        self.progress = gui.add_progress_bar(0.0, animated=False)
        self.status = gui.add_markdown(IDLE_TEXT)
        # viser 1.1's client never redraws a uPlot created with empty data, so the plot starts
        # with one placeholder point and stays hidden until a run has history.
        self.plot = gui.add_uplot(
            (np.zeros(1), np.zeros(1), np.zeros(1)),
            (
                viser.uplot.Series(label="evaluation"),
                viser.uplot.Series(label="MI", stroke="#1c7ed6", width=1),
                viser.uplot.Series(label="best", stroke="#e8590c", width=2),
            ),
            title="MI vs evaluation",
            scales={"x": viser.uplot.Scale(time=False, auto=True), "y": viser.uplot.Scale(auto=True)},
            aspect=1.6,
            visible=False,
        )
        self.best_text = gui.add_markdown("")
        self.start.on_click(self._on_start)
        self.cancel.on_click(lambda event: app.cancel_run())
        self.follow.on_update(lambda _: (app.state.set_follow_best(self.follow.value), app.overlay_worker.poke()))
        self.sigma_in.on_update(lambda _: app.sigma_changed(self.sigma()))

    def sigma(self) -> float:
        return float(self.sigma_in.value)

    def settings(self) -> CalibrationSettings:
        return CalibrationSettings(
            method=self.method.value,
            translation_bound=float(self.t_bound.value),
            rotation_bound_deg=float(self.r_bound.value),
            sigma=self.sigma(),
            rotation_only=bool(self.rotation_only.value),
            coarse_to_fine=bool(self.coarse.value),
        )

    def _on_start(self, event) -> None:
        try:
            self.app.start_run(self.settings())
        except (RuntimeError, ValueError) as exc:
            self.app.notify(event.client, "Cannot start", str(exc), color="red")

    def show_running(self, running: bool) -> None:
        self.start.disabled = running
        self.cancel.disabled = not running
        for handle in (self.method, self.t_bound, self.r_bound, self.sigma_in, self.rotation_only, self.coarse):
            handle.disabled = running
        self.progress.animated = running

    def show_progress(self, run: RunState) -> None:
        self.progress.value = float(np.clip(100.0 * run.fraction, 0.0, 100.0))
        if run.history:
            h = np.asarray(run.history, dtype=np.float64)
            self.plot.data = (h[:, 0], h[:, 1], h[:, 2])
            self.plot.visible = True
        elapsed = (run.finished or time.time()) - run.started if run.started else 0.0
        stage = f"stage {run.stage + 1}/{run.stages} · " if run.stages else ""
        words = {"running": "Running", "done": "Finished", "cancelled": "Cancelled", "failed": "Failed", "idle": "Idle"}
        text = (f"**{words[run.status]}** · {stage}{run.evaluations} evaluations · {elapsed:.1f} s  \n"
                f"objective MI {run.mi:.4f} · best {run.best_mi:.4f}")
        if run.error:
            text += f"  \n{run.error}"
        self.status.content = text
        if run.best is not None:
            self.best_text.content = f"Best so far: {describe(run.best, self.app.state.reference)}"
