"""A checkerboard target: its geometry and an anti-aliased rendering of it into a camera.

The board frame: origin at the centre of the board's outline, x along the columns (the board's
width), y along the rows (its height), z = x cross y, into the board (away from a camera that
faces it, as OpenCV's board frame). The checker pattern is centred on the board with a white
margin around it; the top-left square (smallest x and y) is black.

Rendering casts a ray through every pixel centre (lens distortion undone by Newton steps on
:func:`l2e_studio.geometry.distort`), intersects it with the board's plane and box-filters the
pattern over the pixel with a 4 x 4 supersampling from the local pixel-to-board Jacobian, so
the corner noise a detector sees comes from the rendering itself (edges are partial-coverage
greys, never exact steps).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..camera import CameraModel
from ..geometry import Extrinsic, distort


@dataclass(frozen=True)
class Board:
    """``squares`` = (columns, rows) of squares of side ``square_m``; ``size_m`` = the outer
    (width, height), margin included."""

    squares: tuple[int, int] = (10, 7)
    square_m: float = 0.068
    size_m: tuple[float, float] = (0.8, 0.6)

    def __post_init__(self) -> None:
        cols, rows = self.squares
        if cols < 3 or rows < 3 or self.square_m <= 0:
            raise ValueError("a board needs at least 3 x 3 squares of positive size")
        if self.size_m[0] < cols * self.square_m or self.size_m[1] < rows * self.square_m:
            raise ValueError(f"size_m {self.size_m} is smaller than the pattern "
                             f"({cols * self.square_m:g} x {rows * self.square_m:g} m)")

    @property
    def pattern_m(self) -> tuple[float, float]:
        return self.squares[0] * self.square_m, self.squares[1] * self.square_m

    def inner_corners(self) -> np.ndarray:
        """((cols-1)*(rows-1), 3) inner corners in the board frame, row by row (x fastest)."""
        cols, rows = self.squares
        xs = (np.arange(1, cols) - cols / 2) * self.square_m
        ys = (np.arange(1, rows) - rows / 2) * self.square_m
        X, Y = np.meshgrid(xs, ys)
        return np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])

    def outline(self) -> np.ndarray:
        """(4, 3) outer corners in the board frame (clockwise in the image from top-left)."""
        w, h = self.size_m[0] / 2, self.size_m[1] / 2
        return np.array([[-w, -h, 0.0], [w, -h, 0.0], [w, h, 0.0], [-w, h, 0.0]])

    def albedo(self, x: np.ndarray, y: np.ndarray, black: float = 0.05, white: float = 0.85) -> np.ndarray:
        """Reflectance at board coordinates (NaN off the board)."""
        pw, ph = self.pattern_m
        col = np.floor((x + pw / 2) / self.square_m)
        row = np.floor((y + ph / 2) / self.square_m)
        in_pattern = (np.abs(x) < pw / 2) & (np.abs(y) < ph / 2)
        dark = in_pattern & ((col + row) % 2 == 0)
        value = np.where(dark, black, white)
        on_board = (np.abs(x) <= self.size_m[0] / 2) & (np.abs(y) <= self.size_m[1] / 2)
        return np.where(on_board, value, np.nan)

    def to_yaml(self) -> dict:
        """The realdata ``target.yaml`` document."""
        return {"target": {"kind": "checkerboard", "squares": [int(self.squares[0]), int(self.squares[1])],
                           "square_m": float(self.square_m), "size_m": [float(v) for v in self.size_m]}}


def pixel_rays(camera: CameraModel) -> np.ndarray:
    """(H, W, 3) camera-frame rays (z = 1) through every pixel centre, lens distortion undone."""
    v, u = np.mgrid[0 : camera.height, 0 : camera.width].astype(np.float64)
    K = camera.K
    yd = (v - K[1, 2]) / K[1, 1]
    xd = (u - K[0, 2] - K[0, 1] * yd) / K[0, 0]
    x, y = xd.copy(), yd.copy()
    for _ in range(20):  # Newton on distort(x, y) = (xd, yd)
        fx, fy, (a, b, c, d) = distort(x, y, camera, jacobian=True)
        rx, ry = xd - fx, yd - fy
        det = a * d - b * c
        step_x = (d * rx - b * ry) / det
        step_y = (a * ry - c * rx) / det
        x += step_x
        y += step_y
        if max(np.nanmax(np.abs(step_x)), np.nanmax(np.abs(step_y))) < 1e-12:
            break
    return np.stack([x, y, np.ones_like(x)], axis=-1)


def board_coordinates(rays: np.ndarray, pose: Extrinsic) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where each camera ray meets the board plane: board (x, y) and the depth along the ray
    (NaN where the ray misses the plane or meets it behind the camera). ``pose`` = T_cam_board."""
    R, t = pose.R, pose.translation
    n = R[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (n @ t) / (rays @ n)
    s = np.where(s > 0, s, np.nan)
    local = (rays * s[..., None] - t) @ R
    return local[..., 0], local[..., 1], s


def render_board(
    board: Board,
    camera: CameraModel,
    rays: np.ndarray,
    pose: Extrinsic,
    background: np.ndarray,
    black: float = 0.05,
    white: float = 0.85,
    shading: np.ndarray | None = None,
    supersample: int = 4,
) -> tuple[np.ndarray, np.ndarray]:
    """``background`` (H, W) radiance with the board at ``pose`` (T_cam_board) drawn over it.

    Returns the image and the board's coverage (0..1 per pixel). ``shading`` (H, W) multiplies
    the board's albedo (uneven light). Pixels the board covers partly are blended by coverage.
    """
    h, w = background.shape
    bx, by, _ = board_coordinates(rays, pose)
    reach = 0.5 * np.hypot(*board.size_m) + board.square_m
    near = np.isfinite(bx) & (np.abs(bx) < reach) & (np.abs(by) < reach)
    out = background.astype(np.float64).copy()
    cover = np.zeros((h, w))
    if not near.any():
        return out, cover
    rows, cols = np.flatnonzero(near.any(axis=1)), np.flatnonzero(near.any(axis=0))
    r0, r1 = max(rows[0] - 2, 0), min(rows[-1] + 3, h)
    c0, c1 = max(cols[0] - 2, 0), min(cols[-1] + 3, w)
    x, y = bx[r0:r1, c0:c1], by[r0:r1, c0:c1]
    dxdv, dxdu = np.gradient(x)
    dydv, dydu = np.gradient(y)
    offsets = (np.arange(supersample) + 0.5) / supersample - 0.5
    total = np.zeros(x.shape)
    hits = np.zeros(x.shape)
    for ou in offsets:
        for ov in offsets:
            value = board.albedo(x + ou * dxdu + ov * dxdv, y + ou * dydu + ov * dydv, black, white)
            on = np.isfinite(value)
            total += np.where(on, value, 0.0)
            hits += on
    n = supersample * supersample
    patch_cover = hits / n
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_albedo = np.where(hits > 0, total / np.maximum(hits, 1), 0.0)
    light = 1.0 if shading is None else shading[r0:r1, c0:c1]
    bg = out[r0:r1, c0:c1]
    out[r0:r1, c0:c1] = patch_cover * mean_albedo * light + (1 - patch_cover) * bg
    cover[r0:r1, c0:c1] = patch_cover
    return out, cover
