"""The camera model: intrinsics, distortion and image size.

Loading the model from the file formats users have lives in :mod:`l2e_studio.io.cameras`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

DISTORTION_MODELS = ("radtan", "equidistant")
#: Off-axis angles (deg) at which :func:`fold_r2` looks for the lens model turning back.
_FOLD_GRID = np.radians(np.linspace(0.0, 89.9, 8993))[1:]


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

    @cached_property
    def max_r2(self) -> float:
        """The squared normalised radius ``(X/Z)^2 + (Y/Z)^2`` beyond which the lens model folds
        back (:func:`fold_r2`); ``inf`` where it never does. Points beyond it are not in the image."""
        return fold_r2(self.model, self.D)

    def scaled(self, factor: float) -> "CameraModel":
        """The same camera for the image resized by ``factor`` (``cv2.resize`` pixel centres)."""
        K = self.K.copy()
        K[:2, :2] *= factor
        K[:2, 2] = (K[:2, 2] + 0.5) * factor - 0.5
        return CameraModel(K, round(self.width * factor), round(self.height * factor), self.D, self.model)


def fold_r2(model: str, D: np.ndarray) -> float:
    """Where a distortion polynomial turns back: the squared normalised radius at which the
    distorted radius stops growing with the angle off the optical axis (``inf`` if it grows up
    to 89.9 deg).

    A lens model is a polynomial fitted over the calibration images; past the field it was fitted
    on, a strong barrel term (e.g. k1 = -0.44, k3 = -0.07 on a 1280x720 lens of the dev rigs) makes
    the distorted radius fall again, so points 50-90 deg off axis, which the camera cannot see,
    land back inside the image (OpenCV's ``projectPoints`` does the same). Only the radial part is
    considered: tangential terms are small beside it. Measured on a grid of 0.01 deg.
    """
    d = np.zeros(8)
    D = np.asarray(D, dtype=np.float64).ravel()
    d[: D.size] = D
    if not np.any(d):
        return float("inf")
    th = _FOLD_GRID
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        if model == "equidistant":
            t2 = th * th
            rd = th * (1 + t2 * (d[0] + t2 * (d[1] + t2 * (d[2] + t2 * d[3]))))
        else:
            k1, k2, _, _, k3, k4, k5, k6 = d
            r2 = np.tan(th) ** 2
            rd = np.sqrt(r2) * (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
        grows = np.isfinite(rd) & (np.diff(rd, prepend=0.0) > 0)
    if grows.all():
        return float("inf")
    last = max(int(np.argmin(grows)) - 1, 0)  # the last angle before the first that does not grow
    return float(np.tan(th[last]) ** 2)
