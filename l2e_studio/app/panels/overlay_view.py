"""The overlay panel (docked left): the selected scene's event map with the lidar points
projected at the current extrinsic, and the display controls."""

from __future__ import annotations

import cv2
import numpy as np

from ..context import Workbench
from ..browser_js import hide_inputs, pointer_marker
from ..display import MAP_MODES
from ..exact import parse_number
from ..inspect import ZOOMS, Window, cropped, depth_range, edge_view, legend_html, zoom_window
from ..overlay import (COLOR_MODES, OverlayStyle, default_color_by, default_point_size, encode_jpeg, project_scene,
                       render_view)
from ..readout import MiReading
from ..state import Snapshot
from ..text import score_num

DISPLAY_WIDTH = 640  # px: previews are at most this wide; frames at rest take the panel's width
FRAME_BYTES = 60_000  # at most this much per update per tab (what an SSH tunnel carries in a blink)
REST_QUALITIES = (92, 85, 78, 70, 62, 55, 48, 40)  # the frame at rest: the best of these within FRAME_BYTES
PREVIEW_QUALITIES = (50, 40, 30)  # while a control moves: fast, and within FRAME_BYTES
PANEL_WIDTH = 760  # px at start; then from the window's width (see ``panel_layout``)
CONTROLS_PX = 400  # about the width of the controls docked right (control_width="large")
MIN_3D_PX = 220  # what the 3D view keeps between the overlay and the controls
MIN_PANEL_PX = 640  # the overlay panel never narrower than this
MAX_PANEL_SHARE = 0.6  # of the window's width
PICKING_SHARE = 0.45  # of what the controls leave, while picking pairs: the 3D view gets the rest
MIN_PICKING_PX = 360


def panel_layout(window_width: int, picking: bool = False) -> tuple[int, int]:
    """(overlay panel width, frame width) in CSS px for a window ``window_width`` wide: the
    overlay gets what the controls and a usable 3D view leave, up to 60 % of the window; while
    picking pairs, a bit less than half of what the controls leave (the 3D view is where the
    points are picked: at 1366 px it gets ~530 px instead of ~220)."""
    window_width = min(max(int(window_width), 320), 8192)
    if picking:
        panel = max(MIN_PICKING_PX, int(PICKING_SHARE * (window_width - CONTROLS_PX)))
        return panel, panel - 24
    panel = int(min(window_width - CONTROLS_PX - MIN_3D_PX, MAX_PANEL_SHARE * window_width))
    panel = max(MIN_PANEL_PX, panel)
    return panel, max(480, panel - 24)


VIEWS = ("overlay", "edges")
#: A zoomed window is magnified without smoothing (also where the browser scales the frame).
IMAGE_CSS = {
    "fit": "<style>img[src^='blob:'] { width: 100% !important; }</style>",
    "zoomed": "<style>img[src^='blob:'] { width: 100% !important; image-rendering: pixelated; }</style>",
}
EDGE_LEGEND = ("<div style='font-size:0.75em;padding:0 0.5em'><span style='color:#00c8ff'>■</span> map edges · "
               "<span style='color:#ff00c8'>■</span> depth edges of the projected points · "
               "<span style='color:#999'>■</span> white: both (aligned)</div>")


def _pair(text: str) -> tuple[float, float] | None:
    """``"x, y"`` -> (x, y), or None."""
    parts = str(text).replace(";", ",").split(",")
    if len(parts) < 2:
        return None
    a, b = parse_number(parts[0]), parse_number(parts[1])
    return None if a is None or b is None else (a, b)


def jpeg_within(
    image: np.ndarray, max_bytes: int, qualities: tuple[int, ...], width: int | None = None, start: int | None = None
) -> tuple[np.ndarray, bytes, int]:
    """(the image sent, its JPEG, the quality): the best of ``qualities`` (highest first) that
    fits ``max_bytes``, found by bisection (~1-10 ms per encode of a display-sized frame). The
    image is first shrunk to ``width`` (the width that fitted last time: consecutive frames are
    alike); when not even the lowest quality fits, it is shrunk by steps of 0.8 until it does
    (or to 320 px). ``start``: the quality that fitted last time, tried first with its
    neighbour (two encodes instead of three or four when the answer has not moved)."""
    if width is not None:
        image = display_sized(image, width)
    cache: dict[int, bytes] = {}

    def fits(i: int) -> bool:
        if i not in cache:
            cache[i] = encode_jpeg(image, qualities[i])
        return len(cache[i]) <= max_bytes

    while True:
        lo, hi = 0, len(qualities) - 1  # the answer's index lies in [lo, hi] (hi + 1: none fits)
        if start in qualities:
            i = qualities.index(start)
            if fits(i):
                lo, hi = 0, i
                if i > 0 and not fits(i - 1):
                    lo = i
            else:
                lo = i + 1
                if lo < len(qualities) and fits(lo):
                    hi = lo
        while lo < hi:
            mid = (lo + hi) // 2
            if fits(mid):
                hi = mid
            else:
                lo = mid + 1
        if lo < len(qualities) and fits(lo):
            return image, cache[lo], qualities[lo]
        if image.shape[1] <= 320:
            return image, cache[len(qualities) - 1], qualities[-1]
        image = display_sized(image, int(image.shape[1] * 0.8))
        cache.clear()


def display_sized(image: np.ndarray, width: int = DISPLAY_WIDTH) -> np.ndarray:
    """``image`` shrunk to ``width`` pixels wide (area averaging); unchanged when not wider."""
    h, w = image.shape[:2]
    if w <= width:
        return image
    return cv2.resize(image, (width, max(1, round(h * width / w))), interpolation=cv2.INTER_AREA)


def send_jpeg(handle, image: np.ndarray, data: bytes) -> None:
    """Show ``data`` (the JPEG of ``image``) in a viser image element without encoding again.

    viser 1.1 has no public way to send encoded bytes; its image setter encodes the array and
    assigns these two synced properties, which is what this does with bytes already sized to
    the budget."""
    handle._image = image
    handle._format = "jpeg"
    handle._data = data


class OverlayPanel:
    """A dockable panel with two tabs: the live overlay and (filled by ComparePanel) before/after."""

    def __init__(self, app: Workbench) -> None:
        self.app = app
        gui = app.server.gui
        cam = app.camera
        kind = app.scene_set.scenes[0].map_kind if app.scene_set.scenes else "events"
        seen = project_scene(app.scene_set.scenes[0].points, app.state.reference, cam).index.size
        size = default_point_size(seen, PANEL_WIDTH - 24, round((PANEL_WIDTH - 24) * cam.height / cam.width))
        self.panel = gui.add_panel()
        self.frames = 0
        self.rest_frame = True  # whether the last frame sent was the one at rest (not a preview)
        self.frame_bytes = 0  # size of the last frame sent, and its JPEG quality
        self.frame_quality = 0
        with self.panel.add_tab("Overlay"):
            # Stretch the overlay images to the panel's width (viser shows images at most at
            # their own size; small maps would otherwise stay small); zoomed windows without
            # smoothing (see render)
            self.image_css = gui.add_html(IMAGE_CSS["fit"])
            self.caption = gui.add_markdown("Loading...")
            gui.add_html(pointer_marker("Overlay pointer"))
            self.image = gui.add_image(
                np.zeros((cam.height, cam.width, 3), np.uint8), format="jpeg", jpeg_quality=REST_QUALITIES[0]
            )
            self.legend = gui.add_html(legend_html("intensity"))
            self.zoom = gui.add_dropdown("Zoom", tuple(ZOOMS), initial_value="fit",
                                         hint="Click the image to zoom there (2x) or to move the centre; "
                                              "1:1 shows map pixels at screen pixels")
            self.centre_in = gui.add_text("Zoom centre (px)", f"{cam.width / 2:g}, {cam.height / 2:g}",
                                          hint="x, y in map pixels; or click the image")
            self.view = gui.add_dropdown("View", VIEWS, initial_value="overlay",
                                         hint="edges: map edges (cyan) against the points' depth edges (magenta); "
                                              "white where they agree")
            self.pointer = gui.add_text("Overlay pointer", "", hint="(set by clicks on the image)")
            self.window_size = gui.add_text("Window size", "", hint="(set by the page: its window's size)")
            with gui.add_folder("Display"):
                self.color_by = gui.add_dropdown("Colour by", COLOR_MODES, initial_value=default_color_by(kind),
                                                 hint="Colour the lidar points by their intensity or their depth "
                                                      "(default: depth on camera images, intensity on event maps)")
                self.point_size = gui.add_slider("Point size (px)", 1, 8, 1, size,
                                                 hint="Disc diameter in screen pixels: the same at any zoom and map size "
                                                      "(the default from the scan's density)")
                self.outline = gui.add_checkbox("Dark outline", True,
                                                hint="A dark ring around each point: readable on bright and dark images")
                self.opacity = gui.add_slider("Opacity", 0.0, 1.0, 0.05, 0.8,
                                              hint="Lower it to see the event map through the points")
                self.contrast = gui.add_slider("Contrast", 0.2, 6.0, 0.1, 1.0, hint="Brightens the event map")
                self.map_mode = gui.add_dropdown(
                    "Map", MAP_MODES, initial_value="raw",
                    hint="raw: the accumulated map as recorded; smoothed: clipped and blurred as the MI sees it",
                )
            gui.add_html(hide_inputs([self.pointer, self.window_size]))
        self.compare_tab = self.panel.add_tab("Before / after")
        for handle in (self.color_by, self.point_size, self.outline, self.opacity, self.contrast, self.map_mode,
                       self.zoom, self.view):
            handle.on_update(lambda _: app.display_changed())
        self.centre = (cam.width / 2.0, cam.height / 2.0)
        self.window: Window | None = None  # the part of the map the last frame showed
        self.centre_in.on_update(self._on_centre_typed)
        self.pointer.on_update(self._on_pointer)
        self.window_size.on_update(self._on_window_size)
        self.display_width = DISPLAY_WIDTH  # frames are sent at most this wide
        self.window_width: int | None = None  # the browser window's width, as last reported
        self.picking = False  # picking pairs: a narrower overlay, a wider 3D view
        self._fitted: dict[tuple, tuple[int | None, int]] = {}  # (width, quality) the last frame of a kind fitted at
        self.panel.dock_left()
        self.panel.set_width(PANEL_WIDTH)

    def style(self) -> OverlayStyle:
        return OverlayStyle(
            color_by=self.color_by.value,
            point_size=int(self.point_size.value),
            opacity=float(self.opacity.value),
            contrast=float(self.contrast.value),
            outline=1 if self.outline.value else 0,
        )

    def base_image(self, index: int, style: OverlayStyle) -> np.ndarray:
        sigma = self.app.readout.sigma
        return self.app.displays[index].base(style.contrast, self.map_mode.value, sigma)

    def draw(self, index: int, extrinsic, style: OverlayStyle | None = None, width: int | None = None,
             window: Window | None = None, projection=None, screen_width: float | None = None) -> np.ndarray:
        """The overlay of scene ``index`` at ``extrinsic`` (of ``window`` of the map: None, all of
        it) as an RGB array ``width`` pixels wide (None: at map resolution), its points
        ``style.point_size`` pixels across on screen when the image is shown ``screen_width``
        pixels wide (None: a frame as the panel shows it, ``display_width``; an image at map
        resolution drawn as if the panel showed it, so a saved file looks like the screen)."""
        style = style or self.style()
        disp = self.app.displays[index]
        colors = disp.colors() if style.color_by == "intensity" else None
        box = None if window is None else (window.x0, window.y0, window.width, window.height)
        map_w = window.width if window is not None else self.app.camera.width
        out_w = width or map_w
        # the frame is shown display_width px wide; at map resolution, as the panel would show the map
        screen = screen_width or (self.display_width if width else self.display_width * map_w / self.app.camera.width)
        image = render_view(self.base_image(index, style), disp.scene.points, extrinsic, self.app.camera, style,
                            colors, box, out_w, screen, pixelated=window is not None and out_w > map_w,
                            projection=projection)
        return self.app.annotate(index, extrinsic, image, style.point_size, box)

    def render(self, snap: Snapshot, rest: bool = True) -> None:
        """Draw the overlay and send it within ``FRAME_BYTES``: at rest (``rest``) at the panel's
        width and the best quality that fits; while controls move, a quicker preview at most
        ``DISPLAY_WIDTH`` wide. A zoomed view is a window of the map magnified without
        smoothing; the points are drawn into the frame, at their screen size."""
        style = self.style()
        index, extrinsic = snap.selected, snap.shown_extrinsic
        disp = self.app.displays[index]
        projection = None
        if self.view.value == "edges" or style.color_by == "depth":
            projection = project_scene(disp.scene.points, extrinsic, self.app.camera)
        zoom = self.zoom.value
        cam = self.app.camera
        window = zoom_window((cam.height, cam.width), zoom, self.centre, self.display_width)
        width = self.display_width if rest else min(self.display_width, DISPLAY_WIDTH)
        if self.view.value == "edges":
            assert projection is not None
            normalised = disp.normalised("smoothed", self.app.readout.sigma)  # edges of the map the MI sees
            image = edge_view(normalised, projection.uv, projection.depth)
            if zoom != "fit":
                image = cropped(image, window)
            full = min(width, image.shape[1]) if zoom == "fit" else image.shape[1]  # before the byte budget
        else:
            # drawn at the frame's size: points keep their screen size at any zoom and map size
            image = self.draw(index, extrinsic, style, width, None if zoom == "fit" else window, projection)
            full = image.shape[1]
        css = IMAGE_CSS["fit" if zoom == "fit" else "zoomed"]
        if self.image_css.content != css:
            self.image_css.content = css
        key = (rest, zoom, self.view.value, width)  # what the width that fitted last depends on
        # one resize, straight to the width that fitted last time (or to the full width)
        width_fitted, quality_fitted = self._fitted.get(key, (None, None))
        image, data, quality = jpeg_within(image, FRAME_BYTES, REST_QUALITIES if rest else PREVIEW_QUALITIES,
                                           width_fitted or full, quality_fitted)
        # remember a shrunk width (start there next time); a frame that fits at full width
        # forgets it, so the next one tries full width again
        self._fitted[key] = (image.shape[1] if image.shape[1] < full else None, quality)
        send_jpeg(self.image, image, data)
        self.app.server.flush()  # the frame leaves now, not after viser's 16 ms message window
        self.window, self.rest_frame = window, rest
        self.frame_bytes, self.frame_quality = len(data), quality
        self.frames += 1
        depth = depth_range(projection.depth) if projection is not None and style.color_by == "depth" else None
        legend = legend_html(style.color_by, depth, disp.scene.map_kind)
        if self.view.value == "edges":
            legend = EDGE_LEGEND
        if legend != self.legend.content:
            self.legend.content = legend

    # --- layout --------------------------------------------------------------------------------
    def _on_window_size(self, event) -> None:
        """A page reported its window's size: give the overlay the space (the last report wins:
        viser places panels for every tab at once)."""
        parts = str(self.window_size.value).lower().split("x")
        if event.client is None or len(parts) != 2 or not parts[0].strip().isdigit():
            return
        self.window_width = int(parts[0])
        self._layout()

    def set_picking(self, on: bool) -> None:
        """Narrow the overlay while pairs are picked (the 3D view widens), and back."""
        self.picking = bool(on)
        self._layout(force=True)

    def _layout(self, force: bool = False) -> None:
        panel, frame = panel_layout(self.window_width or PANEL_WIDTH + CONTROLS_PX + MIN_3D_PX, self.picking)
        if frame != self.display_width or force:
            self.panel.set_width(panel)
            self.display_width = frame
            self.app.display_changed()

    # --- zoom and pan ------------------------------------------------------------------------
    def _on_pointer(self, event) -> None:
        """A click on the image (fractions of its width and height): centre there; zoom in from fit."""
        xy = _pair(self.pointer.value)
        if event.client is None or xy is None or self.window is None:
            return
        x, y = self.window.to_map(*xy)
        if self.app.image_clicked(x, y):  # a pair being picked takes the click
            return
        self.centre = (x, y)
        self.centre_in.value = f"{self.centre[0]:.0f}, {self.centre[1]:.0f}"
        if self.zoom.value == "fit":
            self.zoom.value = "2x"  # runs the display callback
        else:
            self.app.display_changed()

    def _on_centre_typed(self, event) -> None:
        xy = _pair(self.centre_in.value)
        if event.client is None or xy is None:
            return
        cam = self.app.camera
        self.centre = (float(np.clip(xy[0], 0, cam.width - 1)), float(np.clip(xy[1], 0, cam.height - 1)))
        self.app.display_changed()

    def show_caption(self, snap: Snapshot, reading: MiReading | None) -> None:
        name = self.app.state.scene_names[snap.selected]
        mi = "" if reading is None else f" · {self.app.readout.label} {score_num(reading.per_scene[snap.selected])}"
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
