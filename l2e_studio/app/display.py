"""Per-scene display data, computed once and cached: the map as a grey image at a given
contrast, the points' intensity colours, and a thinned cloud for the 3D view.

Keeps the per-frame work of the overlay down to projection, drawing and encoding.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

import cv2
import numpy as np

from ..score_maps import CLIP, prepare_map
from ..scenes import Scene
from .overlay import grey_rgb, intensity_colors, normalise_map

MAP_MODES = ("raw", "smoothed")
MAX_CLOUD_POINTS = 40_000  # in the 3D view (picking uses every point); each redraw costs a GPU-less browser ~1 us per point


@dataclass
class SceneDisplay:
    """Display caches of one scene (thread-safe; computed on first use)."""

    scene: Scene
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)
    _norm: dict[tuple[str, float], np.ndarray] = field(default_factory=dict, repr=False)
    _base: dict[tuple[str, float, float], np.ndarray] = field(default_factory=dict, repr=False)
    _colors: np.ndarray | None = field(default=None, repr=False)

    def normalised(self, mode: str = "raw", sigma: float = 5.0) -> np.ndarray:
        """The map scaled to 0..1: as recorded (``raw``) or as the objective sees it (``smoothed``)."""
        if mode not in MAP_MODES:
            raise ValueError(f"map mode must be one of {MAP_MODES}, got {mode!r}")
        key = (mode, float(sigma) if mode == "smoothed" else 0.0)
        with self._lock:
            if key not in self._norm:
                if mode == "raw":
                    self._norm[key] = normalise_map(self.scene.event_map, self.scene.map_kind)
                else:
                    clip = CLIP[self.scene.map_kind]
                    m = prepare_map(self.scene.event_map, sigma=sigma, clip=clip)
                    self._norm[key] = (m / max(float(m.max()), 1e-6)).astype(np.float32)
            return self._norm[key]

    def base(self, contrast: float = 1.0, mode: str = "raw", sigma: float = 5.0) -> np.ndarray:
        """(H, W, 3) uint8 grey map at ``contrast``; the last few are kept."""
        key = (mode, float(sigma) if mode == "smoothed" else 0.0, round(float(contrast), 3))
        with self._lock:
            hit = self._base.get(key)
        if hit is not None:
            return hit
        img = grey_rgb(self.normalised(mode, sigma), contrast)
        with self._lock:
            if len(self._base) >= 4:
                self._base.pop(next(iter(self._base)))
            self._base[key] = img
        return img

    def colors(self) -> np.ndarray:
        """(N, 3) uint8 intensity colours of every point."""
        with self._lock:
            if self._colors is None:
                self._colors = intensity_colors(self.scene.intensity)
            return self._colors

    def cloud(self, max_points: int = MAX_CLOUD_POINTS) -> tuple[np.ndarray, np.ndarray]:
        """Points and colours for the 3D view, evenly thinned to at most ``max_points``."""
        n = self.scene.points.shape[0]
        step = max(1, int(np.ceil(n / max_points)))
        return self.scene.points[::step], self.colors()[::step]

    def thumbnail(self, width: int = 480, contrast: float = 1.0) -> np.ndarray:
        """A small grey map for the camera frustum in the 3D view."""
        img = self.base(contrast)
        h, w = img.shape[:2]
        if w <= width:
            return img
        size = (width, max(1, round(h * width / w)))
        return cv2.resize(img, size, interpolation=cv2.INTER_AREA)
