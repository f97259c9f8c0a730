"""Overlay rendering: lidar points projected onto the accumulated event map, as an RGB image.

Everything here is plain numpy (plus OpenCV for the colour table, dilation, text and JPEG
encoding) and has no viser import, so it can be benchmarked and unit-tested on its own. Points
are drawn as small discs by one vectorised scatter and one dilation -- never one drawing call
per point -- so a full-size overlay (1280x720, 75k points) renders in a few milliseconds.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from ..camera import CameraModel
from ..geometry import Extrinsic, in_image, project_points
from ..objective import CLIP

COLOR_MODES = ("intensity", "depth")
COMPARE_MODES = ("side by side", "swipe", "blend")


@dataclass(frozen=True)
class OverlayStyle:
    """How the overlay looks: what colours the points, their size and opacity, map contrast."""

    color_by: str = "intensity"
    point_size: int = 2
    opacity: float = 0.85
    contrast: float = 1.0

    def __post_init__(self) -> None:
        if self.color_by not in COLOR_MODES:
            raise ValueError(f"color_by must be one of {COLOR_MODES}, got {self.color_by!r}")
        if not 1 <= int(self.point_size) <= 15:
            raise ValueError(f"point_size must be 1..15 px, got {self.point_size}")
        if not 0.0 <= float(self.opacity) <= 1.0:
            raise ValueError(f"opacity must be in [0, 1], got {self.opacity}")
        if not float(self.contrast) > 0.0:
            raise ValueError(f"contrast must be positive, got {self.contrast}")


@dataclass(frozen=True)
class Projection:
    """The points of one scene that land in the image at one extrinsic."""

    uv: np.ndarray  # (M, 2) float pixel coordinates
    depth: np.ndarray  # (M,) camera-frame z, metres
    index: np.ndarray  # (M,) indices into the scene's point array


@lru_cache(maxsize=4)
def color_table(name: str = "turbo") -> np.ndarray:
    """A (256, 3) uint8 RGB lookup table (OpenCV's colour maps, converted from BGR)."""
    cmap = {"turbo": cv2.COLORMAP_TURBO, "viridis": cv2.COLORMAP_VIRIDIS}[name]
    lut = cv2.applyColorMap(np.arange(256, dtype=np.uint8)[:, None], cmap)[:, 0, ::-1]
    return np.ascontiguousarray(lut)


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
    d = projection.depth
    if d.size == 0:
        return np.zeros((0, 3), np.uint8)
    lo, hi = np.percentile(d, [2.0, 98.0])
    t = np.clip((d - lo) / max(hi - lo, 1e-6), 0.0, 1.0)
    return color_table("turbo")[(255 - np.rint(t * 255)).astype(np.uint8)]


def intensity_colors(intensity: np.ndarray) -> np.ndarray:
    """(N, 3) uint8 colours for lidar intensities 0..255 (computed once per scene)."""
    lut = color_table("turbo")
    idx = np.clip(np.nan_to_num(np.asarray(intensity, np.float32)), 0, 255).astype(np.uint8)
    return lut[idx]


@lru_cache(maxsize=32)
def disc_offsets(size: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixel offsets (dy, dx) of a filled disc ``size`` pixels across."""
    size = int(size)
    r = (size - 1) / 2.0
    lo = -int(np.floor(r))
    hi = int(np.ceil(r))
    ys, xs = np.mgrid[lo : hi + 1, lo : hi + 1]
    cy = cx = (lo + hi) / 2.0
    keep = (ys - cy) ** 2 + (xs - cx) ** 2 <= (r + 0.5) ** 2 if size > 2 else np.ones_like(ys, bool)
    return ys[keep].astype(np.int32), xs[keep].astype(np.int32)


@lru_cache(maxsize=32)
def _disc_kernel(size: int) -> tuple[np.ndarray, tuple[int, int]]:
    """The disc as a dilation kernel and its anchor (x, y)."""
    dys, dxs = disc_offsets(size)
    lo = int(min(dys.min(), dxs.min()))
    k = int(max(dys.max(), dxs.max())) - lo + 1
    kernel = np.zeros((k, k), np.uint8)
    kernel[dys - lo, dxs - lo] = 1
    return kernel, (-lo, -lo)


def draw_points(
    base: np.ndarray,
    uv: np.ndarray,
    colors: np.ndarray,
    point_size: int = 2,
    opacity: float = 1.0,
    depth: np.ndarray | None = None,
) -> np.ndarray:
    """Draw discs of ``colors`` at pixel positions ``uv`` on a copy of ``base`` (H, W, 3 uint8).

    Each point's rank is scattered into a one-channel image (near points ranked above far ones
    when ``depth`` is given), the image is grown into discs by one grey dilation (a max filter:
    where discs overlap, the nearer point wins), the ranks are turned into colours through a
    packed RGBA palette, and the disc pixels are copied (or blended, with ``opacity``) onto
    the map. Whole-image operations only: no per-point or per-offset loop.
    """
    h, w = base.shape[:2]
    out = base.copy()
    u = np.rint(uv[:, 0]).astype(np.int32)
    v = np.rint(uv[:, 1]).astype(np.int32)
    ok = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    u, v, colors = u[ok], v[ok], colors[ok]
    if u.size == 0:
        return out
    if depth is not None and u.size > 1:
        order = np.argsort(-np.asarray(depth)[ok])  # far first, so near points rank higher
        u, v, colors = u[order], v[order], colors[order]
    rank = np.zeros((h, w), np.float32)  # 0 = no point; exact for ranks below 2**24
    rank[v, u] = np.arange(1, u.size + 1, dtype=np.float32)  # repeated pixels: the last (nearest) wins
    if point_size > 1:
        kernel, anchor = _disc_kernel(int(point_size))
        rank = cv2.dilate(rank, kernel, anchor=anchor)
    palette = np.zeros((u.size + 1, 4), np.uint8)  # RGBA rows viewed as one uint32 each
    palette[1:, :3] = colors
    layer = palette.view(np.uint32).ravel()[rank.astype(np.int32)]
    layer = np.ascontiguousarray(layer.view(np.uint8).reshape(h, w, 4)[:, :, :3])
    if opacity < 1.0:
        layer = cv2.addWeighted(base, 1.0 - float(opacity), layer, float(opacity), 0.0)
    mask = (rank > 0).view(np.uint8)
    cv2.copyTo(layer, mask, out)
    return out


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
    return draw_points(base_rgb, proj.uv, colors, style.point_size, style.opacity, proj.depth)


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
