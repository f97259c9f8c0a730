"""The camera model: intrinsics, distortion and image size.

Loading the model from the file formats users have lives in :mod:`l2e_studio.io.cameras`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

DISTORTION_MODELS = ("radtan", "equidistant")


@dataclass(frozen=True)
class CameraModel:
    """A pinhole camera with optional lens distortion.

    K is the 3x3 intrinsic matrix. D holds the distortion coefficients: for ``"radtan"``
    (OpenCV / Brown-Conrady) ``k1, k2, p1, p2[, k3]``; for ``"equidistant"`` (OpenCV fisheye,
    Kalibr ``equi``) ``k1, k2, k3, k4``. ``width`` x ``height`` is the image size in pixels.
    """

    K: np.ndarray
    width: int
    height: int
    D: np.ndarray = field(default_factory=lambda: np.zeros(5))
    model: str = "radtan"

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=np.float64)
        D = np.asarray(self.D, dtype=np.float64).ravel()
        if K.shape != (3, 3) or not np.all(np.isfinite(K)):
            raise ValueError(f"K must be a finite 3x3 matrix, got shape {K.shape}")
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise ValueError("K must have positive focal lengths fx, fy")
        if self.model not in DISTORTION_MODELS:
            raise ValueError(f"unknown distortion model {self.model!r}; expected one of {DISTORTION_MODELS}")
        if self.model == "radtan" and D.size not in (0, 4, 5, 8):
            raise ValueError(f"radtan distortion takes 4, 5 or 8 coefficients, got {D.size}")
        if self.model == "equidistant" and D.size not in (0, 4):
            raise ValueError(f"equidistant distortion takes 4 coefficients, got {D.size}")
        if not np.all(np.isfinite(D)):
            raise ValueError("distortion coefficients must be finite")
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise ValueError(f"image size must be positive, got {self.width}x{self.height}")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "D", D)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return self.width, self.height

    @property
    def is_distorted(self) -> bool:
        return bool(np.any(self.D != 0))

    def scaled(self, factor: float) -> "CameraModel":
        """The same camera for the image resized by ``factor`` (``cv2.resize`` pixel centres)."""
        K = self.K.copy()
        K[:2, :2] *= factor
        K[:2, 2] = (K[:2, 2] + 0.5) * factor - 0.5
        return CameraModel(K, round(self.width * factor), round(self.height * factor), self.D, self.model)
