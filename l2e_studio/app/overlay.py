"""Overlay rendering: lidar points projected onto the accumulated event map, as an RGB image.

Everything here is plain numpy (plus OpenCV for the colour table, dilation, text and JPEG
encoding) and has no viser import, so it can be benchmarked and unit-tested on its own. Points
are drawn as small discs by :func:`l2e_studio.drawing.draw_points` (one vectorised scatter and
one dilation), so a full-size overlay (1280x720, 75k points) renders in a few milliseconds.

:func:`render_view` draws the overlay at the size it is shown: the map (or a zoomed window of
it) is scaled to the frame first and the points are drawn into the frame at their sub-pixel
positions, so a point is ``point_size`` screen pixels across whatever the map's size and the
zoom (drawn on the map, a 1920-px photo shown 730 px wide would shrink its discs below a pixel,
and a 4x zoom would blow them up until they hide what they are aligned with).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass

import cv2
import numpy as np

from ..camera import CameraModel
from ..drawing import color_table, depth_colors, disc_offsets, disc_size, draw_points, point_table  # noqa: F401
from ..geometry import Extrinsic, in_image, project_points
from ..score_maps import CLIP

COLOR_MODES = ("intensity", "depth")
COMPARE_MODES = ("side by side", "swipe", "blend")


@dataclass(frozen=True)
class OverlayStyle:
    """How the overlay looks: what colours the points, their size and opacity, map contrast."""

    color_by: str = "intensity"
    point_size: int = 2  # px across on screen (see render_view), or on the image drawn on (render_overlay)
    opacity: float = 0.85
    contrast: float = 1.0
    outline: int = 1  # px of dark ring around each disc: points read on bright images too

    def __post_init__(self) -> None:
        if self.color_by not in COLOR_MODES:
            raise ValueError(f"color_by must be one of {COLOR_MODES}, got {self.color_by!r}")
        if not 1 <= int(self.point_size) <= 15:
            raise ValueError(f"point_size must be 1..15 px, got {self.point_size}")
        if not 0.0 <= float(self.opacity) <= 1.0:
            raise ValueError(f"opacity must be in [0, 1], got {self.opacity}")
        if not float(self.contrast) > 0.0:
            raise ValueError(f"contrast must be positive, got {self.contrast}")
        if not 0 <= int(self.outline) <= 4:
            raise ValueError(f"outline must be 0..4 px, got {self.outline}")


#: Share of the frame the points should cover at the default size: enough to read a sparse
#: 16-beam scan at a glance, little enough that a dense 64-beam one leaves the image visible.
DEFAULT_COVER = 0.15


def default_point_size(n_visible: int, frame_width: int, frame_height: int, lo: int = 2, hi: int = 5) -> int:
    """Screen pixels across for ``n_visible`` points on a frame of that size, so that their discs
    would cover about :data:`DEFAULT_COVER` of it (2 px for a 64-beam scan on a photo, 3-4 for 16 beams)."""
    area = DEFAULT_COVER * frame_width * frame_height / max(int(n_visible), 1)
    return int(np.clip(round(float(np.sqrt(area))), lo, hi))


def default_color_by(map_kind: str) -> str:
    """Depth for camera images (a photo's own colours drown intensity shades; depth edges show
    where the points should sit), intensity for event maps (their black background shows any
    colour, and intensity edges are what the events saw)."""
    return "intensity" if map_kind == "events" else "depth"


@dataclass(frozen=True)
class Projection:
    """The points of one scene that land in the image at one extrinsic."""

    uv: np.ndarray  # (M, 2) float pixel coordinates
    depth: np.ndarray  # (M,) camera-frame z, metres
    index: np.ndarray  # (M,) indices into the scene's point array


def normalise_map(event_map: np.ndarray, map_kind: str = "events") -> np.ndarray:
    """Scale a raw event map (counts) or grey image to float32 0..1 for display.

    Event counts are clipped like the objective clips them (``CLIP``), then divided by their 99.5th
    percentile over firing pixels so that sparse maps are still visible; grey images are
    divided by their maximum.
    """
    m = np.asarray(event_map, dtype=np.float32)
    if m.ndim != 2:
        raise ValueError(f"event map must be 2-D, got shape {m.shape}")
    m = np.nan_to_num(m, nan=0.0, posinf=0.0, neginf=0.0)
    if map_kind == "events":
        m = np.clip(m, 0.0, CLIP["events"])
        firing = m[m > 0]
        top = float(np.percentile(firing, 99.5)) if firing.size else 1.0
    else:
        top = float(m.max()) if m.size else 1.0
    return (m / max(top, 1e-6)).astype(np.float32)


def grey_rgb(normalised: np.ndarray, contrast: float = 1.0) -> np.ndarray:
    """A display map (0..1) as an (H, W, 3) uint8 grey image, brightened by ``contrast``."""
    g = np.clip(normalised * (255.0 * float(contrast)), 0.0, 255.0).astype(np.uint8)
    return np.repeat(g[:, :, None], 3, axis=2)


def project_scene(points: np.ndarray, extrinsic: Extrinsic, camera: CameraModel) -> Projection:
    """Project lidar-frame points at ``extrinsic``; keep those in front of and inside the image."""
    cam = extrinsic.transform(points)
    uv, in_front = project_points(cam, camera)
    keep = in_front & in_image(uv, camera)
    index = np.flatnonzero(keep)
    return Projection(uv=uv[index], depth=cam[index, 2], index=index)


def point_colors(
    projection: Projection, intensity_rgb: np.ndarray | None, color_by: str
) -> np.ndarray:
    """(M, 3) uint8 colours: the scene's intensity colours, or depth through the colour table.

    Depth uses the 2nd..98th percentile of the visible depths so near and far both read;
    near points are red, far points blue.
    """
    if color_by == "intensity":
        if intensity_rgb is None:
            raise ValueError("intensity colours are needed for color_by='intensity'")
        return intensity_rgb[projection.index]
    return depth_colors(projection.depth)


def intensity_colors(intensity: np.ndarray) -> np.ndarray:
    """(N, 3) uint8 colours for lidar intensities 0..255 (computed once per scene)."""
    idx = np.clip(np.nan_to_num(np.asarray(intensity, np.float32)), 0, 255).astype(np.uint8)
    return point_table()[idx]


def render_overlay(
    base_rgb: np.ndarray,
    points: np.ndarray,
    extrinsic: Extrinsic,
    camera: CameraModel,
    style: OverlayStyle,
    intensity_rgb: np.ndarray | None = None,
) -> np.ndarray:
    """The full overlay: project ``points`` at ``extrinsic`` and draw them on ``base_rgb``."""
    proj = project_scene(points, extrinsic, camera)
    colors = point_colors(proj, intensity_rgb, style.color_by)
    return draw_points(base_rgb, proj.uv, colors, style.point_size, style.opacity, proj.depth, style.outline)


#: Scaled map windows kept (each a frame's size, ~2 MB at 1128 px): the live overlay, the
#: before/after pair and a zoomed view at once, for a few scenes being compared.
SCALED_CACHE_SIZE = 6
_scaled: OrderedDict[tuple, tuple[np.ndarray, np.ndarray]] = OrderedDict()
_scaled_lock = threading.Lock()


def scaled_window(base_rgb: np.ndarray, window: tuple[int, int, int, int], size: tuple[int, int],
                  pixelated: bool = False) -> np.ndarray:
    """``window`` (x0, y0, w, h) of ``base_rgb`` scaled to ``size`` (w, h): area averaging when
    shrunk, nearest neighbour when ``pixelated``, linear otherwise; read-only.

    The map under the points does not change while the extrinsic does, so the last few results
    are kept (keyed by the base array itself, which the cache holds, so its id cannot be
    reused): a shrink by a non-integer factor costs ~12 ms at 1280 -> 1128 px, every frame."""
    x0, y0, ww, wh = window
    if tuple(size) == (ww, wh):
        return base_rgb[y0 : y0 + wh, x0 : x0 + ww]
    key = (id(base_rgb), x0, y0, ww, wh, *size, bool(pixelated))
    with _scaled_lock:
        hit = _scaled.get(key)
        if hit is not None and hit[0] is base_rgb:
            _scaled.move_to_end(key)
            return hit[1]
    interp = cv2.INTER_NEAREST if pixelated else cv2.INTER_AREA if size[0] < ww else cv2.INTER_LINEAR
    out = cv2.resize(base_rgb[y0 : y0 + wh, x0 : x0 + ww], tuple(size), interpolation=interp)
    out.flags.writeable = False
    with _scaled_lock:
        _scaled[key] = (base_rgb, out)
        while len(_scaled) > SCALED_CACHE_SIZE:
            _scaled.popitem(last=False)
    return out


def render_view(
    base_rgb: np.ndarray,
    points: np.ndarray,
    extrinsic: Extrinsic,
    camera: CameraModel,
    style: OverlayStyle,
    intensity_rgb: np.ndarray | None = None,
    window: tuple[int, int, int, int] | None = None,
    width: int | None = None,
    screen_width: float | None = None,
    pixelated: bool = False,
    projection: Projection | None = None,
) -> np.ndarray:
    """The overlay of the map's ``window`` (x0, y0, w, h in map pixels; None: all of it) drawn
    ``width`` pixels wide (None: the window's own width).

    The window is scaled first (area averaging when shrunk; nearest neighbour when
    ``pixelated``, so a zoomed map shows its pixels), then the points are drawn into the frame at
    their sub-pixel positions, ``style.point_size`` pixels across when the frame is shown
    ``screen_width`` pixels wide (None: as drawn) and ringed by ``style.outline`` pixels.
    ``projection``: the points already projected at ``extrinsic`` (saves doing it twice).
    """
    h, w = base_rgb.shape[:2]
    x0, y0, ww, wh = window if window is not None else (0, 0, w, h)
    out_w = int(width) if width else ww
    out_h = max(1, int(round(wh * out_w / ww)))
    crop = scaled_window(base_rgb, (x0, y0, ww, wh), (out_w, out_h), pixelated)
    proj = projection if projection is not None else project_scene(points, extrinsic, camera)
    colors = point_colors(proj, intensity_rgb, style.color_by)
    sx, sy = out_w / ww, out_h / wh
    # a map pixel's centre (x + 0.5) lands at (x + 0.5 - x0) * scale in the frame
    uv = np.column_stack(((proj.uv[:, 0] + 0.5 - x0) * sx - 0.5, (proj.uv[:, 1] + 0.5 - y0) * sy - 0.5))
    per_screen = out_w / float(screen_width) if screen_width else 1.0
    size = disc_size(style.point_size, per_screen)
    outline = disc_size(style.outline, per_screen) if style.outline else 0
    return draw_points(crop, uv, colors, size, style.opacity, proj.depth, outline)


def label(image: np.ndarray, text: str) -> np.ndarray:
    """Write a short caption in the top-left corner (in place; returns the image)."""
    scale = max(0.4, image.shape[1] / 1280.0)
    org = (int(8 * scale) + 2, int(24 * scale) + 2)
    cv2.putText(image, text, org, cv2.FONT_HERSHEY_SIMPLEX, 0.8 * scale, (0, 0, 0), 4, cv2.LINE_AA)
    cv2.putText(image, text, org, cv2.FONT_HERSHEY_SIMPLEX, 0.8 * scale, (255, 255, 255), 1, cv2.LINE_AA)
    return image


def compose_before_after(
    before: np.ndarray, after: np.ndarray, mode: str = "side by side", amount: float = 0.5, scale: float = 0.5
) -> np.ndarray:
    """Combine the seed overlay and the result overlay (same shape) into one image.

    ``"side by side"``: both at ``scale`` size next to each other, captioned; ``"swipe"``: seed left
    of a vertical line at ``amount`` of the width, result right of it; ``"blend"``:
    ``(1 - amount) * seed + amount * result``.
    """
    if before.shape != after.shape:
        raise ValueError(f"before {before.shape} and after {after.shape} differ in shape")
    if mode not in COMPARE_MODES:
        raise ValueError(f"mode must be one of {COMPARE_MODES}, got {mode!r}")
    amount = float(np.clip(amount, 0.0, 1.0))
    h, w = before.shape[:2]
    if mode == "side by side":
        size = (max(1, round(w * scale)), max(1, round(h * scale)))
        a = label(cv2.resize(before, size, interpolation=cv2.INTER_AREA) if scale != 1 else before.copy(), "seed")
        b = label(cv2.resize(after, size, interpolation=cv2.INTER_AREA) if scale != 1 else after.copy(), "result")
        return np.ascontiguousarray(np.hstack([a, b]))
    if mode == "swipe":
        cut = int(round(amount * w))
        out = after.copy()
        out[:, :cut] = before[:, :cut]
        out[:, max(cut - 1, 0) : min(cut + 1, w)] = (255, 255, 0)
        label(out, "seed | result")
        return out
    mixed = cv2.addWeighted(before, 1.0 - amount, after, amount, 0.0)
    return label(mixed, f"blend: {1 - amount:.0%} seed / {amount:.0%} result")


def encode_jpeg(image: np.ndarray, quality: int = 80) -> bytes:
    """RGB uint8 image -> JPEG bytes (what the browser is sent)."""
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(image, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return buf.tobytes()


def encode_png(image: np.ndarray) -> bytes:
    """RGB uint8 image -> PNG bytes (for files written to disk)."""
    ok, buf = cv2.imencode(".png", cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()
