"""Before / after: the seed and the result overlays of the selected scene, side by side or
with a swipe or blend control (a tab of the overlay panel)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..browser_js import hide_inputs, pointer_marker
from ..context import Workbench
from ..exact import parse_number
from ..overlay import COMPARE_MODES, compose_before_after
from ..state import Snapshot
from ..text import change, score_num

if TYPE_CHECKING:
    from .overlay_view import OverlayPanel

NO_RESULT = "No result yet: run the optimisation (Optimise tab) to compare the seed with the result."


class ComparePanel:
    def __init__(self, app: Workbench, overlay: "OverlayPanel") -> None:
        self.app = app
        self.overlay = overlay
        gui = app.server.gui
        cam = app.camera
        with overlay.compare_tab:
            self.caption = gui.add_markdown(NO_RESULT)
            gui.add_html(pointer_marker("Compare pointer", drag=True))
            self.image = gui.add_image(np.zeros((cam.height // 2, cam.width, 3), np.uint8), format="jpeg",
                                       jpeg_quality=85, visible=False)
            self.mode = gui.add_dropdown("Compare", COMPARE_MODES, initial_value="swipe",
                                        hint="swipe: drag on the image, seed left of the line and result right of it")
            self.amount = gui.add_slider("Swipe / blend", 0.0, 1.0, 0.01, 0.5,
                                         hint="Swipe: where the seed ends and the result begins; blend: share of the result")
            self.pointer = gui.add_text("Compare pointer", "", hint="(set by clicks and drags on the image)")
            gui.add_html(hide_inputs([self.pointer]))
        self.pointer.on_update(self._on_pointer)
        self.mode.on_update(lambda _: app.compare_changed())
        self.amount.on_update(lambda _: app.compare_changed())
        self.frames = 0

    def _on_pointer(self, event) -> None:
        """Drag (or click) on the image: the swipe line or the blend follows the pointer's x."""
        parts = str(self.pointer.value).split(",")
        fx = parse_number(parts[0]) if parts else None
        if event.client is None or fx is None or self.mode.value == "side by side":
            return
        self.amount.value = float(np.clip(round(fx, 3), 0.0, 1.0))  # runs the amount's callback

    def compose(self, snap: Snapshot, mode: str | None = None, scale: float = 0.5,
                width: int | None = None) -> np.ndarray | None:
        """The before/after image of the selected scene, or None without a result: ``width``
        pixels wide as the panel shows it (points at their screen size), else from overlays at
        map resolution, side by side at ``scale``."""
        result = snap.result
        if result is None:
            return None
        style = self.overlay.style()
        mode = mode or self.mode.value
        each = None if width is None else max(1, width // 2 if mode == "side by side" else width)
        before = self.overlay.draw(snap.selected, result.seed, style, each, screen_width=each)
        after = self.overlay.draw(snap.selected, snap.accepted, style, each, screen_width=each)  # "result": what Accept sets
        return compose_before_after(before, after, mode, float(self.amount.value), 1.0 if each else scale)

    def render(self) -> None:
        snap = self.app.state.snapshot()
        img = self.compose(snap, width=self.overlay.display_width)
        if img is None:
            self.caption.content = NO_RESULT
            self.image.visible = False
            return
        r = snap.result
        name = self.app.state.scene_names[snap.selected]
        label = self.app.readout.label
        # both scored by the readout, like the Seed tab and the Result tab
        everything = [True] * len(self.app.state.scene_names)
        at_seed = self.app.readout.read(r.seed, everything).per_scene[snap.selected]
        at_res = self.app.readout.read(snap.accepted, everything).per_scene[snap.selected]
        held = "" if name in r.scene_names else " (held out of the optimisation)"
        scores = (f"{label} of this scene{held} {score_num(at_seed)} (seed) → {score_num(at_res)} (result, "
                  f"{change(at_res, at_seed)})  \n"
                  f"left/before: the run's seed · right/after, \"result\": {result_words(snap)}")
        self.caption.content = f"**{name}**: {scores}"
        self.image.image = img
        self.image.visible = True
        self.frames += 1


def result_words(snap: Snapshot) -> str:
    """Which transform the "result" side shows: what Accept sets."""
    v = snap.verdict
    if v is None:
        return "the optimiser's answer, not judged"
    if v.seed_stands:
        return "the seed, confirmed (what is handed back: the optimiser's answer is within its own spread of it)"
    if v.settled:
        return f"the optimiser's answer with the seed's {' and '.join(v.from_seed())} (what is handed back)"
    if v.status == "trusted":
        return "the optimiser's answer (trusted)"
    if v.status == "trusted-rotation":
        return "the checked rotation with the seed's translation (what is handed back; the optimiser's translation is not)"
    return "the optimiser's answer, NOT trusted (the saved file keeps the seed)"
