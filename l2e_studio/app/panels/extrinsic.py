"""The seed extrinsic: six sliders with number fields, a step size, reset / load / save, and
the live MI readout of the selected scene and of the included scenes."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import viser

from ...errors import InputError
from ...geometry import Extrinsic
from ..files import save_seed, seed_document, seed_from_upload
from ..pose import SLIDER_NAMES, describe, extrinsic_from_sliders, sliders_from_extrinsic
from ..readout import MiReading
from ..state import Snapshot

if TYPE_CHECKING:
    from ..server import App

#: Step choices: (metres, degrees).
STEPS = {
    "coarse: 1 cm / 1°": (0.01, 1.0),
    "fine: 1 mm / 0.1°": (0.001, 0.1),
    "finest: 0.1 mm / 0.01°": (0.0001, 0.01),
}
TRANSLATION_RANGE = 0.5  # m either side of the file seed (re-centred when a value leaves it)
ROTATION_RANGE = 30.0  # deg either side of zero correction

HELP = (
    "x, y, z: translation of T_cam_lidar (m, camera frame). roll, pitch, yaw: correction to the "
    "file seed's rotation (deg) about the camera's forward / left / up axes."
)


class ExtrinsicPanel:
    def __init__(self, app: "App") -> None:
        self.app = app
        gui = app.server.gui
        self.reference = app.state.reference
        values = sliders_from_extrinsic(app.state.reference, self.reference)
        gui.add_markdown(HELP)
        self.step = gui.add_dropdown("Step", tuple(STEPS), initial_value="fine: 1 mm / 0.1°")
        self.sliders: list[viser.GuiSliderHandle] = []
        for i, name in enumerate(SLIDER_NAMES):
            if i < 3:
                c = float(self.reference.translation[i])
                s = gui.add_slider(f"{name} (m)", round(c - TRANSLATION_RANGE, 2), round(c + TRANSLATION_RANGE, 2),
                                   0.001, float(values[i]), hint=f"T_cam_lidar translation {name}, metres")
            else:
                s = gui.add_slider(f"{name} (°)", -ROTATION_RANGE, ROTATION_RANGE, 0.1, float(values[i]),
                                   hint=f"{name} correction to the file seed, degrees")
            s.on_update(self._on_slider)
            self.sliders.append(s)
        self.readout = gui.add_markdown("MI: computing...")
        self.pose_text = gui.add_markdown("")
        self.reset = gui.add_button("Reset to file seed", icon=viser.Icon.ARROW_BACK_UP,
                                    hint=f"Back to the seed read from {app.scene_set.seed_source or 'the scene folder'}")
        self.load = gui.add_upload_button("Load seed file", icon=viser.Icon.UPLOAD,
                                          hint="camera.yaml, result file, config.json, 4x4 matrix ...")
        self.save = gui.add_button("Save seed", icon=viser.Icon.DEVICE_FLOPPY,
                                   hint="Write the current extrinsic as a seed file in the results folder")
        self.step.on_update(lambda _: self._apply_step())
        self.reset.on_click(lambda event: app.set_extrinsic(app.state.reset_extrinsic(), source="reset"))
        self.load.on_upload(self._on_upload)
        self.save.on_click(self._on_save)
        self._apply_step()

    # --- events ---------------------------------------------------------------------------
    def _on_slider(self, event) -> None:
        if event.client is None:  # our own programmatic update
            return
        values = np.array([s.value for s in self.sliders], dtype=np.float64)
        self.app.set_extrinsic(extrinsic_from_sliders(values, self.reference), source="sliders")

    def _apply_step(self) -> None:
        metres, degrees = STEPS[self.step.value]
        for i, s in enumerate(self.sliders):
            s.step = metres if i < 3 else degrees
            s.precision = 4 if i < 3 and metres < 0.001 else (3 if i < 3 else (2 if degrees < 0.1 else 1))

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
            path = save_seed(self.app.out_dir, ext)
        except OSError as exc:
            self.app.notify(event.client, "Seed not saved", f"{self.app.out_dir}: {exc}", color="red")
            return
        if event.client is not None:
            event.client.send_file_download(path.name, seed_document(ext))
        self.app.notify(event.client, "Seed saved", str(path), color="green")

    # --- refresh from the state ------------------------------------------------------------
    def show(self, extrinsic: Extrinsic) -> None:
        """Move the sliders to ``extrinsic`` (widening a slider's range if it falls outside)."""
        current = np.array([s.value for s in self.sliders], dtype=np.float64)
        values = sliders_from_extrinsic(extrinsic, self.reference, near=current)
        for s, v in zip(self.sliders, values):
            if not s.min <= v <= s.max:
                half = (s.max - s.min) / 2
                s.min, s.max = float(np.floor((v - half) * 100) / 100), float(np.ceil((v + half) * 100) / 100)
            s.value = float(v)

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
            f"**MI · {name}: {reading.per_scene[snap.selected]:.4f}**  \n"
            f"**MI · {n_in} included scenes: {reading.total:.4f}** "
            f"({delta:+.4f} vs file seed)"
        )
