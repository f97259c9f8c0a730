"""The QA tab: held-out table with guardrails, a repeatability study running in the background
(progress, cancel, a plot that streams as runs finish), exports as browser downloads, and the
HTML report -- all over the engine functions of :mod:`l2e_studio.qa`."""

from __future__ import annotations

import datetime as _dt
import threading
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import viser

from ...calibrate import CalibrationSettings, stack_scenes
from ...errors import InputError
from ...export import EXPORT_FORMATS, export_text, result_to_dict
from ...qa import AXES, guardrails
from ...qa.heldout import Candidate, score
from ...qa.studies import StackSource, check_study_args, repeatability_specs, study

if TYPE_CHECKING:
    from ..context import Workbench


class QAPanel:
    def __init__(self, app: "Workbench") -> None:
        self.app = app
        gui = app.server.gui
        self._cancel: threading.Event | None = None
        self._thread: threading.Thread | None = None
        self.score_btn = gui.add_button("Score seed / current / result", icon=viser.Icon.TABLE,
                                        hint="The paper's MI per scene; scenes not used in optimisation are held out")
        self.table = gui.add_markdown("")
        self.n_runs = gui.add_number("Study runs", 8, min=1, max=500, step=1)
        self.noise_m = gui.add_number("Seed noise (m, +-)", 0.05, min=0.0, max=1.0, step=0.005)
        self.noise_deg = gui.add_number("Seed noise (deg, +-)", 2.0, min=0.0, max=30.0, step=0.1)
        self.run_btn = gui.add_button("Run repeatability study", icon=viser.Icon.PLAYER_PLAY)
        self.cancel_btn = gui.add_button("Cancel study", icon=viser.Icon.PLAYER_STOP, disabled=True)
        self.progress = gui.add_progress_bar(0.0, animated=False)
        self.plot = gui.add_uplot(
            (np.zeros(1), np.zeros(1), np.zeros(1)),
            (viser.uplot.Series(label="run"),
             viser.uplot.Series(label="rotation change (deg)", stroke="#1c7ed6", width=2),
             viser.uplot.Series(label="translation change (cm)", stroke="#e8590c", width=2)),
            title="Study: results vs the centre", aspect=1.6,
            scales={"x": viser.uplot.Scale(time=False, auto=True), "y": viser.uplot.Scale(auto=True)}, visible=False)
        self.study_text = gui.add_markdown("")
        self.fmt = gui.add_dropdown("Export format", tuple(EXPORT_FORMATS), initial_value="ros2")
        self.export_btn = gui.add_button("Download export", icon=viser.Icon.DOWNLOAD,
                                         hint="The result (or the current extrinsic when there is none)")
        self.report_btn = gui.add_button("Write HTML report", icon=viser.Icon.FILE_TEXT,
                                         hint=f"A self-contained report of the result, written into {app.out_dir}")
        self.report_text = gui.add_markdown("")
        self.score_btn.on_click(lambda event: self.score_now())
        self.run_btn.on_click(lambda event: self.start_study())
        self.cancel_btn.on_click(lambda event: self._cancel.set() if self._cancel else None)
        self.export_btn.on_click(self._on_export)
        self.report_btn.on_click(self._on_report)

    # --- held-out table ----------------------------------------------------------------------------
    def _settings(self) -> CalibrationSettings:
        try:
            return self.app.run_settings()
        except Exception:
            return CalibrationSettings(edge_gradient=self.app.edge_gradient)

    def score_now(self):
        snap = self.app.state.snapshot()
        ss = self.app.scene_set
        settings = self._settings()
        stack = stack_scenes(ss.scenes, ss.camera, ss.seed, settings)
        cands = [Candidate("seed", ss.seed), Candidate("current", snap.extrinsic)]
        if snap.result is not None:
            cands.append(Candidate("result", snap.result.extrinsic))
        held = ~np.array(snap.included, dtype=bool)
        table = score(stack, cands, None, held)
        names = [c.name for c in cands]
        lines = ["| scene | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
        for row in table.rows():
            lines.append("| " + " | ".join(row) + " |")
        warns = guardrails.held_out_below_seed(table, result="result" if snap.result is not None else "current")
        ri = names.index("result" if snap.result is not None else "current")
        warns += (guardrails.few_points(table.scenes, table.points_in_image[ri]) + guardrails.few_scenes(int((~held).sum()))
                  + guardrails.few_places(stack.places[~held]))
        lines += [""] + [f"- **{w.code}**: {w.message}" for w in warns]
        self.table.content = "\n".join(lines)
        return table

    # --- repeatability study ---------------------------------------------------------------------------
    def start_study(self) -> threading.Thread | None:
        if self._thread is not None and self._thread.is_alive():
            return None
        n, nm, nd = int(self.n_runs.value), float(self.noise_m.value), float(self.noise_deg.value)
        try:
            check_study_args(n, nm, nd, ["SLSQP"])
        except InputError as exc:
            self.study_text.content = f"**Not started:** {exc}"
            return None
        ss = self.app.scene_set
        centre = self.app.state.snapshot().extrinsic
        cam = Path(ss.camera_source) if ss.camera_source and Path(ss.camera_source).is_file() else None
        source = StackSource(folder=str(ss.root), camera_file=str(cam) if cam else None)
        specs = repeatability_specs(centre, n, nm, nd, ["SLSQP"], len(ss.scenes))
        self._cancel = threading.Event()
        self.cancel_btn.disabled = False
        self.run_btn.disabled = True
        self.progress.value = 0.0
        rows: list[tuple[float, float]] = []

        def on_progress(done: int, total: int, run: dict) -> None:
            from ...geometry import Extrinsic

            deg, m = centre.error_to(Extrinsic.from_matrix(np.array(run["result_T"])))
            rows.append((deg, 100 * m))
            self.progress.value = 100.0 * done / total
            x = np.arange(1, len(rows) + 1, dtype=float)
            self.plot.data = (x, np.array([r[0] for r in rows]), np.array([r[1] for r in rows]))
            self.plot.visible = True
            self.study_text.content = f"{done}/{total} runs finished"

        def work() -> None:
            try:
                res = study("repeatability", source, centre, self._settings(), specs, nm, nd,
                            workers=1, on_progress=on_progress, cancel=self._cancel)
                s = res.summary()["methods"].get("SLSQP")
                if s:
                    head = "| | " + " | ".join(AXES) + " |\n|---|" + "---|" * 6
                    mean = "| mean | " + " | ".join(f"{s['mean'][a]:.3f}" for a in AXES) + " |"
                    std = "| std | " + " | ".join(f"{s['std'][a] if s['std'][a] is not None else float('nan'):.3f}" for a in AXES) + " |"
                    self.study_text.content = (f"{len(res.runs)} runs{' (cancelled)' if res.cancelled else ''}, "
                                               f"{res.wall_seconds:.1f} s, run time {s['seconds_mean']:.2f} s each; "
                                               f"relative to the current extrinsic (mm, deg)\n\n{head}\n{mean}\n{std}")
                else:
                    self.study_text.content = "Cancelled before any run finished."
                self.last_study = res
            except Exception as exc:  # shown, never raised into the GUI thread
                self.study_text.content = f"**Study failed:** {exc}"
            finally:
                self.cancel_btn.disabled = True
                self.run_btn.disabled = False

        self._thread = threading.Thread(target=work, name="l2e-qa-study", daemon=True)
        self._thread.start()
        return self._thread

    # --- exports and the report --------------------------------------------------------------------------
    def export_document(self, fmt: str) -> tuple[str, bytes]:
        """The last result as the saved file hands it back (the verdict's extrinsic, its status in
        the header), or the current extrinsic (no verdict) without a result."""
        snap = self.app.state.snapshot()
        ext = snap.handed_back if snap.result is not None else snap.extrinsic
        result = (result_to_dict(snap.result, self.app.camera, verdict=snap.verdict,
                                 judging_cancelled=snap.judging_cancelled) if snap.result is not None else None)
        return f"T_cam_lidar{EXPORT_FORMATS[fmt]}", export_text(ext, fmt, result=result).encode()

    def _on_export(self, event) -> None:
        name, data = self.export_document(self.fmt.value)
        event.client.send_file_download(name, data)

    def write_report(self) -> Path:
        from ...atomic import atomic_write_bytes
        from ...qa.report import ReportInputs, build, settings_from_result

        snap = self.app.state.snapshot()
        if snap.result is None:
            raise RuntimeError("there is no result to report on: run the optimisation first")
        ss = self.app.scene_set
        doc = result_to_dict(snap.result, self.app.camera, ss.root, verdict=snap.verdict,
                             judging_cancelled=snap.judging_cancelled)
        held = ~np.array(snap.included, dtype=bool)
        stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
        path = self.app.out_dir / f"l2e_report_{stamp}.html"
        inp = ReportInputs(ss, doc, path.with_suffix(".yaml"), settings_from_result(doc), snap.result.seed,
                           snap.handed_back, held_out=held)
        page, _ = build(inp)
        atomic_write_bytes(path, page.encode(), keep_existing=True)
        return path

    def _on_report(self, event) -> None:
        try:
            path = self.write_report()
        except (InputError, OSError, RuntimeError) as exc:
            self.app.notify(event.client, "Report not written", str(exc), color="red")
            return
        self.report_text.content = f"Report written to `{path}`"
        self.app.notify(event.client, "Report written", str(path), color="green")
        event.client.send_file_download(path.name, path.read_bytes())
