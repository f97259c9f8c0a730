"""Inspecting the overlay: zoom to native resolution around a clicked centre, a colour legend
with units, and an edge view (pure numpy / OpenCV, no viser).

Zoom levels: ``fit`` shows the whole map; ``1:1`` a window of the display's width in map
pixels, one map pixel per screen pixel; ``2x`` / ``4x`` half / a quarter of that window, each
map pixel drawn as a 2x2 / 4x4 block. The window is magnified without smoothing (nearest
neighbour) to the frame's width and the points are drawn into the magnified frame, so no
smoothing hides a misalignment and a point keeps its screen size at any zoom.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..drawing import point_table

ZOOMS = {"fit": 0, "1:1": 1, "2x": 2, "4x": 4}


@dataclass(frozen=True)
class Window:
    """A crop of the map: top-left corner and size in map pixels."""

    x0: int
    y0: int
    width: int
    height: int

    def to_map(self, fx: float, fy: float) -> tuple[float, float]:
        """A point given as fractions of this window's width and height -> map pixels."""
        fx, fy = float(np.clip(fx, 0.0, 1.0)), float(np.clip(fy, 0.0, 1.0))
        return self.x0 + fx * self.width, self.y0 + fy * self.height


def zoom_window(shape: tuple[int, ...], zoom: str, centre: tuple[float, float], display_width: int) -> Window:
    """The part of a map of ``shape`` that ``zoom`` shows around ``centre`` (x, y map pixels)."""
    h, w = int(shape[0]), int(shape[1])
    factor = ZOOMS[zoom]
    if factor == 0:
        return Window(0, 0, w, h)
    cw = max(8, min(w, round(display_width / factor)))
    ch = max(8, min(h, round(cw * h / w)))
    x0 = int(np.clip(round(centre[0] - cw / 2), 0, w - cw))
    y0 = int(np.clip(round(centre[1] - ch / 2), 0, h - ch))
    return Window(x0, y0, cw, ch)


def cropped(image: np.ndarray, window: Window) -> np.ndarray:
    """The window of ``image`` at its own resolution."""
    return np.ascontiguousarray(image[window.y0 : window.y0 + window.height, window.x0 : window.x0 + window.width])


def depth_range(depth: np.ndarray) -> tuple[float, float]:
    """The depth span the colours cover (the 2nd..98th percentile, as the overlay uses)."""
    if depth.size == 0:
        return 0.0, 0.0
    lo, hi = np.percentile(depth, [2.0, 98.0])
    return float(lo), float(hi)


def _gradient(indices: np.ndarray) -> str:
    lut = point_table()
    stops = ", ".join(f"rgb({r},{g},{b}) {100 * k / (len(indices) - 1):.0f}%"
                      for k, (r, g, b) in enumerate(lut[indices]))
    return f"linear-gradient(to right, {stops})"


def legend_html(color_by: str, depth_m: tuple[float, float] | None = None, map_kind: str = "events") -> str:
    """A colour bar with its units, for the points (by intensity or depth) and the map."""
    if color_by == "depth":
        lo, hi = depth_m or (0.0, 0.0)
        bar = _gradient(np.linspace(255, 0, 9).astype(np.uint8))  # near red -> far blue
        left, right, what = f"{lo:.1f} m (near)", f"{hi:.1f} m (far)", "points: depth along the optical axis"
    else:
        bar = _gradient(np.linspace(0, 255, 9).astype(np.uint8))
        left, right, what = "0", "255", "points: lidar intensity (scaled to 0..255)"
    grey = ("map: events per pixel, black 0 → white ≥ clip" if map_kind == "events"
            else "map: image brightness, black → white")
    return (
        "<div style='font-size:0.75em;line-height:1.3;padding:0 0.5em'>"
        f"<div>{what}</div>"
        f"<div style='display:flex;align-items:center;gap:0.5em'><span>{left}</span>"
        f"<div style='flex:1;height:0.8em;border-radius:2px;background:{bar}'></div><span>{right}</span></div>"
        f"<div style='opacity:0.8'>{grey}</div></div>"
    )


def edge_view(map_norm: np.ndarray, uv: np.ndarray, depth: np.ndarray, jump: float = 0.1) -> np.ndarray:
    """Map edges (cyan) against the projected points' depth discontinuities (magenta).

    Map edges: Canny on the (smoothed) map, thresholds from Otsu's level. Depth discontinuities: image pixels where the
    nearest projected depth differs by more than ``jump`` (relative) from a neighbour's. When
    the calibration is right, the magenta lines sit on the cyan ones; overlap shows white.
    """
    h, w = map_norm.shape[:2]
    grey = np.clip(map_norm * 255.0, 0, 255).astype(np.uint8)
    grey = cv2.GaussianBlur(grey, (0, 0), 2.0)
    high, _ = cv2.threshold(grey, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    map_edges = cv2.Canny(grey, max(10.0, 0.5 * high), max(20.0, high)) > 0
    z = np.full((h, w), np.inf, np.float32)
    if uv.size:
        u = np.clip(np.rint(uv[:, 0]).astype(np.int64), 0, w - 1)
        v = np.clip(np.rint(uv[:, 1]).astype(np.int64), 0, h - 1)
        np.minimum.at(z, (v, u), depth.astype(np.float32))
    filled = np.where(np.isfinite(z), z, 0).astype(np.float32)
    # spread each point over a small neighbourhood so sparse scans form surfaces
    near = cv2.erode(np.where(filled > 0, filled, 1e6).astype(np.float32), np.ones((5, 5), np.uint8))
    far = cv2.dilate(filled, np.ones((5, 5), np.uint8))
    valid = near < 1e6
    depth_edges = valid & (far - near > jump * np.maximum(near, 1e-3))
    depth_edges = cv2.erode(depth_edges.astype(np.uint8), np.ones((2, 2), np.uint8)) > 0
    out = np.zeros((h, w, 3), np.uint8)
    out[map_edges] = (0, 200, 255)
    out[depth_edges] = (255, 0, 200)
    out[map_edges & depth_edges] = (255, 255, 255)
    return out
