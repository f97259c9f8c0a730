"""The overlay panel (docked left): the selected scene's event map with the lidar points
projected at the current extrinsic, and the display controls."""

from __future__ import annotations

import cv2
import numpy as np

from ..context import Workbench
from ..display import MAP_MODES
from ..overlay import COLOR_MODES, OverlayStyle, render_overlay
from ..readout import MiReading
from ..state import Snapshot
from ..text import num

JPEG_QUALITY = 80
DISPLAY_WIDTH = 640  # px: about the overlay's width on the page at 1366x768 (previews are sent at this size)
PREVIEW_JPEG_QUALITY = 50  # a moving preview: ~60 KB per update per tab; the frame at rest uses JPEG_QUALITY
PANEL_WIDTH = 760  # px; the 3D view takes what is left between this panel and the controls


def display_sized(image: np.ndarray, width: int = DISPLAY_WIDTH) -> np.ndarray:
    """``image`` shrunk to ``width`` pixels wide (area averaging); unchanged when not wider."""
    h, w = image.shape[:2]
    if w <= width:
        return image
    return cv2.resize(image, (width, max(1, round(h * width / w))), interpolation=cv2.INTER_AREA)


class OverlayPanel:
    """A dockable panel with two tabs: the live overlay and (filled by ComparePanel) before/after."""

    def __init__(self, app: Workbench) -> None:
        self.app = app
        gui = app.server.gui
        cam = app.camera
        self.panel = gui.add_panel()
        self.frames = 0
        self.full_frame = True  # whether the last frame sent was full size
        with self.panel.add_tab("Overlay"):
            # Stretch the overlay images to the panel's width (viser shows images at most at
            # their own size; small maps would otherwise stay small).
            gui.add_html("<style>img[src^='blob:'] { width: 100% !important; }</style>")
            self.caption = gui.add_markdown("Loading...")
            self.image = gui.add_image(
                np.zeros((cam.height, cam.width, 3), np.uint8), format="jpeg", jpeg_quality=JPEG_QUALITY
            )
            with gui.add_folder("Display"):
                self.color_by = gui.add_dropdown("Colour by", COLOR_MODES, initial_value="intensity",
                                                 hint="Colour the lidar points by their intensity or their depth")
                self.point_size = gui.add_slider("Point size", 1, 8, 1, 2, hint="Disc diameter in pixels")
                self.opacity = gui.add_slider("Opacity", 0.0, 1.0, 0.05, 0.8,
                                              hint="Lower it to see the event map through the points")
                self.contrast = gui.add_slider("Contrast", 0.2, 6.0, 0.1, 1.0, hint="Brightens the event map")
                self.map_mode = gui.add_dropdown(
                    "Map", MAP_MODES, initial_value="raw",
                    hint="raw: the accumulated map as recorded; smoothed: clipped and blurred as the MI sees it",
                )
        self.compare_tab = self.panel.add_tab("Before / after")
        for handle in (self.color_by, self.point_size, self.opacity, self.contrast, self.map_mode):
            handle.on_update(lambda _: app.display_changed())
        self.panel.dock_left()
        self.panel.set_width(PANEL_WIDTH)

    def style(self) -> OverlayStyle:
        return OverlayStyle(
            color_by=self.color_by.value,
            point_size=int(self.point_size.value),
            opacity=float(self.opacity.value),
            contrast=float(self.contrast.value),
        )

    def base_image(self, index: int, style: OverlayStyle) -> np.ndarray:
        sigma = self.app.readout.sigma
        return self.app.displays[index].base(style.contrast, self.map_mode.value, sigma)

    def draw(self, index: int, extrinsic, style: OverlayStyle | None = None) -> np.ndarray:
        """The overlay of scene ``index`` at ``extrinsic`` as an RGB array."""
        style = style or self.style()
        disp = self.app.displays[index]
        colors = disp.colors() if style.color_by == "intensity" else None
        return render_overlay(self.base_image(index, style), disp.scene.points, extrinsic, self.app.camera, style, colors)

    def render(self, snap: Snapshot, full: bool = True) -> None:
        """Draw the overlay; ``full=False`` sends a display-sized preview (while controls move)."""
        image = self.draw(snap.selected, snap.shown_extrinsic)
        # viser 1.1 has no public per-frame quality; its handle reads this attribute when encoding
        self.image._jpeg_quality = JPEG_QUALITY if full else PREVIEW_JPEG_QUALITY
        self.image.image = image if full else display_sized(image)
        self.full_frame = full
        self.frames += 1

    def show_caption(self, snap: Snapshot, reading: MiReading | None) -> None:
        name = self.app.state.scene_names[snap.selected]
        mi = "" if reading is None else f" · MI {num(reading.per_scene[snap.selected])}"
        if snap.showing_result and snap.result is not None and not snap.run.active:
            mi += " at your extrinsic"  # the reading is of the current extrinsic, not of the result shown
        note = ""
        if snap.run.active and snap.follow_best:
            note = " · showing the optimiser's best estimate"
        elif snap.showing_result and snap.result is not None:
            note = " · showing the last run's result: accept it in Result, or change the extrinsic to see yours"
        elif snap.result is not None and not np.allclose(snap.result.extrinsic.params, snap.extrinsic.params):
            note = " · a result is waiting: compare it in Before / after, accept it in Result"
        self.caption.content = f"**{name}**{mi}{note}"
