"""The seed extrinsic: six sliders with number fields, a step size, reset / load / save, and
the live MI readout of the selected scene and of the included scenes."""

from __future__ import annotations

import numpy as np
import viser

from ..context import Workbench
from ...errors import InputError
from ...geometry import Extrinsic
from ..browser_js import KEY_HANDLING_HTML, hide_slider_boxes
from ..checks import check_seed_value
from ..exact import centred_range, format_value, is_partial, nudged, parse_number
from ..files import save_seed, seed_document, seed_from_upload
from ..pose import SLIDER_NAMES, describe, extrinsic_from_sliders, sliders_from_extrinsic
from ..readout import MiReading
from ..state import Snapshot
from ..text import change, score_num

#: Step choices: (metres, degrees).
STEPS = {
    "coarse: 1 cm / 1°": (0.01, 1.0),
    "fine: 1 mm / 0.1°": (0.001, 0.1),
    "finest: 0.1 mm / 0.01°": (0.0001, 0.01),
}
SLIDER_PRECISION = 9  # decimals the sliders keep: never rounded to a grid

HELP = (
    "x, y, z: translation of T_cam_lidar (m, camera frame). roll, pitch, yaw: correction to the "
    "file seed's rotation (deg) about the camera's forward / left / up axes. Type or paste exact "
    "values in the = fields; − / + nudge by one step; sliders span ±100 steps around the value."
)


def _step_label(delta: float, rotation: bool) -> str:
    if rotation:
        return f"{format_value(delta, 3)}°"
    return f"{format_value(delta * 1000, 3)} mm"


class ExtrinsicPanel:
    def __init__(self, app: Workbench) -> None:
        self.app = app
        gui = app.server.gui
        self.reference = app.state.reference
        self.values = sliders_from_extrinsic(app.state.reference, self.reference)
        self.readout = gui.add_markdown(f"{app.readout.label}: computing...")  # on top: visible while nudging at 1366x768
        self.step = gui.add_dropdown("Step", tuple(STEPS), initial_value="fine: 1 mm / 0.1°")
        self.history = gui.add_button_group("Edit", ("Undo", "Redo"),
                                            hint="Undo / redo extrinsic changes (Ctrl+Z, Ctrl+Shift+Z)")
        self.sliders: list[viser.GuiSliderHandle] = []
        self.fields: list[viser.GuiTextHandle] = []
        self.nudges: list[viser.GuiButtonGroupHandle] = []
        self.problems: list[viser.GuiMarkdownHandle] = []  # a refused typed value, said beside its field
        for i, name in enumerate(SLIDER_NAMES):
            unit = "m" if i < 3 else "°"
            what = f"T_cam_lidar translation {name}, metres" if i < 3 else f"{name} correction to the file seed, degrees"
            s = gui.add_slider(f"{name} ({unit})", float(self.values[i]) - 1, float(self.values[i]) + 1, 0.001,
                               float(self.values[i]), hint=what + " (drag: ±100 steps)")
            s.precision = SLIDER_PRECISION
            f = gui.add_text(f"{name} =", format_value(self.values[i]), hint=what + ": type or paste an exact value")
            self.problems.append(gui.add_markdown("", visible=False))
            b = gui.add_button_group(f"{name} ±", ("−", "+"), hint=f"Nudge {name} by one step")
            s.on_update(lambda event, i=i: self._on_slider(event, i))
            f.on_update(lambda event, i=i: self._on_typed(event, i))
            b.on_click(lambda event, i=i: self._on_nudge(event, i))
            self.sliders.append(s)
            self.fields.append(f)
            self.nudges.append(b)
        gui.add_html(hide_slider_boxes([s._impl.uuid for s in self.sliders]) + KEY_HANDLING_HTML)
        self.pose_text = gui.add_markdown("")
        self.reset = gui.add_button("Reset to file seed", icon=viser.Icon.ARROW_BACK_UP,
                                    hint=f"Back to the seed read from {app.scene_set.seed_source or 'the scene folder'}")
        self.load = gui.add_upload_button("Load seed file", icon=viser.Icon.UPLOAD,
                                          hint="camera.yaml, result file, config.json, 4x4 matrix ...")
        self.save = gui.add_button("Save seed", icon=viser.Icon.DEVICE_FLOPPY,
                                   hint="Write the current extrinsic as a seed file in the results folder")
        gui.add_markdown(HELP)
        self.step.on_update(lambda _: self._apply_step())
        self.history.on_click(lambda event: app.undo() if self.history.value == "Undo" else app.redo())
        self.reset.on_click(lambda event: app.set_extrinsic(app.state.reset_extrinsic(), source="reset"))
        self.load.on_upload(self._on_upload)
        self.save.on_click(self._on_save)
        self._apply_step()

    # --- events ---------------------------------------------------------------------------
    def step_of(self, i: int) -> float:
        metres, degrees = STEPS[self.step.value]
        return metres if i < 3 else degrees

    def _set_value(self, i: int, value: float, source: str) -> None:
        """Axis ``i`` takes exactly ``value``; the others keep theirs."""
        values = self.values.copy()
        values[i] = value
        self.app.set_extrinsic(extrinsic_from_sliders(values, self.reference), source=source, values=values)

    def _on_slider(self, event, i: int) -> None:
        if event.client is None:  # our own programmatic update
            return
        self._set_value(i, float(self.sliders[i].value), "sliders")

    def _on_typed(self, event, i: int) -> None:
        """A typed value is checked like the Optimise fields: refused (the state keeps its value,
        said beside the field) unless it is a number within the axis' range."""
        if event.client is None:
            return
        text = self.fields[i].value
        checked = check_seed_value(text, SLIDER_NAMES[i], rotation=i >= 3)
        if checked.value is None:
            partial = is_partial(text)
            self._show_problem(i, "" if partial else f"{checked.problem}; the value stays {format_value(self.values[i])}")
            return
        self._show_problem(i, "")
        if checked.value != self.values[i]:
            self._set_value(i, checked.value, "typed")

    def _on_nudge(self, event, i: int) -> None:
        sign = -1.0 if self.nudges[i].value.startswith("−") else 1.0
        self._set_value(i, nudged(self.values[i], sign * self.step_of(i)), "nudge")

    def _show_problem(self, i: int, text: str) -> None:
        note = self.problems[i]
        content = f"⚠ {text}" if text else ""
        if note.content != content:
            note.content = content
        if note.visible != bool(text):
            note.visible = bool(text)

    def _apply_step(self) -> None:
        for i, s in enumerate(self.sliders):
            s.step = self.step_of(i)
            label = _step_label(self.step_of(i), rotation=i >= 3)
            self.nudges[i].options = (f"− {label}", f"+ {label}")
        self._centre_sliders()

    def _centre_sliders(self) -> None:
        """Each slider spans ±100 steps around its value (so it narrows with the step)."""
        for i, s in enumerate(self.sliders):
            lo, hi = centred_range(self.values[i], self.step_of(i), rotation=i >= 3)
            s.min, s.max = lo, hi
            s.value = float(self.values[i])

    def _on_upload(self, event) -> None:
        upload = self.load.value
        try:
            ext = seed_from_upload(upload.name, upload.content)
        except InputError as exc:
            self.app.notify(event.client, "Seed not loaded", str(exc), color="red")
            return
        self.app.set_extrinsic(ext, source="file")
        self.app.notify(event.client, "Seed loaded", f"{upload.name}: the sliders now show it.", color="green")

    def _on_save(self, event) -> None:
        ext = self.app.state.snapshot().extrinsic
        try:
            path = save_seed(self.app.out_dir, ext, self.app.current_pairs())
        except OSError as exc:
            self.app.notify(event.client, "Seed not saved", f"{self.app.out_dir}: {exc}", color="red")
            return
        if event.client is not None:
            event.client.send_file_download(path.name, seed_document(ext, pairs=self.app.current_pairs()))
        self.app.notify(event.client, "Seed saved", str(path), color="green")

    # --- refresh from the state ------------------------------------------------------------
    def show(self, extrinsic: Extrinsic, values: np.ndarray | None = None, source: str = "") -> None:
        """Show ``extrinsic``: exact ``values`` when the change came from this panel, else derived.

        The field being typed in is left alone (rewriting it would fight the keyboard), and a
        slider being dragged keeps its range; every other change re-centres the sliders and
        rewrites every field, a refused one included (its warning goes with its text).
        """
        if values is None:
            values = sliders_from_extrinsic(extrinsic, self.reference, near=self.values)
        self.values = np.asarray(values, dtype=np.float64).copy()
        for i, f in enumerate(self.fields):
            if source == "typed" and parse_number(f.value) == self.values[i]:
                continue
            self._show_problem(i, "")
            f.value = format_value(self.values[i])
        if source == "sliders":
            return
        self._centre_sliders()

    def show_pose_text(self, extrinsic: Extrinsic) -> None:
        err_deg, err_m = self.reference.error_to(extrinsic)
        self.pose_text.content = (
            f"{describe(extrinsic, self.reference)}  \n"
            f"{err_deg:.3f}° / {100 * err_m:.2f} cm from the file seed · "
            f"rotvec = ({', '.join(f'{a:.5f}' for a in extrinsic.rotvec)}) rad"
        )

    def show_mi(self, reading: MiReading, snap: Snapshot, reference_mi: float) -> None:
        name = self.app.state.scene_names[snap.selected]
        n_in = sum(snap.included)
        delta = reading.total - reference_mi
        self.readout.content = (
            f"**{self.app.readout.label} · {name}: {score_num(reading.per_scene[snap.selected])}**  \n"
            f"**{self.app.readout.label} · {n_in} included scenes: {score_num(reading.total)}** "
            f"({score_num(delta, signed=True)}, {change(reading.total, reference_mi)} vs file seed)"
        )
